"""The 3D picture: the gathered surface is the solution, the PNG shows it, and a missing PyVista
or a failing renderer costs one warning and nothing else.

The problem is the paper's cap pushed onto the plane (as in tests/post/test_postprocess.py) on the
square [-0.25, 0.25]², solved at κ = 1e-3 with the vertex penalty. The ``mpi`` tests gather from
every rank and hold on any number of ranks.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.mesh
import matplotlib.image
import numpy as np
import pytest
import ufl
from conftest import cap_on_square

from shellobstacle.post import pictures
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.render3d import plane_frame
from shellobstacle.solvers.newton.solver import NewtonSolver

COMM = MPI.COMM_WORLD
HALF, N = 0.25, 16
SMALL = Path(__file__).parents[2] / "examples" / "small.toml"


@pytest.fixture(scope="module")
def post() -> Postprocessor:
    """The cap pushed onto the plane, solved at κ = 1e-3."""
    problem = cap_on_square(HALF, N)
    NewtonSolver(problem).solve()
    return Postprocessor(problem)


@pytest.fixture
def fresh(monkeypatch: pytest.MonkeyPatch) -> None:
    """No earlier failure of this process stops the pictures (restored afterwards)."""
    monkeypatch.setattr(pictures, "_unavailable", None)


def _shared(tmp_path: Path) -> Path:
    return Path(COMM.bcast(str(tmp_path), root=0))


@pytest.mark.mpi
def test_the_gathered_surface_is_the_solution(post: Postprocessor) -> None:
    """Rank 0 gets every vertex once, in the global order, with θ, θ + U, g and the contact
    flag of that vertex, and the cells as triangles of those vertices."""
    data = pictures.gather_surface(post)
    data = COMM.bcast(data, root=0)
    problem = post.problem
    S = post.P1
    imap = S.dofmap.index_map
    n = imap.size_global
    assert data.points.shape == data.reference.shape == (n, 3)
    assert data.gap.shape == data.contact.shape == (n,)
    assert data.triangles.shape == (2 * N * N, 3)
    assert np.array_equal(np.unique(data.triangles), np.arange(n))
    # each rank checks its own vertices against its local fields, by coordinates
    lo, hi = imap.local_range
    y = S.tabulate_dof_coordinates()[: hi - lo, :2]
    assert np.array_equal(data.reference[lo:hi, :2], y)  # θ(y) = (y1, y2, ·) for this cap
    theta = np.column_stack(problem.shell.surface.theta_numpy(y))
    assert np.allclose(data.reference[lo:hi], theta, rtol=0, atol=1e-15)
    assert np.array_equal(data.gap[lo:hi], post.nodal_gap().x.array[: hi - lo])
    assert np.array_equal(data.contact[lo:hi], post.indicator().x.array[: hi - lo])
    U = post.cartesian_displacement()
    yv = problem.V.tabulate_dof_coordinates()[:, :2]
    by_point = {tuple(p): u for p, u in zip(yv, U.x.array.reshape(-1, 3), strict=True)}
    expected = np.array([by_point[tuple(p)] for p in y])
    assert np.allclose(data.points[lo:hi] - data.reference[lo:hi], expected, rtol=0, atol=1e-15)
    # the gap is the height of θ + U above the plane, and the contact flags are g ≤ tolerance
    assert np.allclose(data.gap, data.points @ data.q, rtol=0, atol=1e-14)
    assert np.array_equal(data.contact > 0.5, data.gap <= post.tolerance())
    assert int(data.contact.sum()) == post.contact()["num_contact_nodes"] > 0
    # the triangles tile ω: their areas in the (y1, y2) plane add up to the square's
    a, b, c = (data.reference[data.triangles[:, k], :2] for k in range(3))
    u, v = b - a, c - a
    areas = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    assert areas.sum() == pytest.approx((2 * HALF) ** 2, rel=1e-12)
    dx = ufl.Measure("dx", domain=problem.mesh)
    one = dolfinx.fem.assemble_scalar(
        dolfinx.fem.form(dolfinx.fem.Constant(problem.mesh, 1.0) * dx)
    )
    assert COMM.allreduce(one, op=MPI.SUM) == pytest.approx(areas.sum(), rel=1e-12)
    assert np.allclose(areas, 1 / (2 * N * N) * (2 * HALF) ** 2)


def test_plane_frame_is_orthonormal_with_q_last() -> None:
    for q in [(0, 0, 1), (0.3, 0, 0.954), (1, 0, 0), (0.2, -0.5, 0.3)]:
        frame = np.array(plane_frame(q))
        assert np.allclose(frame @ frame.T, np.eye(3), atol=1e-14)
        assert np.allclose(frame[2], np.asarray(q) / np.linalg.norm(q))
        assert np.linalg.det(frame) == pytest.approx(1.0)
    assert np.allclose(np.array(plane_frame((0, 0, 1))), np.eye(3))


def _red(image: np.ndarray) -> np.ndarray:
    """Where ``image`` (RGB, 0-255 or 0-1) shows the contact zone's red (shaded or not)."""
    rgb = image[..., :3].astype(float)
    rgb = rgb / 255.0 if rgb.max() > 1.0 else rgb
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (r > 0.35) & (r > 2.0 * g) & (r > 2.0 * b)


def _gap_coloured(image: np.ndarray) -> np.ndarray:
    """Where ``image`` shows a colour of the gap's map (viridis: green or blue over red, far
    from the greys of the plane and the background)."""
    rgb = image[..., :3].astype(float)
    rgb = rgb / 255.0 if rgb.max() > 1.0 else rgb
    spread = rgb.max(axis=-1) - rgb.min(axis=-1)
    return (spread > 0.2) & ~_red(image)


def _views(data: pictures.SurfaceData, tmp_path: Path) -> dict[str, np.ndarray]:
    """The renderer's two views of ``data``, run as write_picture runs it."""
    surface, views = tmp_path / "surface.npz", tmp_path / "views.npz"
    np.savez(surface, **data.arrays())
    subprocess.run([sys.executable, str(pictures._RENDERER), str(surface), str(views)], check=True)
    with np.load(views) as npz:
        return {k: npz[k] for k in npz.files}


def test_the_views_show_the_shell_in_the_gap_s_colours_and_outline_the_contact_zone(
    post: Postprocessor, tmp_path: Path
) -> None:
    """The contact zone's red appears in the close view exactly when a vertex touches."""
    data = pictures.gather_surface(post)
    views = _views(data, tmp_path)
    assert bool(views["contact"]) and bool(views["outlined"])
    assert tuple(views["clim"]) == (min(data.gap.min(), 0.0), data.gap.max())
    whole, close = views["whole"], views["close"]
    assert whole.dtype == np.uint8 and whole.shape[2] >= 3 and close.shape[2] >= 3
    assert _gap_coloured(whole).mean() > 0.1  # the shell fills a good part of the view
    assert _gap_coloured(close).mean() > 0.1
    assert _red(close).sum() > 300  # the outline: a tube around a zone some cells wide
    # without contact (the same surface, every flag cleared): no red anywhere
    lifted = dataclasses.replace(data, contact=np.zeros_like(data.contact))
    views = _views(lifted, tmp_path)
    assert not bool(views["contact"]) and not bool(views["outlined"])
    assert _red(views["close"]).sum() == 0 and _red(views["whole"]).sum() == 0
    # one touching vertex and no touching cell: the vertex is marked
    one = np.zeros_like(data.contact)
    one[int(np.argmin(data.gap))] = 1.0
    views = _views(dataclasses.replace(data, contact=one), tmp_path)
    assert bool(views["contact"]) and not bool(views["outlined"])
    assert _red(views["close"]).sum() > 20


@pytest.mark.mpi
def test_the_picture_shows_the_shell_the_gap_and_the_contact_zone(
    post: Postprocessor, tmp_path: Path, fresh: None
) -> None:
    """A PNG of both views with the colour bar and legend, drawn from the surface gathered
    from every rank; no temporary file stays behind."""
    folder = _shared(tmp_path)
    picture = pictures.write_picture(post, folder / "shell_3d.png", "the cap on the plane")
    assert picture.warning is None, picture.warning
    assert picture.path == folder / "shell_3d.png"
    if COMM.rank == 0:
        image = matplotlib.image.imread(picture.path)
        assert image.shape[0] > 400 and image.shape[1] > 1000
        assert _red(image).sum() > 300  # the outline (and the legend's line)
        assert _gap_coloured(image).mean() > 0.1  # the shell, and the colour bar
        assert sorted(p.name for p in folder.iterdir()) == ["shell_3d.png"]


def test_without_pyvista_the_first_picture_warns_and_the_rest_are_silent(
    post: Postprocessor, tmp_path: Path, fresh: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    import importlib.util

    find_spec = importlib.util.find_spec

    def without_pyvista(name: str, *args):
        return None if name == "pyvista" else find_spec(name, *args)

    monkeypatch.setattr(importlib.util, "find_spec", without_pyvista)
    first = pictures.write_picture(post, tmp_path / "a.png")
    assert first.path is None
    assert "PyVista is not installed" in first.warning and "[pictures]" in first.warning
    second = pictures.write_picture(post, tmp_path / "b.png")
    assert second == pictures.Picture(None, None)
    assert list(tmp_path.iterdir()) == []


def test_a_crashing_renderer_is_one_warning(
    post: Postprocessor, tmp_path: Path, fresh: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """VTK without an OpenGL context dies of a segmentation fault: the caller lives on, says
    why once, and does not start the renderer again."""
    crash = tmp_path / "crash.py"
    crash.write_text(
        "import os, sys\nprint('no OpenGL here', file=sys.stderr)\n"
        f"os.kill(os.getpid(), {int(signal.SIGSEGV)})\n"
    )
    monkeypatch.setattr(pictures, "_RENDERER", crash)
    out = tmp_path / "out"
    out.mkdir()
    first = pictures.write_picture(post, out / "shell_3d.png")
    assert first.path is None
    assert f"signal {int(signal.SIGSEGV)}" in first.warning
    assert "no OpenGL here" in first.warning and "EGL" in first.warning
    crash.write_text("raise SystemExit('started again')\n")
    assert pictures.write_picture(post, out / "shell_3d.png") == pictures.Picture(None, None)
    assert list(out.iterdir()) == []  # no picture, no temporary files


def test_solve_without_pyvista_writes_everything_else(
    tmp_path: Path, fresh: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A PyVista that cannot be imported (here a package that raises ImportError, first on the
    renderer's path): exit 0, one warning in the log and the summary, every other file."""
    if COMM.size > 1:
        pytest.skip("the command line runs serially here")
    from shellobstacle.cli.main import main

    fake = tmp_path / "fake" / "pyvista"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('simulated: no PyVista here')\n")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(fake.parent), *sys.path]))
    out = tmp_path / "run"
    assert main(["solve", str(SMALL), "-o", str(out), "-q", "--set", "domain.h=0.08"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "checks.txt",
        "config.toml",
        "cross_section.png",
        "deformed_surface.bp",
        "log.txt",
        "parameter_domain.bp",
        "summary.json",
        "surface.bp",
    ]
    summary = json.loads((out / "summary.json").read_text())
    warned = [w for w in summary["warnings"] if "3D pictures are skipped" in w]
    assert len(warned) == 1 and "simulated: no PyVista here" in warned[0]
    assert "shell_3d.png" not in summary["files"]
    assert (out / "log.txt").read_text().count("3D pictures are skipped") == 1


def test_solve_draws_the_picture_and_lists_it(tmp_path: Path, fresh: None) -> None:
    if COMM.size > 1:
        pytest.skip("the command line runs serially here")
    from shellobstacle.cli.main import main

    out = tmp_path / "run"
    assert main(["solve", str(SMALL), "-o", str(out), "-q", "--set", "domain.h=0.05"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert "shell_3d.png" in summary["files"] and "cross_section.png" in summary["files"]
    assert not [w for w in summary["warnings"] if "3D" in w]
    image = matplotlib.image.imread(out / "shell_3d.png")
    assert _red(image).sum() > 300 and _gap_coloured(image).mean() > 0.1
    off = tmp_path / "off"
    args = ["solve", str(SMALL), "-o", str(off), "-q", "--set", "domain.h=0.08"]
    assert main([*args, "--set", "output.pictures=false"]) == 0
    assert not (off / "shell_3d.png").exists() and (off / "cross_section.png").exists()


def test_experiment_load_draws_the_largest_load_and_a_resumed_run_keeps_it(
    tmp_path: Path, fresh: None
) -> None:
    """Batch 3 draws the last value's solution beside its cross-sections in report.md; a
    resumed run whose values are all recorded has no solution to draw and keeps the drawing."""
    if COMM.size > 1:
        pytest.skip("the command line runs serially here")
    from shellobstacle.cli.main import main

    paraboloid = Path(__file__).parents[2] / "examples" / "paraboloid.toml"
    out = tmp_path / "load"
    args = ["experiment", "load", str(paraboloid), "--values", "0,40", "-o", str(out), "-q"]
    assert main([*args, "--set", "domain.h=0.06"]) == 0
    png = out / "batch3_shell_3d.png"
    report = (out / "report.md").read_text()
    assert "![the shell in 3D at ell = 40](batch3_shell_3d.png)" in report
    assert report.index("batch3_cross_sections.png") < report.index("batch3_shell_3d.png")
    assert _red(matplotlib.image.imread(png)).sum() > 20  # one contact vertex at this h
    drawn = png.stat().st_mtime_ns
    assert main([*args, "--set", "domain.h=0.06", "--resume"]) == 0
    assert png.stat().st_mtime_ns == drawn
    assert "batch3_shell_3d.png" in (out / "report.md").read_text()
    png.unlink()  # a drawing that is missing is not referenced
    assert main([*args, "--set", "domain.h=0.06", "--resume"]) == 0
    assert "batch3_shell_3d.png" not in (out / "report.md").read_text()


@pytest.mark.parametrize(
    ("experiment", "options", "png"),
    [
        ("mesh", ["--q", "1", "--refinements", "1"], "batch2_shell_3d.png"),
        ("solvers", ["--sizes", "0.1,0.07", "--exponent", "1"], "solvers_shell_3d.png"),
    ],
)
def test_experiments_draw_their_finest_solution(
    tmp_path: Path, fresh: None, experiment: str, options: list[str], png: str
) -> None:
    """``experiment mesh`` and ``experiment solvers`` draw their finest mesh's solution, with
    its contact zone, and reference it in report.md; a resumed run whose steps are all
    recorded keeps that drawing."""
    if COMM.size > 1:
        pytest.skip("the command line runs serially here")
    from shellobstacle.cli.main import main

    paper = Path(__file__).parents[2] / "examples" / "paper.toml"
    out = tmp_path / experiment
    args = ["experiment", experiment, str(paper), *options, "-o", str(out), "-q"]
    args += ["--set", "domain.h=0.07"]
    assert main(args) == 0
    assert f"]({png})" in (out / "report.md").read_text()
    assert _red(matplotlib.image.imread(out / png)).sum() > 20
    drawn = (out / png).stat().st_mtime_ns
    assert main([*args, "--resume"]) == 0
    assert (out / png).stat().st_mtime_ns == drawn
    assert f"]({png})" in (out / "report.md").read_text()


def test_the_doctor_names_what_draws_the_pictures(monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.metadata

    from shellobstacle.cli import doctor

    assert doctor._pictures().startswith(f"pyvista {importlib.metadata.version('pyvista')}, vtk ")
    version = importlib.metadata.version

    def without(name: str) -> str:
        if name == "pyvista":
            raise importlib.metadata.PackageNotFoundError(name)
        return version(name)

    monkeypatch.setattr(importlib.metadata, "version", without)
    assert doctor._pictures() == (
        "off (pyvista is not installed: pip install 'shellobstacle[pictures]')"
    )
