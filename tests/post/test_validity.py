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
from shellobstacle.cli.main import EXIT_FAILED, EXIT_INVALID, EXIT_OK, main
from shellobstacle.config.loader import load_config
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.validity import THRESHOLDS, TRIVIAL, assess

SMALL = Path(__file__).parents[2] / "examples" / "small.toml"
#: a uniform pressure 1000 times the peak of the paper's load (examples/small.toml)
CRUSHING = "load.p=['0', '0', '-1000*(2*epsilon/25)*0.295']"
#: the validity, not the 3D picture (tests/post/test_pictures.py), is under test here
NO_PICTURES = ["--set", "output.pictures=false"]


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
    assert "material.epsilon" in v.warnings()[0] and "[load] p" in v.warnings()[0]

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
    """solve: the paper's problem exits 0 with one warning only, that it is beyond linear
    kinematics (tests/post/test_nonlinearity.py); under a pressure 1000× the paper's
    peak the shell is pushed through the plane: exit 3, a warning per violated measure on the
    terminal and in summary.json, every file still written (the same on 2 ranks)."""
    comm = MPI.COMM_WORLD
    base = Path(comm.bcast(str(tmp_path_factory.mktemp("validity")) if comm.rank == 0 else None))
    args = ["solve", str(SMALL), "-q", *NO_PICTURES, "--set", "domain.h=0.06"]
    ok = main([*args, "-o", str(base / "ok")])
    assert ok == EXIT_OK
    comm.barrier()  # rank 0 writes the files
    summary = json.loads((base / "ok" / "summary.json").read_text())
    assert summary["validity"]["valid"] is True
    assert [w.split(":")[0] for w in summary["warnings"]] == ["beyond linear kinematics"]
    assert 0 < summary["validity"]["penetration"] < THRESHOLDS["penetration"]

    out = base / "crushed"
    code = main([*args, "-o", str(out), "--set", CRUSHING])
    assert code == EXIT_INVALID
    comm.barrier()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] is True
    validity = summary["validity"]
    assert validity["valid"] is False
    assert set(validity["violations"]) == {"penetration", "displacement", "orientation"}
    assert validity["penetration"] > 0.5 and validity["displacement"] > 1.0
    assert len(summary["warnings"]) == 4  # and beyond linear kinematics
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
    paraboloid = str(Path(__file__).parents[2] / "examples" / "paraboloid.toml")
    args = ["experiment", "load", paraboloid, "-q", "-o", str(out), "--set", "domain.h=0.06"]
    args += NO_PICTURES
    assert main([*args, "--parameter", "ell", "--values", "40,4000"]) == EXIT_OK
    report = (out / "report.md").read_text()
    assert "**Outside the model's validity**" in report
    assert "ell = 4000 (penetration)" in report and "ell = 40 (" not in report
    log = (out / "log.txt").read_text()
    assert log.count("warning: ell = 4000: outside the model's validity") == 1
    assert "warning: ell = 40: outside" not in log


@pytest.mark.mpi
def test_the_python_api_measures_a_solve() -> None:
    """SolveResult.validity: the paper's problem inside, the crushing load outside."""
    from shellobstacle.api import solve

    inside = solve(load_config(SMALL, ["domain.h=0.06"])).validity
    outside = solve(load_config(SMALL, ["domain.h=0.06", CRUSHING])).validity
    assert inside.valid and [w.split(":")[0] for w in inside.warnings()] == [
        "beyond linear kinematics"
    ]
    assert set(outside.violations) == {"penetration", "displacement", "orientation"}


def _solve(folder: Path, *settings: str) -> tuple[int, dict]:
    """``solve`` of examples/small.toml at h = 0.08 with ``settings``: the exit code and the
    summary."""
    args = ["solve", str(SMALL), "-o", str(folder), "-q", "--set", "domain.h=0.08", *NO_PICTURES]
    code = main([*args, *(x for item in settings for x in ("--set", item))])
    MPI.COMM_WORLD.barrier()  # rank 0 writes the files
    return code, json.loads((folder / "summary.json").read_text())


def _steps(summary: dict) -> list[int]:
    return [stage["iterations"] for stage in summary["continuation"]]


@pytest.mark.mpi
def test_newton_stops_relative_to_the_problem_s_scale(shared_dir) -> None:
    """The paper's load is ∝ ε, so ε = 1e-40 multiplies the whole problem (load vector about
    1e-43) by 1e-37 and leaves its solution unchanged: the same Newton steps and the same
    solution. (An absolute tolerance of 1e-30 stopped it at ζ = 0 in 0 steps.)"""
    code, paper = _solve(shared_dir / "paper")
    tiny_code, tiny = _solve(shared_dir / "tiny", "material.epsilon=1e-40")
    assert code == tiny_code == EXIT_OK, tiny["warnings"]
    assert _steps(tiny) == _steps(paper) and min(_steps(paper)) >= 1
    for key in ("contact_area", "zeta3_min"):
        assert tiny[key] == pytest.approx(paper[key], rel=1e-8)
    assert tiny["validity"]["displacement"] == pytest.approx(
        paper["validity"]["displacement"], rel=1e-8
    )


#: the paper's load times 1e-30 (examples/small.toml): a displacement of 1e-31 of the shell's size
FAINT = "load.p=['0', '0', '-1e-30*Piecewise((2*epsilon/25*(0.295-5*r**2), r < 0.06), (0, True))']"


@pytest.mark.mpi
def test_a_load_too_small_for_the_material_is_flagged_trivial(shared_dir) -> None:
    """exit 3 and one warning naming the load and the material keys, not "valid" and exit 0;
    the solve itself is a converged one (the response is linear in the load)."""
    code, summary = _solve(shared_dir / "faint", FAINT)
    assert code == EXIT_INVALID, summary
    assert summary["converged"] is True and max(_steps(summary)) >= 1
    assert summary["validity"]["violations"] == ["trivial"]
    assert 0 < summary["validity"]["displacement"] < TRIVIAL
    (warning,) = summary["warnings"]
    assert "\n" not in warning
    assert all(k in warning for k in ("[load] p", "material.epsilon", "material.lambda"))


@pytest.mark.mpi
def test_lame_constants_beyond_double_precision_are_refused(shared_dir) -> None:
    """λ = μ = 1e-300: the Newton direction ``K⁻¹ R`` overflows; it was taken for a decrement
    below round-off ("converged" in 0 steps at ζ = 0). Now the solve fails: exit 1 and one line
    saying why."""
    lame = ("material.lambda=1e-300", "material.mu=1e-300")
    code, summary = _solve(shared_dir / "lame", *lame)
    assert code == EXIT_FAILED, summary
    assert summary["converged"] is False and _steps(summary) == [0]
    assert "the Newton direction overflows" in summary["error"]
    assert "singular at the scale of the load" in summary["error"]
    assert "\n" not in summary["error"]


@pytest.mark.mpi
def test_an_unloaded_shell_at_rest_is_valid() -> None:
    """p = 0: ζ = 0 is the solution, not a trivial one."""
    from shellobstacle.api import solve
    from shellobstacle.solvers.newton.solver import ZERO_LOAD

    cfg = load_config(SMALL, ["domain.h=0.08", "load.p=['0', '0', '0']"])
    result = solve(cfg)
    validity = result.validity
    assert not validity.loaded and validity.displacement == 0.0 and validity.valid
    assert {(step.iterations, step.reason) for step in result.steps} == {(0, ZERO_LOAD)}
