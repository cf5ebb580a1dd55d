"""The coarse-grid Galerkin solve that seeds the contact zone (solvers/newton/coarse_space.py)."""

from __future__ import annotations

import math

from petsc4py import PETSc

import dolfinx.fem.petsc
import numpy as np
import pytest
from conftest import lu_solve, square
from conftest import make_paper_shell as paper_shell

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.coarse_space import CoarseSpace, _quadratic_bsplines
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.spec import Discretization


def galerkin_residual(coarse: CoarseSpace, K: PETSc.Mat, f: PETSc.Vec) -> tuple[PETSc.Vec, float]:
    """``δ̃`` and ``‖Pᵀ(Kδ̃ − f)‖`` (0 for the Galerkin projection)."""
    d = f.duplicate()
    coarse.solve(f, d)
    r = f.duplicate()
    K.mult(d, r)
    r.axpy(-1.0, f)
    rc = coarse.P.createVecRight()
    coarse.P.multTranspose(r, rc)
    return d, rc.norm()


def energy(K: PETSc.Mat, x: PETSc.Vec) -> float:
    y = x.duplicate()
    K.mult(x, y)
    return float(np.sqrt(y.dot(x)))


@pytest.mark.mpi
@pytest.mark.parametrize(("ratio", "smooth"), [(16.0, False), (64.0, False), (16.0, True)])
def test_the_coarse_solve_is_the_galerkin_projection(ratio: float, smooth: bool) -> None:
    """δ̃ = P(PᵀKP)⁻¹Pᵀf: zero at the Dirichlet dofs, Pᵀ(Kδ̃ − f) = 0, and closer to K⁻¹f
    in the energy norm than the other vectors of the subspace (here: δ̃ perturbed in it)."""
    problem = PenalizedProblem(paper_shell(), square(n=32))
    solver = NewtonSolver(problem)
    system = solver.system
    system.load()
    K, f = system.K, system.f
    coarse = CoarseSpace(problem.V, K, problem.bcs, ratio, smooth=smooth)
    n_dofs = K.getSize()[0]
    assert 0 < coarse.size < 3 * n_dofs / ratio
    d, residual = galerkin_residual(coarse, K, f)
    mask = f.duplicate()
    mask.set(1.0)
    dolfinx.fem.petsc.set_bc(mask, problem.bcs)
    assert np.all(d.array_r[mask.array_r == 0.0] == 0.0)
    assert residual <= 1e-10 * f.norm()
    exact = lu_solve(K, f)
    e = exact.copy()
    e.axpy(-1.0, d)
    best = energy(K, e)
    assert best < energy(K, exact)  # it captures part of the solution
    yc = coarse.P.createVecRight()
    rng = np.random.default_rng(0)
    yc.array[:] = rng.standard_normal(yc.getLocalSize())
    other = d.duplicate()
    coarse.P.mult(yc, other)
    other.scale(1e-3 * d.norm() / max(other.norm(), 1e-300))
    other.axpy(1.0, e)  # K⁻¹f − (δ̃ − the perturbation)
    assert energy(K, other) >= best
    coarse.destroy()


@pytest.mark.mpi
def test_the_grid_has_at_most_about_max_nodes_nodes() -> None:
    """On a fine mesh the grid stops at ``max_nodes`` nodes (H grows beyond 4h): here 30
    grid nodes asked for on the 0.5 × 0.5 square with 33² mesh nodes, where ``ratio`` 16 alone
    would give 68; the capped space is still a Galerkin space (Pᵀ(Kδ̃ − f) = 0)."""
    problem = PenalizedProblem(paper_shell(), square(n=32))
    solver = NewtonSolver(problem)
    system = solver.system
    system.load()
    K, f = system.K, system.f
    uncapped = CoarseSpace(problem.V, K, problem.bcs, 16.0)
    capped = CoarseSpace(problem.V, K, problem.bcs, 16.0, max_nodes=30)
    grid = (math.ceil(math.sqrt(30)) + 1) ** 2  # nodes of the 6 × 6 grid
    assert 0 < capped.size <= 3 * grid < uncapped.size
    _, residual = galerkin_residual(capped, K, f)
    assert residual <= 1e-10 * f.norm()
    for coarse in (uncapped, capped):
        coarse.destroy()


def test_the_bsplines_are_c1_and_reproduce_linear_functions() -> None:
    """The 9 B-splines at a point sum to 1, with the coefficients ``k − 1/2`` (Greville
    abscissae) to the grid coordinate, and they are C¹ across the grid lines (the kinks of
    P1 hats are what Koiter's interior penalty makes stiff)."""
    nx, ny = 5, 4
    rng = np.random.default_rng(3)
    u = rng.uniform(0, 1, (400, 2)) * [nx, ny]
    numbers, values, width = _quadratic_bsplines(u, nx, ny)
    assert width == (nx + 2) * (ny + 2) and numbers.max() < width
    k, l = numbers % (nx + 2), numbers // (nx + 2)
    assert np.allclose(values.sum(1), 1.0, atol=1e-14)
    assert np.allclose((values * (k - 0.5)).sum(1), u[:, 0], atol=1e-13)
    assert np.allclose((values * (l - 0.5)).sum(1), u[:, 1], atol=1e-13)

    def field(points: np.ndarray) -> np.ndarray:  # one fixed spline with random coefficients
        c = np.random.default_rng(4).standard_normal(width)
        n, v, _ = _quadratic_bsplines(points, nx, ny)
        return (c[n] * v).sum(1)

    step = 1e-7
    for x in (1.0, 2.0, 3.0):  # across the grid lines u_1 = x: value and slope continuous
        left = np.array([[x - step, 1.3], [x - 2 * step, 1.3]])
        right = np.array([[x + step, 1.3], [x + 2 * step, 1.3]])
        fl, fr = field(left), field(right)
        assert abs(fl[0] - fr[0]) < 1e-6
        assert abs((fl[0] - fl[1]) / step - (fr[1] - fr[0]) / step) < 1e-5


def test_koiter_first_step_is_seeded_by_the_bsplines() -> None:
    """Koiter's first κ from ζ = 0 factorizes only the contact zone: the B-spline step
    predicts the contact, so no full Jacobian is factorized first (P1 hats predict none)."""
    import dataclasses

    mesh = square(n=16)
    problem = PenalizedProblem(
        dataclasses.replace(paper_shell(), model="koiter"), mesh, Discretization(degree=2)
    )
    problem.set_kappa((0.5 / 16) ** 0.5)
    result = NewtonSolver(problem).solve()
    assert result.converged
    assert result.factorizations == 1 and result.zone_steps == result.iterations
