"""The validity measures of a solution (shellobstacle.post.validity) and solve's exit status 3.

The measures are checked on displacements whose values are known in closed form (a rigid
translation, a mirror image), then on solves inside and far outside the model's validity,
serially and on 2 ranks.
"""

from __future__ import annotations

import json
from pathlib import Path

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
import ufl

from shellobstacle.api import make_mesh
from shellobstacle.cli.main import EXIT_INVALID, EXIT_OK, main
from shellobstacle.config.loader import load_config
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.validity import THRESHOLDS, TRIVIAL, assess

SMALL = Path(__file__).parents[1] / "examples" / "small.toml"
#: a uniform pressure 1000 times the peak of the paper's load (examples/small.toml)
CRUSHING = "load.p=['0', '0', '-1000*(2*epsilon/25)*0.295']"


@pytest.fixture(scope="module")
def paper_problem() -> PenalizedProblem:
    cfg = load_config(SMALL, ["domain.h=0.08"])
    return PenalizedProblem(cfg.shell, make_mesh(cfg.domain), cfg.discretization, kappa=1e-3)


def _set_cartesian(problem: PenalizedProblem, U) -> None:
    """ζ_i = U·a_i: the covariant components of the Cartesian displacement ``U`` (UFL)."""
    G = problem.G
    zeta = ufl.as_vector(
        [ufl.dot(U, ufl.as_vector(G.a_cov[i] if i < 2 else G.a3)) for i in range(3)]
    )
    problem.zeta.interpolate(dolfinx.fem.Expression(zeta, problem.V.element.interpolation_points))
    problem.zeta.x.scatter_forward()


def _theta_extent(problem: PenalizedProblem) -> tuple[float, float]:
    """(diam of θ at the vertices, max θ·q): the scales of the measures."""
    comm = problem.mesh.comm
    x = problem.mesh.geometry.x[:, :2]
    theta = np.asarray(problem.shell.surface.theta_numpy(x))
    lo, hi = theta.min(axis=1), theta.max(axis=1)
    comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
    comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
    return float(np.linalg.norm(hi - lo)), float(hi[2])


@pytest.mark.mpi
def test_measures_of_known_displacements(paper_problem: PenalizedProblem) -> None:
    """ζ = 0 (no response to the paper's load: trivial); a rigid translation by −0.2 e₃
    (penetration 0.2 − min θ₃ over max θ₃,
    displacement 0.2 / diam θ(ω), orientation 1); the mirror image y1 → −y1 (orientation −1 at
    the centre, where the cap is flat)."""
    problem = paper_problem
    post = Postprocessor(problem)
    size, height = _theta_extent(problem)
    problem.zeta.x.array[:] = 0.0
    v = assess(post, 1e-3)
    assert v.penetration == 0.0 and v.displacement == 0.0
    assert v.orientation == pytest.approx(1.0, abs=1e-12)
    assert v.loaded and v.violations == ["trivial"]
    assert "material.epsilon" in v.warnings()[0] and "solver.atol" in v.warnings()[0]

    x = ufl.SpatialCoordinate(problem.mesh)
    _set_cartesian(problem, ufl.as_vector([0.0, 0.0, -0.2 + 0.0 * x[0]]))
    v = assess(post, 1e-3)
    rim = np.sqrt(1.0 - 0.5**2) - 0.85  # θ₃ on the clamped circle |y| = 0.5
    assert v.penetration == pytest.approx((0.2 - rim) / height, rel=1e-3)
    assert v.displacement == pytest.approx(0.2 / size, rel=1e-3)
    assert v.orientation == pytest.approx(1.0, abs=1e-2)  # P1 interpolation of a_i·e₃
    assert v.violations == ["penetration"]
    assert v.penalty_ratio is not None and v.penalty_ratio > 0

    _set_cartesian(problem, ufl.as_vector([-2.0 * x[0], 0.0, 0.0]))
    v = assess(post, 1e-3)
    assert v.orientation < -0.9
    assert "orientation" in v.violations
    assert any("folds over itself" in line for line in v.warnings())


@pytest.mark.mpi
def test_the_papers_problem_is_inside_and_a_crushing_load_outside(tmp_path_factory) -> None:
    """solve: the paper's problem exits 0 with no warning; under a pressure 1000× the paper's
    peak the shell is pushed through the plane: exit 3, a warning per violated measure on the
    terminal and in summary.json, every file still written (the same on 2 ranks)."""
    comm = MPI.COMM_WORLD
    base = Path(comm.bcast(str(tmp_path_factory.mktemp("validity")) if comm.rank == 0 else None))
    ok = main(["solve", str(SMALL), "-o", str(base / "ok"), "-q", "--set", "domain.h=0.06"])
    assert ok == EXIT_OK
    comm.barrier()  # rank 0 writes the files
    summary = json.loads((base / "ok" / "summary.json").read_text())
    assert summary["validity"]["valid"] is True and summary["warnings"] == []
    assert 0 < summary["validity"]["penetration"] < THRESHOLDS["penetration"]

    out = base / "crushed"
    code = main(
        ["solve", str(SMALL), "-o", str(out), "-q", "--set", "domain.h=0.06", "--set", CRUSHING]
    )
    assert code == EXIT_INVALID
    comm.barrier()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] is True
    validity = summary["validity"]
    assert validity["valid"] is False
    assert set(validity["violations"]) == {"penetration", "displacement", "orientation"}
    assert validity["penetration"] > 0.5 and validity["displacement"] > 1.0
    assert len(summary["warnings"]) == 3
    log = (out / "log.txt").read_text()
    assert log.count("warning: outside the model's validity") == 3
    assert "exit status 3" in log
    assert (out / "cross_section.png").is_file()


def test_a_load_sweep_names_the_values_outside_the_validity(tmp_path: Path) -> None:
    """experiment load: a bump load 100 times the example's pushes the paraboloid's apex
    through the plane; the report names that value and only it, the log warns."""
    if MPI.COMM_WORLD.size > 1:
        pytest.skip("serial")
    out = tmp_path / "sweep"
    paraboloid = str(Path(__file__).parents[1] / "examples" / "paraboloid.toml")
    args = ["experiment", "load", paraboloid, "-q", "-o", str(out), "--set", "domain.h=0.06"]
    assert main([*args, "--parameter", "ell", "--values", "40,4000"]) == EXIT_OK
    report = (out / "report.md").read_text()
    assert "**Outside the model's validity**" in report
    assert "ell = 4000 (penetration)" in report and "ell = 40 (" not in report
    log = (out / "log.txt").read_text()
    assert log.count("warning: ell = 4000: outside the model's validity") == 1
    assert "warning: ell = 40:" not in log


@pytest.mark.mpi
def test_the_python_api_measures_a_solve() -> None:
    """SolveResult.validity(): the paper's problem inside, the crushing load outside."""
    from shellobstacle.api import solve_config

    inside = solve_config(load_config(SMALL, ["domain.h=0.06"])).validity()
    outside = solve_config(load_config(SMALL, ["domain.h=0.06", CRUSHING])).validity()
    assert inside.valid and inside.warnings() == []
    assert set(outside.violations) == {"penetration", "displacement", "orientation"}


#: the paper's load is ∝ ε: at ε = 1e-40 the load vector (about 1e-43) is below Newton's
#: absolute tolerance (1e-30), which "converged" in 0 steps to ζ = 0 with exit 0
TINY = ["domain.h=0.08", "material.epsilon=1e-40"]


@pytest.mark.mpi
def test_material_constants_too_small_give_an_invalid_trivial_solution(shared_dir) -> None:
    """exit 3 and a warning naming the material keys (not "valid" and exit 0); the paper's
    constants at the same size are valid (the test above)."""
    out = shared_dir / "tiny"
    args = ["solve", str(SMALL), "-o", str(out), "-q"]
    code = main([*args, *(x for item in TINY for x in ("--set", item))])
    MPI.COMM_WORLD.barrier()
    summary = json.loads((out / "summary.json").read_text())
    assert code == EXIT_INVALID, summary
    assert summary["validity"]["violations"] == ["trivial"]
    assert summary["validity"]["displacement"] < TRIVIAL
    (warning,) = summary["warnings"]
    assert all(k in warning for k in ("material.epsilon", "material.lambda", "material.mu"))


@pytest.mark.mpi
def test_an_unloaded_shell_at_rest_is_valid() -> None:
    """p = 0: ζ = 0 is the solution, not a trivial one."""
    from shellobstacle.api import solve_config

    cfg = load_config(SMALL, ["domain.h=0.08", "load.p=['0', '0', '0']"])
    validity = solve_config(cfg).validity()
    assert not validity.loaded and validity.displacement == 0.0 and validity.valid
