"""The a posteriori indicators (shellobstacle.adapt.estimator; the model page's eq. estimator).

Two exact solutions:

- uniform normal pressure on a spherical cap, ζ_3 free: ``ζ = (0, 0, w)`` is in every
  discrete space (tests/models/test_exact.py), so every residual and jump vanishes and ``η`` is
  round-off;
- a manufactured smooth ``ζ`` on the paper's cap over [-0.3, 0.3]² without contact, its load
  the strong form (8) of the package's own geometry and stresses (as
  tests/models/test_manufactured.py does on an ellipsoid). Measured: the error and ``η`` both
  fall like h (rates 1.00, 0.98 on n = 8 … 64) and the efficiency index
  ``η / ‖ζ − ζ_h‖_{V_M}`` is 6.7, 6.9, 7.0, 7.0 on n = 8, 16, 32, 64.
"""

from pathlib import Path

# isort: split
from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
import sympy as sp
import ufl

from shellobstacle.adapt.estimator import ErrorEstimator
from shellobstacle.geometry.expressions import y1, y2
from shellobstacle.geometry.surface import Surface
from shellobstacle.geometry.translation import to_ufl
from shellobstacle.models.membrane import membrane_stress, strain, stress_divergence
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

COMM = MPI.COMM_WORLD
EPS, LAM, MU = 0.001, 0.4, 0.012
L = 0.3
Y = (y1, y2)


def test_indicator_of_the_exact_constant_solution_vanishes() -> None:
    """ζ = (0, 0, w) on the spherical cap: ``η`` is round-off against the size of its parts
    for a solution off by 1 %."""
    R, p = 1.0, 1e-4
    shell = Shell(
        Surface.spherical_cap(R, 0.85),
        Material(EPS, LAM, MU),
        Load.uniform_normal_pressure(p),
        Obstacle((0.0, 0.0, 1.0)),
    )
    mesh = dolfinx.mesh.create_rectangle(
        COMM, [[-L, -L], [L, L]], [12, 13], ghost_mode=dolfinx.mesh.GhostMode.shared_facet
    )
    problem = PenalizedProblem(shell, mesh, Discretization(transverse="free"), 1.0)
    assert NewtonSolver(problem).solve().converged
    w = p * R**2 / (4 * EPS * (4 * LAM * MU / (LAM + 2 * MU) + 2 * MU))
    z = problem.zeta.x.array.reshape(-1, 3)
    assert np.allclose(z, [0.0, 0.0, w], rtol=0, atol=1e-9 * w)
    estimator = ErrorEstimator(problem)
    exact = estimator()
    z[:, 2] *= 1.01  # a constant ζ_3 off by 1 %: the normal residual is 1 % of the load
    off = estimator()
    assert off.total > 0
    assert exact.total <= 1e-8 * off.total, (exact.part_totals(), off.part_totals())
    assert off.part_totals()["normal"] == pytest.approx(off.total, rel=1e-6)


def _bubble():
    return (sp.Float(L * L) - y1**2) * (sp.Float(L * L) - y2**2)


@pytest.fixture(scope="module")
def manufactured():
    """Exact ζ and its strong-form load on the paper's cap (no contact: ζ_3 ≥ 0 lifts it)."""
    surface = Surface.spherical_cap(1.0, 0.85)
    G = surface.geometry_sympy()
    b = _bubble()
    zeta = [4 * b * (1 + y2), 4 * b * (1 - 2 * y1), 8 * b * (1 + y1 * y2)]
    grad = [[sp.diff(z, y) for y in Y] for z in zeta]
    n = membrane_stress(G, EPS, LAM, MU, strain(G, zeta, grad))
    dn = [[[sp.diff(n[al][be], y) for y in Y] for be in range(2)] for al in range(2)]
    div = stress_divergence(G, n, dn)
    normal = sum(G.b_lower[al][be] * n[al][be] for al in range(2) for be in range(2))
    return surface, zeta, [-div[0], -div[1], -normal]


def _study(manufactured, n: int) -> tuple[float, float]:
    """(‖ζ − ζ_h‖_{V_M}, η) on an n × n mesh."""
    surface, zeta, p = manufactured
    mesh = dolfinx.mesh.create_rectangle(
        COMM, [[-L, -L], [L, L]], [n, n], ghost_mode=dolfinx.mesh.GhostMode.shared_facet
    )
    x = ufl.SpatialCoordinate(mesh)
    to = {y1: x[0], y2: x[1]}
    shell = Shell(surface, Material(EPS, LAM, MU), Load(("0", "0", "0")), Obstacle())
    problem = PenalizedProblem(shell, mesh, Discretization(), 1.0, [to_ufl(e, to) for e in p])
    assert NewtonSolver(problem).solve().converged
    assert problem.energies()["penalty_energy"] == 0.0
    zh = problem.zeta.x.array.reshape(-1, 3)
    G = surface.geometry_numpy(problem.V.tabulate_dof_coordinates())
    g_min = COMM.allreduce(problem.obstacle.gap(G, [zh[:, i] for i in range(3)]).min(), op=MPI.MIN)
    assert g_min > 0.01  # no contact
    e = [problem.zeta[i] - to_ufl(zeta[i], to) for i in range(3)]
    dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": 8})
    grads = sum(ufl.inner(ufl.grad(e[a]), ufl.grad(e[a])) for a in range(2))
    form = dolfinx.fem.form((sum(ei**2 for ei in e) + grads) * dx)
    error = np.sqrt(COMM.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM))
    return float(error), ErrorEstimator(problem)().total


def test_indicator_is_reliable_and_efficient_on_a_manufactured_solution(manufactured) -> None:
    """The efficiency index η/‖ζ − ζ_h‖ stays in the measured band [6, 8] (reliability and
    efficiency with these constants) and both converge at the rate 1 in h (Theorem 8.1
    without contact)."""
    ns = (8, 16, 32)
    errors, etas = np.array([_study(manufactured, n) for n in ns]).T
    index = etas / errors
    assert np.all((index >= 6.0) & (index <= 8.0)), index
    h = 2 * L / np.array(ns)
    assert np.polyfit(np.log(h), np.log(errors), 1)[0] == pytest.approx(1.0, abs=0.1)
    assert np.polyfit(np.log(h), np.log(etas), 1)[0] == pytest.approx(1.0, abs=0.1)


@pytest.mark.mpi
def test_indicators_on_2_ranks_equal_the_serial_ones() -> None:
    """The paper's problem on a square with contact: every part of η on the distributed
    (ghosted) mesh equals the serial value; the edge jumps across process boundaries are
    counted once."""
    from shellobstacle.config.loader import load_config
    from shellobstacle.solvers.newton.continuation import continuation

    shell = load_config(Path(__file__).parents[2] / "examples" / "paper.toml").shell
    out = []
    for comm in (COMM, MPI.COMM_SELF):
        mesh = dolfinx.mesh.create_rectangle(
            comm, [[-0.25, -0.25], [0.25, 0.25]], [24, 24],
            ghost_mode=dolfinx.mesh.GhostMode.shared_facet,
        )  # fmt: skip
        problem = PenalizedProblem(shell, mesh, Discretization())
        continuation(problem, NewtonSolver(problem), [1e-1, 1e-2, 1e-3])
        parts = ErrorEstimator(problem)().part_totals()
        assert parts["contact"] > 0  # the shell touches the plane
        out.append(parts)
    for key, value in out[0].items():
        assert value == pytest.approx(out[1][key], rel=1e-8), key
