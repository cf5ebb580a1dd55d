"""Pictures and cross-sections show the obstacle, whatever its kind: the surface drawn for a
ball lies on the ball, the contact zone's outline lies on it, a cross-section carries the
ball's profile, and a solve of examples/cap_on_ball.toml draws both.

Serial: the samples are taken on rank 0, the command line runs serially here.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from mpi4py import MPI

import matplotlib.image
import numpy as np
import pytest
from conftest import make_paper_shell as paper_shell
from conftest import square

from shellobstacle.api import solve_problem
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.obstacle import Cylinder, ExpressionObstacle, Sphere
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post import pictures
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.obstacle_shape import onto, profile_below
from shellobstacle.post.plotting import plot_cross_section
from shellobstacle.post.sections import CrossSection, cross_section
from shellobstacle.spec import Obstacle

COMM = MPI.COMM_WORLD
BALL = Obstacle(kind="sphere", center=(0.0, 0.0, -2.0), radius=2.0, side="outside")
CAP_ON_BALL = Path(__file__).parents[2] / "examples" / "cap_on_ball.toml"

pytestmark = pytest.mark.skipif(COMM.size > 1, reason="serial: samples and drawing on one rank")


@pytest.fixture(scope="module")
def ball() -> PenalizedProblem:
    """The paper's cap on the 24 × 24 square pressed onto the ball of radius 2 (κ = h^1.5)."""
    shell = dataclasses.replace(paper_shell(), obstacle=BALL)
    r = solve_problem(shell, square(COMM), PenaltySpec(exponent=1.5))
    assert r.converged, r.error
    return r.problem


def _numpy():
    """A NumPy geometry: g is a function of space, the geometry only names the backend."""
    return paper_shell().surface.geometry_numpy(np.zeros((1, 2)))


def _box(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples' box around points ``x``: their bounding box widened as the pictures do."""
    lo, hi = x.min(axis=0), x.max(axis=0)
    pad = pictures.MARGIN * float(np.max(hi - lo))
    return lo - pad, hi + pad


def test_points_moved_onto_a_ball_a_cylinder_and_a_paraboloid_lie_on_them() -> None:
    """Newton steps along ∇g end on g = 0 with unit normals ∇g/|∇g|: exact in one step for
    the signed distances, to round-off in three for a formula."""
    rng = np.random.default_rng(1)
    x = rng.uniform(-0.5, 0.5, (200, 3))
    sphere = Sphere((0.0, 0.0, -2.0), 2.0)
    G = _numpy()
    on, normal = onto(sphere, G, x)
    assert np.allclose(np.linalg.norm(on - sphere.center, axis=1), 2.0, rtol=0, atol=1e-14)
    assert np.allclose(normal, (on - sphere.center) / 2.0, rtol=0, atol=1e-14)
    cylinder = Cylinder((0.0, 0.0, -1.0), (1.0, 0.0, 0.0), 1.0)
    on, _ = onto(cylinder, G, x)
    assert np.allclose(np.hypot(on[:, 1], on[:, 2] + 1.0), 1.0, rtol=0, atol=1e-14)
    paraboloid = ExpressionObstacle("x3 + 0.5*(x1**2 + x2**2)")
    on, normal = onto(paraboloid, G, x * 0.2)
    assert np.abs(on[:, 2] + 0.5 * (on[:, 0] ** 2 + on[:, 1] ** 2)).max() < 1e-13
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0)


def test_the_surface_drawn_for_a_ball_lies_on_the_ball(ball: PenalizedProblem) -> None:
    """The contour g = 0 of the samples is the sphere |x − c| = R to the grid's accuracy
    (linear interpolation of the distance along a grid edge: ≤ h²/(8R)), and it spans the
    box across the shell (the ball's cap under it, not a fragment)."""
    pytest.importorskip("pyvista")
    from shellobstacle.post.render3d import obstacle_surface

    data = pictures.gather_surface(Postprocessor(ball))
    assert data.level is not None and data.box is not None
    surface = obstacle_surface(data.arrays())
    h = float(data.box[1, 0])
    r = np.linalg.norm(np.asarray(surface.points) - BALL.center, axis=1)
    assert surface.n_points > 1000
    assert np.abs(r - BALL.radius).max() <= h**2 / (8 * BALL.radius) + 1e-12
    lo, hi = _box(data.points)
    reach = np.asarray(surface.points)[:, :2]
    assert np.allclose(reach.min(axis=0), lo[:2], atol=h) and np.allclose(
        reach.max(axis=0), hi[:2], atol=h
    )
    # the samples are g on the grid: one of them, by its index
    origin, spacing = data.box
    i, j, k = (np.array(data.level.shape) * [0.3, 0.6, 0.2]).astype(int)
    x = origin + spacing * [i, j, k]
    assert data.level[i, j, k] == pytest.approx(np.linalg.norm(x - BALL.center) - 2.0, abs=1e-14)


def test_the_contact_outline_lies_on_the_ball(ball: PenalizedProblem) -> None:
    """The outline's points are the boundary vertices of the touching cells moved onto the
    sphere and lifted along its normal by the tube's radius: |x − c| = R + radius."""
    pytest.importorskip("pyvista")
    from shellobstacle.post.render3d import contact_mark

    data = pictures.gather_surface(Postprocessor(ball))
    arrays = data.arrays()
    mark = contact_mark(arrays, arrays["triangles"], arrays["q"], 0.01)
    assert mark is not None and not isinstance(mark, np.ndarray), "a zone some cells wide"
    r = np.linalg.norm(np.asarray(mark.points) - BALL.center, axis=1)
    assert mark.n_points >= 4 and np.allclose(r, 2.01, rtol=0, atol=1e-13)
    # they come from contact vertices: within the penalty's penetration of the ball
    nearest = np.linalg.norm(data.points[:, None] - np.asarray(mark.points)[None], axis=2)
    assert nearest.min(axis=0).max() < 0.01 + 10 * abs(min(data.gap.min(), 0.0)) + 1e-6


def test_the_profile_below_a_line_is_the_ball_s_upper_surface() -> None:
    """Scanning down from above a ball finds its top, from inside a ball its bottom; a line
    that misses the ball gives NaN."""
    G = _numpy()
    s = np.array([0.0, 0.5, 1.9, 2.5])
    base = np.column_stack([s, np.zeros(4), np.zeros(4)])
    z = profile_below(Sphere((0, 0, -2.0), 2.0), G, base, (0, 0, 1), 1.0, -5.0)
    expected = -2.0 + np.sqrt(4.0 - s[:3] ** 2)
    assert np.allclose(z[:3], expected, rtol=0, atol=1e-12) and np.isnan(z[3])
    inside = Sphere((0, 0, 0.0), 2.0, side="inside")
    z = profile_below(inside, G, base[:3], (0, 0, 1), 3.0, -3.0)
    assert np.allclose(z, -np.sqrt(4.0 - s[:3] ** 2), rtol=0, atol=1e-12)


def test_a_cross_section_over_the_ball_carries_its_profile(
    ball: PenalizedProblem, tmp_path: Path
) -> None:
    """The profile is the ball's great circle in the section's plane x2 = 0 across the whole
    section; the deformed shell lies on or above it (up to the penalty's penetration) and
    touches it; the figure draws the profile; a plane's section carries none."""
    section = cross_section(ball, n=201)
    s, z = section.obstacle_s, section.obstacle_height
    assert s is not None and z is not None and np.isfinite(z).all()
    assert s.min() < section.deformed[:, 0].min() and s.max() > section.deformed[:, 0].max()
    w = float(np.mean(section.deformed[:, 1]))
    assert np.allclose(z, -2.0 + np.sqrt(4.0 - s**2 - w**2), rtol=0, atol=1e-12)
    under = np.interp(section.deformed[:, 0], s, z)
    above = section.deformed[:, 2] - under
    penetration = abs(min(float(section.height_deformed.min()), 0.0))
    assert above.min() >= -penetration - 1e-4 and above.min() < 1e-3
    path = plot_cross_section([("ball", section)], section.q, tmp_path / "section.png")
    image = matplotlib.image.imread(path)[..., :3]
    grey = (np.abs(image - 0.45).max(axis=-1) < 0.03).sum()  # the profile's thick grey line
    assert grey > 2000
    # as experiment load records it (JSON) and reads it back
    from shellobstacle.io.records import jsonable

    record = json.loads(json.dumps(dataclasses.asdict(section), default=jsonable))
    back = CrossSection(
        **{k: np.asarray(v) if isinstance(v, list) else v for k, v in record.items()}
    )
    assert np.array_equal(back.obstacle_s, s) and np.array_equal(back.obstacle_height, z)
    plane = PenalizedProblem(paper_shell(), square(COMM, n=8))
    flat = cross_section(plane, n=51)
    assert flat.obstacle_s is None and flat.obstacle_height is None


def _red(image: np.ndarray) -> np.ndarray:
    rgb = image[..., :3].astype(float)
    rgb = rgb / 255.0 if rgb.max() > 1.0 else rgb
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (r > 0.35) & (r > 2.0 * g) & (r > 2.0 * b)


def test_solve_draws_the_cap_on_the_ball(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """examples/cap_on_ball.toml at h = 0.05: the picture is drawn without warning, shows the
    contact outline and the grey ball around the shell."""
    pytest.importorskip("pyvista")
    from shellobstacle.cli.main import main

    monkeypatch.setattr(pictures, "_unavailable", None)
    out = tmp_path / "run"
    args = ["solve", str(CAP_ON_BALL), "-o", str(out), "-q", "--set", "domain.h=0.05"]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert "shell_3d.png" in summary["files"]
    assert not [w for w in summary["warnings"] if "3D" in w]
    image = matplotlib.image.imread(out / "shell_3d.png")[..., :3]
    assert _red(image).sum() > 300
    # the ball's translucent grey (the plane's colour, shaded): a good part of the picture
    grey = (image.max(axis=-1) - image.min(axis=-1) < 0.04) & (image.mean(axis=-1) < 0.85)
    grey &= image.mean(axis=-1) > 0.5
    assert grey.mean() > 0.1


def test_a_shifted_plane_is_drawn_from_its_samples_at_its_height() -> None:
    """Only the plane x·q = 0 takes the plane's square; x·q = c ≠ 0 (and a plane written as a
    formula) is contoured from its samples, which put it at its height, with no height lines."""
    pytest.importorskip("pyvista")
    from shellobstacle.obstacle import Plane
    from shellobstacle.post.render3d import _height_lines, obstacle_surface

    q = np.array([0.6, 0.0, 0.8])  # tilted: its heights x·q carry round-off
    assert pictures.drawn_as_plane(Plane(q))
    assert not pictures.drawn_as_plane(Plane(q, -0.1))
    assert not pictures.drawn_as_plane(ExpressionObstacle("x3"))
    rng = np.random.default_rng(2)
    points = rng.uniform(-0.25, 0.25, (300, 3)) * [1.0, 1.0, 0.3] + [0.0, 0.0, 0.1]
    shifted = Plane(q, -0.1)
    gap = points @ q + 0.1
    samples = pictures.obstacle_samples(shifted, paper_shell().surface, points, gap)
    assert np.allclose(samples["onto"] @ q, -0.1, rtol=0, atol=1e-14)
    assert np.allclose(samples["normal"], q)
    surface = obstacle_surface(samples)
    assert surface.n_points > 100
    # VTK's contour points are single precision
    assert np.allclose(np.asarray(surface.points) @ q, -0.1, rtol=0, atol=1e-6)
    assert _height_lines(surface, q).n_points == 0
    ball = obstacle_surface(
        pictures.obstacle_samples(
            Sphere(BALL.center, 2.0), paper_shell().surface, points, points[:, 2]
        )
    )
    assert _height_lines(ball, np.array([0.0, 0.0, 1.0])).n_points > 100


def test_an_obstacle_out_of_the_box_is_not_drawn_and_the_views_are(ball: PenalizedProblem) -> None:
    """g > 0 on the whole box (the obstacle far from the shell): no surface, both views."""
    pytest.importorskip("pyvista")
    from shellobstacle.post.render3d import obstacle_surface, render

    data = pictures.gather_surface(Postprocessor(ball)).arrays()
    data["level"] = np.abs(data["level"]) + 1.0
    assert obstacle_surface(data).n_points == 0
    views = render(data)
    assert views["whole"].ndim == 3 and views["close"].ndim == 3 and bool(views["curved"])
