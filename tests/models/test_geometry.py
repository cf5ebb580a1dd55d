"""Geometry (docs/model.md §1) against independent SymPy derivations, and its three backends.

The reference values are derived here from ``θ`` alone, without :class:`Geometry`: the metric
``a_αβ = ∂_α θ · ∂_β θ``, Christoffel symbols from the metric,
``Γ^σ_αβ = ½ a^{στ}(∂_α a_βτ + ∂_β a_ατ − ∂_τ a_αβ)``, the curvature of the Monge patch
``z = f(y)``, ``K = (f_11 f_22 − f_12²)/(1 + f_1² + f_2²)²``, and the closed forms of the
sphere and the ellipsoid.
"""

import math

# isort: split
from mpi4py import MPI

import dolfinx
import dolfinx.fem
import numpy as np
import pytest
import sympy as sp
import ufl

from shellobstacle.geometry.expressions import y1, y2
from shellobstacle.geometry.surface import Surface
from shellobstacle.obstacle import Plane

R, OFFSET = 1.0, 0.85
AXES, ELL_OFFSET = (0.8, 0.6, 0.5), 0.1
POINTS = [(0.0, 0.0), (0.1, -0.2), (0.25, 0.15), (-0.3, 0.3), (0.05, 0.28)]
RTOL = 1e-12


def _num(expr, point) -> float:
    """Value of a SymPy expression in ``y1, y2`` at ``point`` (high-precision evaluation)."""
    subs = {y1: sp.Float(point[0], 30), y2: sp.Float(point[1], 30)}
    return float(sp.sympify(expr).xreplace(subs).evalf(30))


def _close(value, reference, rtol=RTOL, scale=1.0) -> bool:
    return abs(value - reference) <= rtol * max(abs(reference), scale)


def _metric_reference(theta):
    """Metric, its inverse and Christoffel symbols ``Γ[σ][α][β]`` from the metric formula."""
    Y = (y1, y2)
    d = [[sp.diff(t, y) for t in theta] for y in Y]
    a = sp.Matrix(2, 2, lambda i, j: sum(d[i][k] * d[j][k] for k in range(3)))
    ainv = a.inv()
    gamma = [
        [
            [
                sum(
                    ainv[s, t]
                    * (
                        sp.diff(a[be, t], Y[al])
                        + sp.diff(a[al, t], Y[be])
                        - sp.diff(a[al, be], Y[t])
                    )
                    for t in range(2)
                )
                / 2
                for be in range(2)
            ]
            for al in range(2)
        ]
        for s in range(2)
    ]
    return a, ainv, gamma


def _monge_curvature(f):
    """Gaussian curvature of the graph ``z = f(y1, y2)``."""
    f1, f2 = sp.diff(f, y1), sp.diff(f, y2)
    f11, f12, f22 = sp.diff(f, y1, 2), sp.diff(f, y1, y2), sp.diff(f, y2, 2)
    return (f11 * f22 - f12**2) / (1 + f1**2 + f2**2) ** 2


@pytest.fixture(scope="module")
def sphere():
    return Surface.spherical_cap(radius=R, offset=OFFSET)


@pytest.fixture(scope="module")
def ellipsoid():
    return Surface.ellipsoid_cap(AXES, offset=ELL_OFFSET)


@pytest.fixture(scope="module")
def references(sphere, ellipsoid):
    """``(Geometry on SymPy, metric reference)`` of each surface, built once."""
    return {
        name: (s.geometry_sympy(), _metric_reference(s.theta))
        for name, s in (("sphere", sphere), ("ellipsoid", ellipsoid))
    }


@pytest.mark.parametrize("point", POINTS)
def test_spherical_cap_closed_forms(sphere, point):
    """K = 1/R², b_αβ = −a_αβ/R (outward a_3), √a = R/√(R² − |y|²), a_3 points up."""
    G = sphere.geometry_sympy()
    r2 = point[0] ** 2 + point[1] ** 2
    assert _close(_num(G.gaussian_curvature, point), 1.0 / R**2)
    assert _close(_num(G.sqrt_a, point), R / math.sqrt(R**2 - r2))
    assert _close(_num(G.mean_curvature, point), -1.0 / R)
    for al in range(2):
        for be in range(2):
            a_ab = _num(G.a_lower[al][be], point)
            assert _close(_num(G.b_lower[al][be], point), -a_ab / R, scale=1.0)
    # a_3 is the outward unit normal of the sphere centred at (0, 0, −offset)
    x = [_num(t, point) for t in sphere.theta]
    outward = np.array([x[0], x[1], x[2] + OFFSET]) / R
    a3 = np.array([_num(c, point) for c in G.a3])
    np.testing.assert_allclose(a3, outward, rtol=0, atol=1e-14)
    assert a3[2] > 0


def _check_christoffel_and_bases(G, reference, point):
    a, ainv, gamma = reference
    for al in range(2):
        for be in range(2):
            assert _close(_num(G.a_lower[al][be], point), _num(a[al, be], point), scale=1.0)
            assert _close(_num(G.a_upper[al][be], point), _num(ainv[al, be], point), scale=1.0)
            for s in range(2):
                assert _close(
                    _num(G.christoffel[s][al][be], point), _num(gamma[s][al][be], point), scale=1.0
                ), (s, al, be)
    assert _close(_num(G.det_a, point), _num(a.det(), point))
    # a^j · a_i = δ^j_i with a_3 = a^3
    cov = [*G.a_cov, G.a3]
    for j in range(3):
        for i in range(3):
            value = _num(sum(G.a_contra[j][k] * cov[i][k] for k in range(3)), point)
            assert abs(value - (1.0 if i == j else 0.0)) <= 1e-14, (j, i)
    # a_3 is a unit normal: orthogonal to a_1 and a_2 (checked above) and of length 1
    assert abs(_num(sum(c * c for c in G.a3), point) - 1.0) <= 1e-14


@pytest.mark.parametrize("point", POINTS)
@pytest.mark.parametrize("name", ["sphere", "ellipsoid"])
def test_christoffel_and_bases(references, name, point):
    """Metric, inverse, Γ^σ_αβ against the metric formula; a^j · a_i = δ^j_i; |a_3| = 1."""
    _check_christoffel_and_bases(*references[name], point)


@pytest.mark.parametrize("point", POINTS)
def test_ellipsoid_cap_curvature(ellipsoid, point):
    """K against the Monge-patch formula and the classical ellipsoid formula."""
    G = ellipsoid.geometry_sympy()
    A, B, C = AXES
    K = _num(G.gaussian_curvature, point)
    assert _close(K, _num(_monge_curvature(ellipsoid.theta[2]), point))
    x1, x2 = point
    x3 = C * math.sqrt(1 - x1**2 / A**2 - x2**2 / B**2)  # the point on the full ellipsoid
    K_classical = 1.0 / (A * B * C) ** 2 / (x1**2 / A**4 + x2**2 / B**4 + x3**2 / C**4) ** 2
    assert _close(K, K_classical)
    assert K > 0
    # at the apex the principal curvatures are −C/A² and −C/B² (normal pointing up)
    if point == (0.0, 0.0):
        k_lo, k_hi = (_num(k, point) for k in G.principal_curvatures())
        assert _close(k_lo, -C / B**2) and _close(k_hi, -C / A**2)


def _all_quantities(G):
    """Every scalar of a Geometry, flattened in a fixed order."""
    out = [G.sqrt_a, G.det_a, G.gaussian_curvature, G.mean_curvature, *G.a3]
    out += [G.a_lower[i][j] for i in range(2) for j in range(2)]
    out += [G.a_upper[i][j] for i in range(2) for j in range(2)]
    out += [G.b_lower[i][j] for i in range(2) for j in range(2)]
    out += [G.b_mixed[i][j] for i in range(2) for j in range(2)]
    out += [G.christoffel[s][i][j] for s in range(2) for i in range(2) for j in range(2)]
    out += [c for v in G.a_contra for c in v]
    plane = Plane((0.0, 0.6, 0.8))
    out += [*plane.c(G), plane.c_norm(G)]
    return out


def test_from_strings_matches_spherical_cap(sphere):
    """A user θ given as strings gives the same geometry as the built-in spherical cap."""
    user = Surface.from_strings(["y1", "y2", "sqrt(1-y1**2-y2**2)-0.85"])
    ref, got = _all_quantities(sphere.geometry_sympy()), _all_quantities(user.geometry_sympy())
    for point in POINTS:
        for r, g in zip(ref, got, strict=True):
            assert _close(_num(g, point), _num(r, point), scale=1.0)


@pytest.mark.parametrize("name", ["sphere", "ellipsoid"])
def test_numpy_backend_matches_sympy(name, request):
    surface = request.getfixturevalue(name)
    pts = np.array(POINTS)
    ref = _all_quantities(surface.geometry_sympy())
    got = _all_quantities(surface.geometry_numpy(pts))
    for r, g in zip(ref, got, strict=True):
        expected = np.array([_num(r, p) for p in pts])
        got_values = np.broadcast_to(g, expected.shape)
        np.testing.assert_allclose(got_values, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ["sphere", "ellipsoid"])
def test_theta_numpy_is_the_geometry_theta(name, request):
    """``theta_numpy`` gives θ of ``geometry_numpy`` as full arrays, also for a constant
    component and when evaluated again (the lambdified expressions are reused)."""
    surface = request.getfixturevalue(name)
    pts = np.array(POINTS)
    for _ in range(2):
        theta = surface.theta_numpy(pts)
        reference = surface.geometry_numpy(pts).theta
        assert len(theta) == 3
        for t, r in zip(theta, reference, strict=True):
            assert t.shape == (len(pts),)
            np.testing.assert_array_equal(t, np.broadcast_to(r, t.shape))
    flat = Surface.from_strings(["y1", "y2", "0.25"])
    np.testing.assert_array_equal(flat.theta_numpy(pts)[2], np.full(len(pts), 0.25))


@pytest.mark.mpi
@pytest.mark.parametrize("name", ["sphere", "ellipsoid"])
def test_ufl_backend_at_nodes(name, request):
    """K, √a and Γ^1_12 of ``geometry_ufl`` interpolated into P1 equal the exact nodal values."""
    surface = request.getfixturevalue(name)
    comm = MPI.COMM_WORLD
    mesh = dolfinx.mesh.create_rectangle(comm, [[-0.3, -0.3], [0.3, 0.3]], [6, 5])
    V = dolfinx.fem.functionspace(mesh, ("Lagrange", 1))
    G = surface.geometry_ufl(mesh)
    nodes = V.tabulate_dof_coordinates()
    exact = surface.geometry_numpy(nodes)
    assert isinstance(G.gaussian_curvature, ufl.core.expr.Expr)
    for quantity, reference in [
        (G.gaussian_curvature, exact.gaussian_curvature),
        (G.sqrt_a, exact.sqrt_a),
        (G.christoffel[0][0][1], exact.christoffel[0][0][1]),
    ]:
        f = dolfinx.fem.Function(V)
        f.interpolate(dolfinx.fem.Expression(quantity, V.element.interpolation_points))
        local = np.abs(f.x.array - reference).max(initial=0.0)
        scale = comm.allreduce(np.abs(reference).max(initial=0.0), op=MPI.MAX)
        assert comm.allreduce(local, op=MPI.MAX) <= 1e-12 * max(scale, 1.0)
    if name == "sphere":
        np.testing.assert_allclose(exact.gaussian_curvature, 1.0 / R**2, rtol=1e-12)
    else:  # the ellipsoid's K is not constant: the comparison above is not trivial
        K = exact.gaussian_curvature
        k_max = comm.allreduce(K.max(initial=-np.inf), op=MPI.MAX)
        k_min = comm.allreduce(K.min(initial=np.inf), op=MPI.MIN)
        assert k_max - k_min > 0.1 * k_max
