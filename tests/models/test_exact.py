"""Exact solution: uniform normal pressure on a spherical cap (GUIDE.md, verification habits).

With ``p^{i,ε} = (0, 0, p)``, ``transverse = "free"`` and no contact, ``ζ_1 = ζ_2 = 0``,
``ζ_3 = w`` solves (8): ``γ_αβ = −b_αβ w = a_αβ w/R``, so
``n^{αβ} = (2εw/R)(4λμ/(λ+2μ) + 2μ) a^{αβ}``, whose covariant divergence vanishes, and
``−b_αβ n^{αβ} = (4εw/R²)(4λμ/(λ+2μ) + 2μ) = p``. Every finite-element space holds it, so the
discrete solution equals it up to the solver tolerance and the quadrature of the geometry.
"""

# isort: split
from mpi4py import MPI

import dolfinx
import numpy as np
import pytest

from shellobstacle.geometry.surface import Surface
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

EPS = 0.001
P = 1e-4  # > 0: pushes along a^3 = outward normal, away from the plane x3 = 0


def _deflection(p, R, lam, mu, eps=EPS):
    return p * R**2 / (4 * eps * (4 * lam * mu / (lam + 2 * mu) + 2 * mu))


def _solve_and_check(R, offset, lam, mu, degree, n, half_width=0.3):
    comm = MPI.COMM_WORLD
    shell = Shell(
        Surface.spherical_cap(R, offset),
        Material(EPS, lam, mu),
        Load.uniform_normal_pressure(P),
        Obstacle((0.0, 0.0, 1.0)),
    )
    L = half_width
    mesh = dolfinx.mesh.create_rectangle(comm, [[-L, -L], [L, L]], [n, n + 1])
    problem = PenalizedProblem(shell, mesh, Discretization(degree=degree, transverse="free"), 1.0)
    result = NewtonSolver(problem).solve()
    assert result.converged

    w = _deflection(P, R, lam, mu)
    assert w > 0
    zeta = problem.zeta.x.array.reshape(-1, 3)
    err_local = np.abs(zeta - np.array([0.0, 0.0, w])).max(initial=0.0)
    err = comm.allreduce(err_local, op=MPI.MAX)
    # (the max runs over the boundary nodes too: ζ_3 is free there and must equal w)
    assert err <= 1e-6 * w, f"max nodal error {err:.3e} for w = {w:.6g}"

    # no contact: the gap g(ζ) = θ·q + ζ_j c_j is positive at every node, the penalty inactive
    nodes = problem.V.tabulate_dof_coordinates()
    G = shell.surface.geometry_numpy(nodes)
    g = problem.obstacle.gap(G, [zeta[:, i] for i in range(3)])
    g_min = comm.allreduce(g.min(initial=np.inf), op=MPI.MIN)
    theta_q_min = comm.allreduce(G.theta[2].min(initial=np.inf), op=MPI.MIN)
    assert g_min > theta_q_min > 0  # the shell moved away from the plane
    assert problem.energies()["penalty_energy"] == 0.0
    return err / w


@pytest.mark.parametrize("degree", [1, 2])
def test_spherical_cap_paper_data(degree):
    """R = 1, offset 0.85, λ = 0.4, μ = 0.012 (the paper's data): ζ = (0, 0, w) to 1e-6."""
    _solve_and_check(1.0, 0.85, 0.4, 0.012, degree, n=6)


@pytest.mark.parametrize("degree", [1, 2])
def test_spherical_cap_other_data(degree):
    """R = 2, offset 1.5, λ = 1.0, μ = 0.5 on a wider square."""
    _solve_and_check(2.0, 1.5, 1.0, 0.5, degree, n=5, half_width=0.8)


@pytest.mark.mpi
def test_spherical_cap_parallel():
    """The same under MPI (global reductions): P1 and P2 on a finer mesh."""
    for degree in (1, 2):
        _solve_and_check(1.0, 0.85, 0.4, 0.012, degree, n=10)
