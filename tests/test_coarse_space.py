"""The coarse-grid Galerkin solve that seeds the contact zone (solvers/coarse_space.py)."""

from __future__ import annotations

import math

from petsc4py import PETSc

import dolfinx.fem.petsc
import numpy as np
import pytest

from shellobstacle.problem import PenalizedProblem
from shellobstacle.solvers.coarse_space import CoarseSpace
from shellobstacle.solvers.newton import NewtonSolver
from tests.test_contact_zone import lu_solve
from tests.test_newton import paper_shell, square


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
@pytest.mark.parametrize("ratio", [16.0, 64.0])
def test_the_coarse_solve_is_the_galerkin_projection(ratio: float) -> None:
    """δ̃ = P(PᵀKP)⁻¹Pᵀf: zero at the Dirichlet dofs, Pᵀ(Kδ̃ − f) = 0, and closer to K⁻¹f
    in the energy norm than the other vectors of the subspace (here: δ̃ perturbed in it)."""
    problem = PenalizedProblem(paper_shell(), square(n=32))
    solver = NewtonSolver(problem)
    system = solver.system
    system.load()
    K, f = system.K, system.f
    coarse = CoarseSpace(problem.V, K, problem.bcs, ratio)
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
