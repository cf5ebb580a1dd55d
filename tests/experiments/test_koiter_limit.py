"""Koiter's model against the membrane model as ε → 0 (``experiment koiter-limit``)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
from conftest import make_paper_shell

from shellobstacle.cli.main import main
from shellobstacle.experiments.boundary_layer import distance_to_boundary, layer_width
from shellobstacle.geometry.surface import Surface
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.spec import Discretization, Load, Material, Shell

COMM = MPI.COMM_WORLD
PAPER = Path(__file__).parents[2] / "examples" / "paper.toml"


def test_layer_width_of_an_exponential_layer() -> None:
    """ζ_K = ζ_M (1 − e^{−d/ℓ}) reaches half of ζ_M at d = ℓ ln 2."""
    d = np.linspace(0.0, 0.2, 2001)
    membrane = 1e-3 * (1 + d)
    for ell in (0.005, 0.02):
        koiter = membrane * (1 - np.exp(-d / ell))
        assert layer_width(d[::-1], koiter[::-1], membrane[::-1]) == pytest.approx(
            ell * math.log(2), rel=1e-3
        )
    assert math.isnan(layer_width(d, -membrane, membrane))  # bending keeps it on the other side


@pytest.mark.skipif(COMM.size > 1, reason="one mesh, serial")
def test_distance_to_boundary_on_a_disk() -> None:
    mesh = create_mesh(DomainSpec("disk", h=0.05, radius=0.5))
    dist = distance_to_boundary(mesh)
    n = mesh.topology.index_map(2).size_local
    mid = dolfinx.mesh.compute_midpoints(mesh, 2, np.arange(n, dtype=np.int32))[:, :2]
    exact = 0.5 - np.linalg.norm(mid, axis=1)
    # the boundary is sampled at its vertices (spacing ≤ 0.05): within a sagitta and a half-chord
    assert np.abs(dist.x.array[:n] - exact).max() < 0.03
    assert dist.x.array[:n].min() > 0


@pytest.mark.slow  # Koiter's P2 forms compiled and solved at three ε
def test_bending_scale_is_koiter_at_another_thickness() -> None:
    """With the load and penalty ∝ ε, scaling the bending energy by (ε'/ε)² gives Koiter's
    solution at ε' (computed with its own compiled forms)."""
    mesh = dolfinx.mesh.create_rectangle(
        COMM,
        [[-0.25, -0.25], [0.25, 0.25]],
        [8, 8],
        ghost_mode=dolfinx.mesh.GhostMode.shared_facet,
    )

    def solve(eps: float, scale: float | None = None) -> np.ndarray:
        shell = make_paper_shell(model="koiter", epsilon=eps)
        problem = PenalizedProblem(shell, mesh, Discretization(degree=2))
        if scale is not None:
            problem.set_bending_scale(scale)
        continuation(problem, NewtonSolver(problem), [1e-1, 1e-2, 1e-3])
        return problem.zeta.x.array.copy()

    direct, scaled = solve(1e-2), solve(1e-3, scale=100.0)
    unscaled = solve(1e-3)
    size = np.sqrt(COMM.allreduce(np.sum(direct**2)))
    assert np.sqrt(COMM.allreduce(np.sum((direct - scaled) ** 2))) < 1e-8 * size
    assert np.sqrt(COMM.allreduce(np.sum((direct - unscaled) ** 2))) > 1e-2 * size


def test_bending_scale_needs_koiter_and_a_positive_scale() -> None:
    mesh = dolfinx.mesh.create_unit_square(COMM, 2, 2)
    shell = Shell(
        Surface.spherical_cap(1.0, 0.85), Material(1e-3, 0.4, 0.012), Load(("0", "0", "-1e-4"))
    )
    with pytest.raises(ValueError, match="only Koiter's model"):
        PenalizedProblem(shell, mesh).set_bending_scale(2.0)


@pytest.fixture(scope="module")
def koiter_limit_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("kl") / "out"
    if COMM.size > 1:
        out = Path(COMM.bcast(str(out)))
    args = ["experiment", "koiter-limit", str(PAPER), "-o", str(out), "-q"]
    args += ["--set", "domain.h=0.08", "--epsilons", "1e-1,1e-2,1e-3", "--edge-h", "0.02"]
    assert main(args) == 0
    COMM.barrier()  # rank 0 writes the files
    return out


@pytest.mark.slow  # the experiment at three ε
@pytest.mark.mpi
def test_koiter_tends_to_the_membrane_on_the_papers_problem(koiter_limit_run: Path) -> None:
    """‖ζ_K(ε) − ζ_M‖_{V_M} falls as ε does; the thick shells do not reach the plane (the
    experiment runs on ghosted meshes under MPI)."""
    with open(koiter_limit_run / "koiter_limit.csv") as f:
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]
    assert [r["epsilon"] for r in rows] == [1e-1, 1e-2, 1e-3]
    distance = [r["distance_VM"] for r in rows]
    assert distance[0] > distance[1] > distance[2], distance
    assert rows[0]["relative"] > 0.5  # ε = 0.1: bending dominates
    assert rows[0]["contact_area_koiter"] == 0
    report = (koiter_limit_run / "report.md").read_text()
    assert "## Koiter's model and the membrane limit" in report
    for name in ("koiter_limit.png", "koiter_limit_layer.png", "config.toml", "log.txt"):
        assert (koiter_limit_run / name).is_file(), name
    # Koiter's solution at the config's ε = 1e-3 in 3D (gathered from every rank)
    assert (koiter_limit_run / "koiter_limit_shell_3d.png").stat().st_size > 20_000
    assert "(koiter_limit_shell_3d.png)" in report


@pytest.mark.parametrize(
    "bad",
    [
        ["--epsilons", "0,1e-2"],
        ["--epsilons", ""],
        ["--edge-h", "-1"],
        ["--set", "solver.linear_solver='iterative'"],
    ],
)
def test_koiter_limit_refuses_bad_options(tmp_path: Path, bad: list[str]) -> None:
    out = tmp_path / "x"
    assert main(["experiment", "koiter-limit", str(PAPER), "-o", str(out), "-q", *bad]) == 2


@pytest.mark.skipif(COMM.size > 1, reason="serial")
def test_koiter_limit_verbose_prints_each_newton_step(tmp_path: Path) -> None:
    """-v: a line per Newton iteration of every solve, in log.txt too."""
    out = tmp_path / "verbose"
    args = ["experiment", "koiter-limit", str(PAPER), "-o", str(out), "-v"]
    args += ["--set", "domain.h=0.1", "--epsilons", "1e-1", "--edge-h", "0.05"]
    assert main([*args, "--set", "output.pictures=false"]) == 0
    log = (out / "log.txt").read_text()
    assert "Newton 1: relative residual" in log and "Newton: " in log


@pytest.mark.skipif(COMM.size > 1, reason="two runs, serial")
def test_the_bending_form_of_the_config_reaches_the_experiment(tmp_path: Path, capsys) -> None:
    """``discretization.bending`` of a membrane config sets Koiter's bending form in
    koiter-limit (not a constant of the experiment), without a warning that it is ignored."""
    rows = {}
    for bending in ("hybrid", "c0ip"):
        out = tmp_path / bending
        args = ["experiment", "koiter-limit", str(PAPER), "-o", str(out), "-q"]
        args += ["--set", "domain.h=0.1", "--set", "output.pictures=false"]
        args += ["--set", f"discretization.bending={bending}", "--epsilons", "1e-2"]
        assert main([*args, "--edge-h", "0.05"]) == 0
        assert "ignored" not in capsys.readouterr().err
        with open(out / "koiter_limit.csv") as f:
            rows[bending] = {k: float(v) for k, v in next(csv.DictReader(f)).items()}
        assert f'bending = "{bending}"' in (out / "config.toml").read_text()
    hybrid, c0ip = rows["hybrid"], rows["c0ip"]
    # the membrane solutions do not depend on the bending form, Koiter's does (O(h) apart)
    assert hybrid["contact_area_membrane"] == c0ip["contact_area_membrane"]
    assert hybrid["distance_VM"] != c0ip["distance_VM"]
    assert hybrid["distance_VM"] == pytest.approx(c0ip["distance_VM"], rel=0.05)


@pytest.mark.skipif(COMM.size > 1, reason="serial")
def test_the_commands_study_is_small_unless_full(monkeypatch, tmp_path: Path) -> None:
    """``experiment koiter-limit examples/paper.toml`` scales the config's sizes up alike to
    at most FAST_DOFS dofs (its own sizes give 0.71 M); ``--full`` keeps them. The command
    solves on the mesh its options describe."""
    from shellobstacle.cli.parser import parser
    from shellobstacle.config.loader import load_config
    from shellobstacle.experiments import koiter_limit
    from shellobstacle.experiments.boundary_layer import EDGE_FRACTION, graded_domain
    from shellobstacle.experiments.options import experiment_domains, experiment_options
    from shellobstacle.mesh.resources import estimate

    cfg = load_config(PAPER)

    def study(*extra: str) -> tuple[DomainSpec, list[float]]:
        args = parser().parse_args(["experiment", "koiter-limit", str(PAPER), *extra])
        options = experiment_options(args, cfg)
        [domain] = experiment_domains(args, cfg, options)
        return domain, options["--epsilons"]

    (fast, epsilons), (full, _) = study(), study("--full")
    assert full == graded_domain(cfg.domain, epsilons)
    assert estimate(fast, "koiter", 2).dofs <= koiter_limit.FAST_DOFS
    assert estimate(full, "koiter", 2).dofs > 5 * koiter_limit.FAST_DOFS
    assert fast.h > cfg.domain.h and fast.edge_h == pytest.approx(EDGE_FRACTION * fast.h)
    assert fast.edge_width == full.edge_width  # the band of the smallest ε's layer

    solved: list[DomainSpec] = []

    def run_koiter_limit(cfg, folder, domain, *_args, **_kwargs) -> str:
        solved.append(domain)
        return ""

    monkeypatch.setattr(koiter_limit, "run_koiter_limit", run_koiter_limit)
    assert main(["experiment", "koiter-limit", str(PAPER), "-q", "-o", str(tmp_path / "x")]) == 0
    assert solved == [fast]
