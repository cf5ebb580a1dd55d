"""The penalty at its quadrature points equals the UFL forms; factorization reuse (§4–5)."""

from __future__ import annotations

from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np
import pytest
from conftest import make_paper_shell as paper_shell
from conftest import square

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers import quadrature_penalty as quadrature
from shellobstacle.solvers.linear.direct import DirectStrategy
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonOptions, NewtonSolver
from shellobstacle.solvers.quadrature_penalty import QuadraturePenalty
from shellobstacle.spec import Discretization

KAPPA = 1e-3


def pressed(problem: PenalizedProblem) -> None:
    """A displacement that pushes the middle of the cap through the plane (g < 0 there)."""
    problem.zeta.interpolate(
        lambda x: np.vstack([0.01 * x[1], -0.02 * x[0], -0.2 + 2.0 * (x[0] ** 2 + x[1] ** 2)])
    )
    dolfinx.fem.petsc.set_bc(problem.zeta.x.petsc_vec, problem.bcs)
    problem.zeta.x.scatter_forward()


def assembled_vector(problem: PenalizedProblem, name: str) -> PETSc.Vec:
    b = dolfinx.fem.petsc.assemble_vector(problem.forms[name])
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    dolfinx.fem.petsc.set_bc(b, problem.bcs)
    return b


@pytest.mark.mpi
@pytest.mark.parametrize(("degree", "quadrature"), [(1, "gauss"), (1, "vertex"), (2, "gauss")])
def test_point_penalty_equals_the_forms(degree: int, quadrature: str) -> None:
    """Energy, residual, its κ-derivative and Jacobian from the point matrix M equal the UFL
    forms' values."""
    disc = Discretization(degree=degree, penalty_quadrature=quadrature)
    problem = PenalizedProblem(paper_shell(), square(n=10), disc, kappa=KAPPA)
    pressed(problem)
    pen = QuadraturePenalty(problem)
    g = pen.gap(problem.zeta.x.petsc_vec)
    num_active = problem.mesh.comm.allreduce(int(np.sum(g < 0)))
    assert 0 < num_active < pen.num_points  # both sides of the kink are exercised

    energy = problem.scalar("penalty_energy")
    assert pen.energy(g, KAPPA) == pytest.approx(energy, rel=1e-12)

    expected = assembled_vector(problem, "penalty_residual")
    ours = expected.duplicate()
    ours.set(0.0)
    pen.add_residual(np.minimum(g, 0.0), KAPPA, ours)
    ours.axpy(-1.0, expected)
    assert ours.norm() <= 1e-12 * expected.norm()

    ours.set(0.0)
    pen.add_kappa_derivative(g, KAPPA, ours)  # −∂R/∂κ = (1/κ) · the penalty's residual
    ours.axpy(-1.0 / KAPPA, expected)
    assert ours.norm() <= 1e-12 * expected.norm() / KAPPA

    J = dolfinx.fem.petsc.assemble_matrix(problem.forms["jacobian"], bcs=problem.bcs)
    J.assemble()
    K = dolfinx.fem.petsc.assemble_matrix(problem.forms["stiffness"], bcs=problem.bcs)
    K.assemble()
    K.axpy(1.0, pen.jacobian(g, KAPPA), structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
    K.axpy(-1.0, J)
    assert K.norm() <= 1e-12 * J.norm()


def test_no_active_point_no_penalty_jacobian() -> None:
    """At ζ = 0 the cap is above the plane: no active point, no penalty Jacobian."""
    problem = PenalizedProblem(paper_shell(), square(n=8), kappa=KAPPA)
    pen = QuadraturePenalty(problem)
    g = pen.gap(problem.zeta.x.petsc_vec)
    assert np.all(g > 0)
    assert pen.jacobian(g, KAPPA) is None
    assert pen.energy(g, KAPPA) == 0.0


def test_the_nodal_problem_has_no_kappa() -> None:
    """kappa=None (the exact nodal problem, κ = 0): no penalty term even where g < 0, no κ."""
    problem = PenalizedProblem(paper_shell(), square(n=8), kappa=None)
    pressed(problem)
    assert not problem.penalized and problem.kappa is None
    assert "penalty_energy" not in problem.forms and "penalty_residual" not in problem.forms
    energies = problem.energies()
    assert energies["penalty_energy"] == 0.0
    assert energies["penalized_energy"] == energies["energy"]
    residual = assembled_vector(problem, "residual")  # K ζ − f: the elastic part alone
    expected = problem.load_vector()
    expected.scale(-1.0)
    problem.stiffness().multAdd(problem.zeta.x.petsc_vec, expected, expected)
    expected.axpy(-1.0, residual)
    assert expected.norm() <= 1e-12 * residual.norm()
    with pytest.raises(ValueError, match="no κ"):
        problem.set_kappa(1e-3)


@pytest.mark.mpi
def test_factorization_reuse_same_solution_fewer_factorizations() -> None:
    """Reusing one factorization per solve gives the same ζ as factorizing at every step."""
    kappas = [1e-2, 1e-3, 1e-4, 1e-5]
    results = {}
    for reuse in (False, True):
        problem = PenalizedProblem(paper_shell(), square(n=32))
        options = NewtonOptions(contact_zone=False)
        solver = NewtonSolver(problem, options, DirectStrategy(reuse=reuse))
        steps = continuation(problem, solver, kappas)
        results[reuse] = (problem.zeta.x.petsc_vec.copy(), steps)
    (z_fresh, fresh), (z_reuse, reused) = results[False], results[True]
    assert all(s.converged for s in fresh + reused)
    assert all(s.newton.relative_residual <= 1e-10 or s.newton.round_off_limited for s in reused)
    # every Newton step of the fresh solver factorizes; the reusing one at least once less
    assert [s.newton.factorizations for s in fresh] == [s.iterations for s in fresh]
    total_fresh = sum(s.newton.factorizations for s in fresh)
    total_reused = sum(s.newton.factorizations for s in reused)
    assert total_reused < total_fresh
    assert max(max(s.newton.linear_iterations) for s in reused) > 1  # CG did run
    z_reuse.axpy(-1.0, z_fresh)
    assert z_reuse.norm() <= 1e-8 * z_fresh.norm()


def test_reuse_gives_up_and_factorizes_when_cg_is_slow(monkeypatch: pytest.MonkeyPatch) -> None:
    """CG that does not converge within its budget falls back to a new factorization."""
    problem = PenalizedProblem(paper_shell(), square(n=24))
    linear = DirectStrategy(reuse_max_iterations=1)
    solver = NewtonSolver(problem, NewtonOptions(contact_zone=False), linear)
    # always try CG, however much the active set moved: with one iteration it must fail
    monkeypatch.setattr(linear, "_moved", lambda: 0)
    steps = continuation(problem, solver, [1e-2, 1e-3])
    assert all(s.converged for s in steps)
    assert linear.reuse_failures > 0  # (in the last κ's solve)
    assert sum(s.newton.factorizations for s in steps) > len(steps)


@pytest.mark.mpi
def test_cholesky_and_lu_give_the_same_solution() -> None:
    """The Jacobian is symmetric positive definite: MUMPS Cholesky solves the same problem."""
    solutions = []
    for factorization in ("lu", "cholesky"):
        problem = PenalizedProblem(paper_shell(), square(n=24))
        solver = NewtonSolver(problem, NewtonOptions(factorization=factorization))
        steps = continuation(problem, solver, [1e-2, 1e-4])
        assert all(s.converged for s in steps)
        solutions.append(problem.zeta.x.petsc_vec.copy())
    solutions[1].axpy(-1.0, solutions[0])
    assert solutions[1].norm() <= 1e-8 * solutions[0].norm()


@pytest.mark.mpi
def test_a_residual_at_a_few_points_multiplies_their_rows_only(monkeypatch) -> None:
    """Values nonzero at a few points (an active set of about 1 %): ``add_residual`` takes
    those rows of ``M`` only, and its sum is bit for bit ``M``'s full transpose product."""
    problem = PenalizedProblem(paper_shell(), square(n=16))
    penalty = QuadraturePenalty(problem)
    values = np.zeros(penalty.D.size)
    values[::97] = -np.linspace(1.0, 2.0, values[::97].size)
    b = dolfinx.fem.petsc.create_vector(problem.V)
    b.array[:] = np.sin(np.arange(b.getLocalSize()))
    expected = b.copy()
    q = penalty.M.createVecLeft()
    q.array[:] = values / KAPPA
    penalty.M.multTransposeAdd(q, expected, expected)
    rows = []
    rows_of = quadrature.rows_of
    monkeypatch.setattr(quadrature, "rows_of", lambda M, p: rows.append(p.size) or rows_of(M, p))
    penalty.add_residual(values, KAPPA, b)
    assert rows == [np.count_nonzero(values)]
    assert np.array_equal(b.array, expected.array)


@pytest.mark.mpi
def test_the_penalty_hessian_added_on_its_columns_is_the_full_products() -> None:
    """``add_penalty_hessian`` (the incremental Jacobian's update, on the columns the points
    touch) gives ``K ± P_A`` of ``penalty_hessian`` and ``MatAXPY``: bit for bit serially, to
    round-off on several ranks; also for a handful of points and for a rank without any."""
    problem = PenalizedProblem(paper_shell(), square(n=16), kappa=KAPPA)
    pressed(problem)
    pen = QuadraturePenalty(problem)
    g = pen.gap(problem.zeta.x.petsc_vec)
    active = np.flatnonzero(g < 0)
    comm = problem.mesh.comm
    cases = [(active, 1.0), (active[::50], -1.0)]
    if comm.size > 1:
        cases.append((active[:3] if comm.rank else active[:0], 1.0))
    for points, sign in cases:
        assert comm.allreduce(points.size) > 0
        expected = problem.stiffness().duplicate(copy=True)
        P = quadrature.penalty_hessian(pen.M, pen.D, points, KAPPA)
        expected.axpy(sign, P, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        ours = problem.stiffness().duplicate(copy=True)
        quadrature.add_penalty_hessian(ours, pen.M, pen.D, points, KAPPA, sign)
        if comm.size == 1:
            assert all(
                np.array_equal(a, b)
                for a, b in zip(ours.getValuesCSR(), expected.getValuesCSR(), strict=True)
            )
        ours.axpy(-1.0, expected)
        assert ours.norm() <= 1e-14 * expected.norm()
