"""The Brezis–Sibony iteration (docs/model.md §6, the paper's (38)) against Newton's solution.

A 6×6 square of the paper's shell and material, with the paper's load widened to
``|y| < 0.15`` so that five vertices touch the plane, and ``κ = 1e-2``: about 2·10⁴ steps
(a few seconds) with the consistent mass.
"""

from __future__ import annotations

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
from conftest import make_paper_shell as paper_shell
from conftest import square

from shellobstacle.experiments.solvers import compare_solvers, write_solver_comparison
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.norms import l2_norm
from shellobstacle.solvers.brezis_sibony.iteration import BrezisSibonyOptions, BrezisSibonySolver
from shellobstacle.solvers.brezis_sibony.result import BrezisSibonyResult
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver

LOAD = "Piecewise((-(2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.15), (0, True))"
KAPPA = 1e-2
N = 6


def newton_reference(comm: MPI.Comm) -> tuple[PenalizedProblem, dolfinx.fem.Function, float]:
    """The problem, Newton's solution (a copy) and h, on ``comm``."""
    mesh = square(comm, n=N)
    problem = PenalizedProblem(paper_shell(LOAD), mesh, kappa=KAPPA)
    continuation(problem, NewtonSolver(problem), [1.0, 1e-1, KAPPA])
    assert Postprocessor(problem).contact()["num_contact_nodes"] >= 5
    ref = dolfinx.fem.Function(problem.V)
    ref.x.array[:] = problem.zeta.x.array
    return problem, ref, mesh_size(mesh)


def relative_difference(problem: PenalizedProblem, ref: dolfinx.fem.Function) -> float:
    return l2_norm(problem.zeta - ref) / l2_norm(ref)


@pytest.fixture(scope="module")
def reference() -> tuple[PenalizedProblem, dolfinx.fem.Function, float]:
    return newton_reference(MPI.COMM_WORLD)


@pytest.fixture(scope="module")
def consistent(reference) -> tuple[BrezisSibonyResult, float, float]:
    """One converged run with the consistent mass: the result, its L² distance to Newton's
    solution (absolute) and the norm of Newton's solution."""
    problem, ref, h = reference
    seen: list[tuple[int, float]] = []
    opts = BrezisSibonyOptions(rtol=1e-12, rtol_residual=0.0, progress_every=5000)
    result = BrezisSibonySolver(problem, h, opts).solve(progress=lambda k, d: seen.append((k, d)))
    assert [k for k, _ in seen] == list(range(5000, result.iterations + 1, 5000))
    return result, l2_norm(problem.zeta - ref), l2_norm(ref)


def test_converges_to_newton(consistent) -> None:
    """(38) from the linearized start reaches Newton's solution of the penalized problem."""
    result, difference, norm = consistent
    assert result.converged, result.reason
    assert result.iterations > 1000  # the contact makes it nonlinear: not solved by the start
    assert difference < 1e-8 * norm
    assert result.relative_residual < 1e-8


def test_every_step_contracts_within_the_bound(consistent) -> None:
    """Every increment ratio is < 1, and none exceeds the bound max|1 − τλ| (no slack needed:
    R is piecewise linear, so R(ψ) − R(φ) = J̄(ψ − φ) exactly with K ≤ J̄ ≤ K + P_all)."""
    result, difference, _ = consistent
    increments = np.asarray(result.increments)
    assert len(increments) == result.iterations and result.increment_stride == 1
    ratios = increments[1:] / increments[:-1]
    assert np.all(ratios < 1.0)
    assert ratios.max() == pytest.approx(result.max_ratio, rel=1e-15)
    assert result.max_ratio <= result.contraction_bound < 1.0
    assert result.contraction_factor <= result.contraction_bound
    assert result.contraction_factor_tail <= result.contraction_bound
    # hence the a posteriori bound ρ/(1 − ρ) Δ_n covers the true error
    assert difference <= result.error_estimate


def test_automatic_step_is_below_two_over_lambda_max(consistent, reference) -> None:
    """τ λ_max = 2/(1 + s) < 2 and Ξ = τ / h⁴."""
    result, _, _ = consistent
    _, _, h = reference
    assert result.tau * result.lambda_max < 2.0
    assert result.tau * result.lambda_max == pytest.approx(2.0 / 1.1)
    assert result.xi == pytest.approx(result.tau / h**4)
    assert 0 < result.lambda_min < result.lambda_max


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="dense check on one process")
def test_spectrum_brackets_the_jacobian(reference) -> None:
    """SLEPc's λ_min, λ_max equal dense ones (λ_max of K + (1/κ) Mᵀ diag(1/D) M, the
    Jacobian with every penalty point active, formed densely from the point matrix), and
    bracket the Jacobian's spectrum at Newton's solution."""
    problem, ref, h = reference
    solver = BrezisSibonySolver(problem, h)
    lam_min, lam_max = solver.spectrum()
    free = np.flatnonzero(solver.free.array_r == 1.0)

    def dense(form) -> np.ndarray:
        A = dolfinx.fem.petsc.assemble_matrix(form, bcs=problem.bcs)
        A.assemble()
        return A.convert("dense").getDenseArray()[np.ix_(free, free)]

    M = solver.M.convert("dense").getDenseArray()[np.ix_(free, free)]
    L = np.linalg.cholesky(M)

    def eigenvalues(A: np.ndarray) -> np.ndarray:
        X = np.linalg.solve(L, np.linalg.solve(L, A).T)
        return np.linalg.eigvalsh(0.5 * (X + X.T))

    assert eigenvalues(dense(problem.forms["stiffness"]))[0] == pytest.approx(lam_min, rel=1e-6)
    pen = solver.penalty
    points = pen.M.convert("dense").getDenseArray()
    all_active = (points.T / pen.D) @ points / float(problem.kappa.value)
    safe = dense(problem.forms["stiffness"]) + all_active[np.ix_(free, free)]
    assert eigenvalues(safe)[-1] == pytest.approx(lam_max, rel=1e-6)
    problem.zeta.x.array[:] = ref.x.array
    at_solution = eigenvalues(dense(problem.forms["jacobian"]))
    assert lam_min <= at_solution[0] * (1 + 1e-8)
    assert at_solution[-1] <= lam_max * (1 + 1e-8)


def check_residual_is_the_forms(problem: PenalizedProblem, ref, h: float) -> None:
    """The step's residual ``Kψ − L + (1/κ) Mᵀ min(g, 0)`` is the assembled residual form, at
    Newton's solution and at three times it (deeper in the plane), where the penalty is a
    large part of it."""
    solver = BrezisSibonySolver(problem, h)
    mass = solver.ksp.getPC().getFactorSolverType()
    assert mass == ("petsc" if problem.mesh.comm.size == 1 else "mumps")
    norm_load = solver._load()
    for scale in (1.0, 3.0):
        problem.zeta.x.array[:] = scale * ref.x.array
        g = solver.penalty.gap(problem.zeta.x.petsc_vec)
        assert problem.mesh.comm.allreduce(int(np.count_nonzero(g < 0))) > 0
        solver._residual()
        form = solver._form_residual()
        elastic = solver.K.createVecLeft()
        solver.K.mult(problem.zeta.x.petsc_vec, elastic)
        elastic.axpy(-1.0, solver.L)
        elastic.axpy(-1.0, form)  # minus the form's penalty part
        penalty = elastic.norm()
        assert penalty > 1e-3 * norm_load
        form.axpy(-1.0, solver.R)
        assert form.norm() <= 1e-13 * (norm_load + penalty)  # round-off of the terms' sizes
    problem.zeta.x.array[:] = ref.x.array


def test_step_residual_is_the_residual_form(reference) -> None:
    """See :func:`check_residual_is_the_forms` (serially)."""
    check_residual_is_the_forms(*reference)


@pytest.mark.mpi
def test_step_residual_is_the_residual_form_in_parallel() -> None:
    """:func:`check_residual_is_the_forms` on the distributed mesh."""
    check_residual_is_the_forms(*newton_reference(MPI.COMM_WORLD))


def test_iteration_cap_returns_the_iterate(reference) -> None:
    """At max_iterations: converged=False, the iterate in problem.zeta, the increments; a
    second run from start='current' continues exactly where the first stopped."""
    problem, _, h = reference
    opts = BrezisSibonyOptions(max_iterations=40)
    first = BrezisSibonySolver(problem, h, opts).solve()
    assert not first.converged and first.iterations == 40
    assert "no convergence in 40" in first.reason
    assert len(first.increments) == 40 and all(np.isfinite(first.increments))
    assert first.relative_residual > 1e-6
    resume = BrezisSibonyOptions(max_iterations=40, start="current")
    BrezisSibonySolver(problem, h, resume).solve()
    two_runs = problem.zeta.x.array.copy()
    straight = BrezisSibonySolver(problem, h, BrezisSibonyOptions(max_iterations=80)).solve()
    assert straight.iterations == 80
    assert straight.increments[:40] == pytest.approx(first.increments, rel=1e-12)
    assert np.allclose(problem.zeta.x.array, two_runs, rtol=1e-12, atol=0.0)


def test_lumped_mass_converges_to_the_same_solution(reference) -> None:
    """Row-sum mass (a deviation from the paper): same fixed point, its own step and bound."""
    problem, ref, h = reference
    result = BrezisSibonySolver(problem, h, BrezisSibonyOptions(mass="lumped", rtol=1e-12)).solve()
    assert result.converged, result.reason
    assert relative_difference(problem, ref) < 1e-8
    assert result.max_ratio <= result.contraction_bound < 1.0
    assert result.tau * result.lambda_max < 2.0


def test_too_large_user_step_is_reported_as_diverging(reference, consistent) -> None:
    """A user Ξ with τ λ_max = 3 > 2: the bound says so and the run stops, without raising."""
    problem, _, h = reference
    result, _, _ = consistent
    xi = 3.0 / (result.lambda_max * h**4)
    bad = BrezisSibonySolver(problem, h, BrezisSibonyOptions(xi=xi, max_iterations=1000)).solve()
    assert not bad.converged and bad.reason.startswith("diverging")
    assert bad.tau == pytest.approx(xi * h**4)
    assert bad.contraction_bound == pytest.approx(2.0) and bad.max_ratio > 1.0


def test_options_are_validated() -> None:
    with pytest.raises(ValueError, match="mass"):
        BrezisSibonyOptions(mass="diagonal")
    with pytest.raises(ValueError, match="start"):
        BrezisSibonyOptions(start="random")
    with pytest.raises(ValueError, match="xi"):
        BrezisSibonyOptions(xi=-1.0)


@pytest.mark.mpi
def test_parallel_run_matches_serial_and_newton() -> None:
    """Distributed (38) takes the serial steps (2000 steps of the consistent-mass iteration on
    the same mesh, each rank alone for the serial run), and the lumped variant converges to
    the distributed Newton solution. (Parallel MUMPS solves of this tiny mass matrix cost
    ~1 ms, so the full consistent run stays serial.)"""
    steps = BrezisSibonyOptions(max_iterations=2000)
    runs = []
    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):
        problem = PenalizedProblem(paper_shell(LOAD), square(comm, n=N), kappa=KAPPA)
        result = BrezisSibonySolver(problem, mesh_size(problem.mesh), steps).solve()
        runs.append((result, l2_norm(problem.zeta), Postprocessor(problem).zeta3_range()))
    (par, par_norm, par_range), (ser, ser_norm, ser_range) = runs
    assert par.iterations == ser.iterations == 2000
    for key in ("tau", "lambda_min", "lambda_max", "contraction_bound"):
        assert getattr(par, key) == pytest.approx(getattr(ser, key), rel=1e-8), key  # eigen_tol
    assert np.allclose(par.increments, ser.increments, rtol=1e-10, atol=0.0)
    assert par_norm == pytest.approx(ser_norm, rel=1e-12)
    assert par_range == pytest.approx(ser_range, rel=1e-10)

    problem, ref, h = newton_reference(MPI.COMM_WORLD)
    lumped = BrezisSibonyOptions(mass="lumped", rtol=1e-12, rtol_residual=0.0)
    result = BrezisSibonySolver(problem, h, lumped).solve()
    assert result.converged, result.reason
    assert relative_difference(problem, ref) < 1e-8
    assert result.max_ratio <= result.contraction_bound


def test_compare_solvers_writes_table_and_figure(tmp_path) -> None:
    """compare_solvers on a ready mesh: both solvers agree; the CSV and the PNG are written."""
    opts = BrezisSibonyOptions(max_iterations=200_000, rtol=1e-9)
    rows = compare_solvers(paper_shell(LOAD), [square(n=N)], q=2.0, bs_options=opts)
    (row,) = rows
    assert row["kappa"] == pytest.approx(row["h"] ** 2)
    assert row["contact_nodes"] > 0 and row["newton_iterations"] > 0
    assert row["bs_converged"] and row["bs_iterations"] > 100
    assert row["contraction_observed"] <= row["contraction_bound"] < 1.0
    assert row["relative_l2_difference"] <= row["bs_error_estimate"] < 1e-4
    fake = [dict(row, h=h, bs_iterations=round(7.0 / h**2)) for h in (0.2, 0.1, 0.05)]
    out = write_solver_comparison(fake, tmp_path)
    assert out["slope"] == pytest.approx(-2.0, abs=1e-3)
    lines = out["csv"].read_text().splitlines()
    assert lines[0].startswith("h_target,h,dofs") and len(lines) == 4
    assert out["png"].stat().st_size > 0
