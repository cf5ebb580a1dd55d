"""Koiter's model (docs/model.md §8): the change of curvature, the C⁰ interior-penalty bending
energy, and the discrete solutions against exact ones.

- symbolic: an infinitesimal rigid displacement ``η_i = (c + d ∧ θ)·a_i`` has
  ``γ_αβ(η) = ρ_αβ(η) = 0`` on elliptic, parabolic, hyperbolic and non-graph surfaces;
- a clamped circular plate under uniform pressure against ``w = p (R² − r²)² / (64 D)``;
- manufactured solutions on an elliptic paraboloid and on a saddle (K < 0): the strong form
  of Koiter's equations, derived in UFL from the package's own ``strain`` and
  ``change_of_curvature``, is the load; the energy-norm error (H¹ for ζ_α, broken H² and
  facet jumps for ζ_3) converges at the rate 1 of P2;
- ``ζ_K(ε) → ζ_M`` as ε → 0 on the paper's problem (load ∝ ε);
- serial and 2-rank solves agree.
"""

from __future__ import annotations

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
import sympy as sp
import ufl
from conftest import make_paper_shell

from shellobstacle.api import make_mesh
from shellobstacle.config.loader import ConfigError, parse_config
from shellobstacle.geometry.expressions import y1, y2
from shellobstacle.geometry.surface import Surface, cross, dot
from shellobstacle.geometry.translation import to_ufl
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.models.hybrid_bending import DEFAULT_HYBRID_PENALTY
from shellobstacle.models.koiter import (
    DEFAULT_INTERIOR_PENALTY,
    bending_moment,
    change_of_curvature,
)
from shellobstacle.models.membrane import membrane_stress, strain
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.spec import BENDING_FORMS, Discretization, Load, Material, Obstacle, Shell

COMM = MPI.COMM_WORLD
Y = (y1, y2)
POINTS = np.array([(0.0, 0.0), (0.11, -0.07), (-0.2, 0.13), (0.05, 0.21), (-0.17, -0.19)])
RATE_TOL = 0.15

SURFACES = {
    "spherical cap": Surface.spherical_cap(1.0, 0.85),
    "ellipsoid cap": Surface.ellipsoid_cap((0.8, 0.6, 0.5), 0.1),
    "cylinder": Surface.from_strings(["y1", "y2", "sqrt(1 - y1**2)"]),
    "saddle": Surface.from_strings(["y1", "y2", "1 + 0.8*y1*y2 + 0.3*y1**2"]),
    "wavy": Surface.from_strings(["y1", "y2", "1 + 0.2*sin(3*y1)*cos(2*y2)"]),
    "torus patch": Surface.from_strings(
        ["(2 + cos(y2))*cos(y1)", "(2 + cos(y2))*sin(y1)", "sin(y2)"]
    ),
}


def _numeric(exprs, points=POINTS):
    """Values of nested lists of SymPy expressions at ``points`` (NumPy arrays)."""
    shape = np.shape(np.empty(np.shape(exprs), dtype=object))
    flat = list(np.asarray(exprs, dtype=object).ravel())
    f = sp.lambdify(Y, flat, "numpy", cse=True)
    values = [np.broadcast_to(v, len(points)) for v in f(points[:, 0], points[:, 1])]
    return np.asarray(values, dtype=float).reshape(*shape, len(points))


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_rigid_displacements_neither_stretch_nor_bend(name: str) -> None:
    """γ_αβ(η) = ρ_αβ(η) = 0 for η_i = (c + d ∧ θ)·a_i, c and d arbitrary (docs/model.md §8)."""
    G = SURFACES[name].geometry_sympy()
    c, d = (1.0, -2.0, 0.5), (0.7, 0.3, -1.1)
    u = [c[k] + cross(d, G.theta)[k] for k in range(3)]
    eta = [dot(u, G.a_cov[0]), dot(u, G.a_cov[1]), dot(u, G.a3)]
    grad = [[sp.diff(e, y) for y in Y] for e in eta]
    hess = [[sp.diff(eta[2], a, b) for b in Y] for a in Y]
    gamma = strain(G, eta, grad)
    rho = change_of_curvature(G, eta, grad, hess)
    # the scale: the largest single term of ρ, |∂_αβ η_3|
    scale = np.abs(_numeric(hess)).max()
    assert scale > 0.1
    assert np.abs(_numeric(gamma)).max() < 1e-12 * scale
    assert np.abs(_numeric(rho)).max() < 1e-12 * scale


@pytest.mark.parametrize("name", ["ellipsoid cap", "saddle", "torus patch"])
def test_covariant_derivative_of_curvature(name: str) -> None:
    """``b^τ_{β|α}`` from the third derivatives (Weingarten) equals the direct derivative of
    ``b^τ_β`` plus the Christoffel terms, and is symmetric in α, β (Codazzi–Mainardi)."""
    G = SURFACES[name].geometry_sympy()
    C, bm = G.christoffel, G.b_mixed
    direct = [
        [
            [
                sp.diff(bm[be][t], Y[al])
                + sum(C[t][al][s] * bm[be][s] for s in range(2))
                - sum(C[s][al][be] * bm[s][t] for s in range(2))
                for be in range(2)
            ]
            for t in range(2)
        ]
        for al in range(2)
    ]
    ours, theirs = _numeric(G.b_covariant_derivative), _numeric(direct)
    assert np.abs(theirs).max() > 1e-2
    np.testing.assert_allclose(ours, theirs, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ours, ours.transpose(2, 1, 0, 3), rtol=1e-10, atol=1e-12)


# -- a clamped circular plate --------------------------------------------------------------
PLATE_EPS, PLATE_LAM, PLATE_MU, PLATE_P, PLATE_R = 0.01, 0.4, 0.3, 1e-6, 0.5


def plate_shell() -> Shell:
    plane = Surface((y1, y2, sp.Float(1.0)), "plane", "the plane x3 = 1")
    material = Material(PLATE_EPS, PLATE_LAM, PLATE_MU)
    return Shell(plane, material, Load(("0", "0", repr(PLATE_P))), Obstacle(), "koiter")


def plate_deflection_error(
    comm, h: float, refinements: int = 0, bending: str = "hybrid"
) -> tuple[float, float, PenalizedProblem]:
    """Largest nodal error of ζ_3 relative to the centre deflection, and the largest |ζ_α|."""
    eps, lam, mu = PLATE_EPS, PLATE_LAM, PLATE_MU
    D = eps**3 / 3 * (4 * lam * mu / (lam + 2 * mu) + 4 * mu)  # = 2E(ε)³/(3(1 − ν²))
    spec = DomainSpec(kind="disk", h=h, radius=PLATE_R, refinements=refinements)
    mesh = make_mesh(spec, ghosted=True) if comm is COMM else _serial_mesh(spec)
    problem = PenalizedProblem(plate_shell(), mesh, Discretization(degree=2, bending=bending))
    NewtonSolver(problem).solve()
    x = problem.V.tabulate_dof_coordinates()
    n = problem.V.dofmap.index_map.size_local
    values = problem.zeta.x.array.reshape(-1, 3)[:n]
    r2 = x[:n, 0] ** 2 + x[:n, 1] ** 2
    exact = PLATE_P * (PLATE_R**2 - r2) ** 2 / (64 * D)
    error = mesh.comm.allreduce(np.abs(values[:, 2] - exact).max(), op=MPI.MAX)
    tangential = mesh.comm.allreduce(np.abs(values[:, :2]).max(initial=0.0), op=MPI.MAX)
    return error / (PLATE_P * PLATE_R**4 / (64 * D)), tangential, problem


def _serial_mesh(spec: DomainSpec) -> dolfinx.mesh.Mesh:
    from shellobstacle.mesh.meshing import create_mesh

    return create_mesh(spec, MPI.COMM_SELF)


@pytest.mark.parametrize("bending", BENDING_FORMS)
def test_clamped_plate_matches_the_closed_form_deflection(bending: str) -> None:
    """A flat shell (K = 0, refused by the membrane model) clamped on a disk under uniform
    pressure: ζ_α = 0 and ζ_3 → p (R² − r²)² / (64 D), D = (ε³/3)(4λμ/(λ+2μ) + 4μ); the nodal
    error falls as h² (both P2 bending forms and the polygonal disk give h²)."""
    hs = [0.1, 0.05, 0.025]
    errors = []
    for h in hs:
        error, tangential, _ = plate_deflection_error(COMM, h, bending=bending)
        assert tangential == 0.0  # the membrane part decouples: no in-plane displacement
        errors.append(error)
    rate = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert abs(rate - 2.0) < RATE_TOL, (errors, rate)
    assert errors[-1] < 5e-3


@pytest.mark.mpi
def test_serial_and_parallel_plates_agree() -> None:
    """The distributed Koiter solve (a refined mesh with ghost cells, the children on their
    parent's rank: facet terms across ranks) equals a serial solve of the same mesh."""
    if COMM.size == 1:
        pytest.skip("compares a distributed solve with a serial one")
    par = plate_deflection_error(COMM, 0.1, refinements=1)
    ser = plate_deflection_error(MPI.COMM_SELF, 0.1, refinements=1)
    assert par[0] == pytest.approx(ser[0], rel=1e-9)
    assert par[2].energies()["energy"] == pytest.approx(ser[2].energies()["energy"], rel=1e-10)


@pytest.mark.mpi
def test_an_unghosted_parallel_mesh_is_refused() -> None:
    """Koiter's facet terms would silently miss the facets between ranks without ghosts."""
    spec = DomainSpec(kind="disk", h=0.1, radius=PLATE_R, refinements=1)
    mesh = make_mesh(spec)  # uniform refinement drops the ghost cells
    if COMM.size == 1:
        PenalizedProblem(plate_shell(), mesh, Discretization(degree=2))  # serial: fine
        return
    with pytest.raises(ValueError, match="ghost"):
        PenalizedProblem(plate_shell(), mesh, Discretization(degree=2))


def test_koiter_needs_p2_and_a_clamped_edge() -> None:
    mesh = dolfinx.mesh.create_unit_square(COMM, 2, 2)
    with pytest.raises(ValueError, match="degree = 2"):
        PenalizedProblem(plate_shell(), mesh, Discretization(degree=1))
    with pytest.raises(ValueError, match="clamped"):
        PenalizedProblem(plate_shell(), mesh, Discretization(degree=2, transverse="free"))


# -- manufactured solutions ----------------------------------------------------------------
EPS, LAM, MU = 0.1, 0.4, 0.3
L = 0.3


def strong_load(G, zeta):
    """``p^i`` of Koiter's equations for a smooth ζ (UFL expressions of the coordinates).

    With ``W = ½(n^{αβ} γ_αβ + m^{αβ} ρ_αβ) √a`` and γ, ρ linear in the jet
    ``(η_i, ∂_α η_i, ∂_αβ η_3)``, the Euler–Lagrange equations read
    ``p^i √a = ∂W/∂η_i − ∂_α (∂W/∂(∂_α η_i)) + δ_i3 ∂_αβ (m^{αβ} √a)``; each partial
    derivative of W is ``n : γ(unit jet) + m : ρ(unit jet)``, and UFL differentiates in y.
    """
    grad = [ufl.grad(z) for z in zeta]
    g = [[grad[i][a] for a in range(2)] for i in range(3)]
    hz = ufl.grad(ufl.grad(zeta[2]))
    n = membrane_stress(G, EPS, LAM, MU, strain(G, zeta, g))
    m = bending_moment(
        G,
        EPS,
        LAM,
        MU,
        change_of_curvature(G, zeta, g, [[hz[0, 0], hz[0, 1]], [hz[1, 0], hz[1, 1]]]),
    )
    zero_g = [[0, 0] for _ in range(3)]
    zero_h = [[0, 0], [0, 0]]

    def work(eta, grad_eta, hess):
        gam, rho = strain(G, eta, grad_eta), change_of_curvature(G, eta, grad_eta, hess)
        return sum(n[a][b] * gam[a][b] + m[a][b] * rho[a][b] for a in range(2) for b in range(2))

    sqrt_a = G.sqrt_a
    p = []
    for i in range(3):
        unit = [1 if k == i else 0 for k in range(3)]
        value = work(unit, zero_g, zero_h) * sqrt_a
        for a in range(2):
            unit_g = [[1 if (k, c) == (i, a) else 0 for c in range(2)] for k in range(3)]
            value -= ufl.grad(work([0, 0, 0], unit_g, zero_h) * sqrt_a)[a]
        if i == 2:
            value += sum(
                ufl.grad(ufl.grad(m[a][b] * sqrt_a))[a, b] for a in range(2) for b in range(2)
            )
        p.append(value / sqrt_a)
    return p


MANUFACTURED = {
    "elliptic paraboloid": Surface.elliptic_paraboloid(1.0, (1.5, 2.5)),
    "saddle": Surface.from_strings(["y1", "y2", "1 + 0.8*y1*y2 + 0.3*y1**2"]),
}


def _exact():
    bubble = (sp.Float(L * L) - y1**2) * (sp.Float(L * L) - y2**2)
    return [5 * bubble * (1 + y2), 5 * bubble * (1 - 2 * y1), 100 * bubble**2 * sp.cos(y1 + 2 * y2)]


def manufactured_errors(
    surface: Surface, n: int, sigma: float | None = None, bending: str = "hybrid"
):
    """Solve on the n × n mesh of [-L, L]²; errors (energy, H¹ of ζ_α, broken H² of ζ_3)."""
    shell = Shell(surface, Material(EPS, LAM, MU), Load(("0", "0", "0")), Obstacle(), "koiter")
    mesh = dolfinx.mesh.create_rectangle(COMM, [[-L, -L], [L, L]], [n, n])
    x = ufl.SpatialCoordinate(mesh)
    exact = [to_ufl(z, {y1: x[0], y2: x[1]}) for z in _exact()]
    p = strong_load(surface.geometry_ufl(mesh), exact)
    disc = Discretization(degree=2, interior_penalty=sigma, bending=bending)
    problem = PenalizedProblem(shell, mesh, disc, p=p)
    NewtonSolver(problem).solve()
    e = [problem.zeta[i] - exact[i] for i in range(3)]
    dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": 8})
    dS = ufl.Measure("dS", domain=mesh, metadata={"quadrature_degree": 8})
    ds = ufl.Measure("ds", domain=mesh, metadata={"quadrature_degree": 8})
    nrm, h = ufl.FacetNormal(mesh), ufl.CellDiameter(mesh)
    jump = ufl.jump(ufl.grad(e[2]), nrm)
    forms = {
        "H1": sum(e[a] ** 2 + ufl.inner(ufl.grad(e[a]), ufl.grad(e[a])) for a in range(2)) * dx,
        "H2": ufl.inner(ufl.grad(ufl.grad(e[2])), ufl.grad(ufl.grad(e[2]))) * dx,
        "jumps": 2 * jump**2 / (h("+") + h("-")) * dS + ufl.dot(ufl.grad(e[2]), nrm) ** 2 / h * ds,
    }
    sq = {
        k: COMM.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(f)))
        for k, f in forms.items()
    }
    return {
        "energy": np.sqrt(sum(sq.values())),
        "H1": np.sqrt(sq["H1"]),
        "H2": np.sqrt(sq["H2"]),
        "zeta": problem.zeta,
    }


@pytest.fixture(
    scope="module", params=[(name, b) for name in sorted(MANUFACTURED) for b in BENDING_FORMS]
)
def convergence(request):
    name, bending = request.param
    ns = [4, 8, 16, 32]
    errors = [manufactured_errors(MANUFACTURED[name], n, bending=bending) for n in ns]
    return (name, bending), ns, errors


def test_manufactured_energy_norm_rate(convergence) -> None:
    """P2: the energy-norm error (H¹ of ζ_α, broken H² and facet jumps of ζ_3) falls as h,
    on an elliptic surface and on a saddle (which the membrane model refuses), with either
    bending form."""
    name, ns, errors = convergence
    hs = [2 * L / n for n in ns]
    rate = np.polyfit(np.log(hs), np.log([e["energy"] for e in errors]), 1)[0]
    assert abs(rate - 1.0) < RATE_TOL, (name, [e["energy"] for e in errors], rate)
    # ζ_α converges at least as fast (P2 in H¹: up to h²)
    rate_h1 = np.polyfit(np.log(hs), np.log([e["H1"] for e in errors]), 1)[0]
    assert rate_h1 > 1.0 - RATE_TOL, (name, rate_h1)


def test_interior_penalty_changes_less_than_the_error(convergence) -> None:
    """σ at its default (16 hybrid, 8 C⁰-IP) and at 4 times it give solutions closer to each
    other than to the exact one."""
    (name, bending), ns, errors = convergence
    sigma = 4 * (DEFAULT_HYBRID_PENALTY if bending == "hybrid" else DEFAULT_INTERIOR_PENALTY)
    other = manufactured_errors(MANUFACTURED[name], ns[2], sigma=sigma, bending=bending)
    assert other["energy"] < 2 * errors[2]["energy"]
    a, b = errors[2]["zeta"], other["zeta"]
    diff = np.sqrt(COMM.allreduce(np.sum((a.x.array - b.x.array) ** 2)))
    size = np.sqrt(COMM.allreduce(np.sum(a.x.array**2)))
    assert diff < 0.05 * size


# -- the membrane limit --------------------------------------------------------------------
@pytest.mark.slow  # continuations at three ε and the membrane's
def test_koiter_tends_to_the_membrane_solution_as_epsilon_vanishes() -> None:
    """On the paper's problem (load ∝ ε, so the membrane solution does not depend on ε),
    ``ζ_K(ε) → ζ_M`` on a fixed mesh. The discrete bending terms weigh about ε²/h⁴ against
    the membrane's, so the limit shows once ε ≪ h² (here h² ≈ 1e-3): measured relative
    distances 0.84, 0.17, 1.3e-4 at ε = 1e-2, 1e-4, 1e-6."""
    mesh = dolfinx.mesh.create_rectangle(COMM, [[-0.25, -0.25], [0.25, 0.25]], [16, 16])
    disc = Discretization(degree=2)
    kappas = [1e-1, 1e-2, 1e-3, 1e-4]

    def solve(model: str, eps: float) -> np.ndarray:
        shell = make_paper_shell(model=model, epsilon=eps)
        problem = PenalizedProblem(shell, mesh, disc)
        continuation(problem, NewtonSolver(problem), kappas)
        return problem.zeta.x.array.copy()

    membrane = solve("membrane", 1e-3)
    size = np.sqrt(COMM.allreduce(np.sum(membrane**2)))
    distances = [
        np.sqrt(COMM.allreduce(np.sum((solve("koiter", eps) - membrane) ** 2))) / size
        for eps in (1e-2, 1e-4, 1e-6)
    ]
    assert distances[0] > distances[1] > distances[2], distances
    assert distances[0] > 0.1  # thick: bending matters
    assert distances[2] < 1e-3, distances


# -- configuration -------------------------------------------------------------------------
def _config(**sections):
    data = {
        "surface": {"kind": "expression", "theta": ["y1", "y2", "1 + 0.8*y1*y2"]},
        "domain": {"kind": "disk", "h": 0.1, "radius": 0.3},
        "material": {"epsilon": 0.01, "lambda": 0.4, "mu": 0.3},
        "load": {"p": ["0", "0", "-1e-6"]},
        "penalty": {"kappa": 1e-6},
    }
    data.update(sections)
    return parse_config(data)


def test_config_switches_the_model() -> None:
    assert _config().shell.model == "membrane"
    cfg = _config(model={"kind": "koiter"})
    assert cfg.shell.model == "koiter"
    assert cfg.discretization.degree == 2  # Koiter's default
    assert cfg.resolved["discretization"]["degree"] == 2
    with pytest.raises(ConfigError, match="degree"):
        _config(model={"kind": "koiter"}, discretization={"degree": 1})
    with pytest.raises(ConfigError, match="did you mean 'koiter'"):
        _config(model={"kind": "koitre"})


def test_config_refuses_what_koiter_cannot_use() -> None:
    koiter = {"kind": "koiter"}
    with pytest.raises(ConfigError, match="transverse"):
        _config(model=koiter, discretization={"transverse": "free"})
    with pytest.raises(ConfigError, match="linear_solver = 'direct' or 'multigrid'"):
        _config(model=koiter, solver={"linear_solver": "iterative"})
    # geometric multigrid takes Koiter's stiffness as it is (tested in test_multigrid.py)
    assert _config(model=koiter, solver={"linear_solver": "multigrid"}).shell.model == "koiter"
    # nested iteration relaxes ζ_3 as the membrane's L² unknown; the fix the message names
    # ('off') is accepted, as is "auto" (which never nests Koiter's model)
    with pytest.raises(ConfigError, match=r"nested_iteration.*set it to 'off'"):
        _config(model=koiter, solver={"nested_iteration": "on"})
    for value in ("off", "auto"):
        assert _config(model=koiter, solver={"nested_iteration": value}).shell.model == "koiter"
