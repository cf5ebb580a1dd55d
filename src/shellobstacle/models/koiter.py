"""Koiter's linear shell model: the change of curvature and its C⁰ interior-penalty energy
(docs/model.md §8, :eq:`koiter-energy`; Ciarlet 2005, ch. 4).

The change of curvature :func:`change_of_curvature` is a pure function on scalar lists, like
:mod:`shellobstacle.models.membrane`, usable with UFL and SymPy. :func:`bending_energy` writes the
bending energy of a C⁰ Lagrange ``ζ_3`` (degree ≥ 2): basix has no C¹ element, so the H²
conformity of ``ζ_3`` and the clamped condition ``∂_ν ζ_3 = 0`` are imposed weakly, by the
symmetric interior-penalty terms of the bending moment on the facets (Engel et al. 2002,
Brenner & Sung 2005; :eq:`koiter-c0ip`):

    E_b(η) = ½ Σ_T ∫_T m^{αβ}(η) ρ_αβ(η) √a dy − Σ_F ∫_F {M_nn(η)} [∂_n η_3] ds
             + ½ Σ_F ∫_F (σ / h_F) C_F [∂_n η_3]² ds,

with ``m^{αβ} = (ε³/3) a^{αβστ} ρ_στ``, ``M_nn = √a m^{αβ} n_α n_β`` (``n`` the unit normal of
the facet in the plane of ω), ``C_F = (ε³/3) √a a^{αβστ} n_α n_β n_σ n_τ`` the facet's bending
stiffness and ``F`` running over the interior facets and the clamped boundary (where the
jump is ``∂_n η_3`` itself). The exact solution satisfies the discrete equations (the
facet terms are what integrating the broken Hessian by parts leaves), so the method is
consistent; ``σ`` large enough makes it coercive. The default bending form is the hybrid
one of :mod:`shellobstacle.models.hybrid_bending`, which reuses this module's change of curvature,
bending moment and facet stiffness.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import ufl

from shellobstacle.geometry.surface import Geometry
from shellobstacle.models.membrane import elastic_product

__all__ = [
    "DEFAULT_INTERIOR_PENALTY",
    "bending_energy",
    "bending_moment",
    "change_of_curvature",
    "facet_stiffness",
    "normal_normal",
]

Tensor2 = list[list[Any]]

DEFAULT_INTERIOR_PENALTY = 8.0
"""``σ`` of the facet penalty for P2 with ``h_F`` the mean diameter of the facet's cells:
the value of the DOLFINx biharmonic demo. The solutions change by less than the
discretization error between σ = 8 and σ = 32 (tests/models/test_koiter.py)."""


def change_of_curvature(
    G: Geometry,
    eta: Sequence[Any],
    grad_eta: Sequence[Sequence[Any]],
    hess_eta3: Sequence[Sequence[Any]],
) -> Tensor2:
    """Linearized change of curvature ``ρ_αβ(η)`` (:eq:`change-of-curvature`; Ciarlet 2005,
    Thm 4.2-1):

    ``ρ_αβ = ∂_αβ η_3 − Γ^σ_αβ ∂_σ η_3 − b^σ_α b_σβ η_3 + b^σ_α (∂_β η_σ − Γ^τ_βσ η_τ)
    + b^τ_β (∂_α η_τ − Γ^σ_ατ η_σ) + b^τ_{β|α} η_τ``.

    ``eta[i] = η_i`` (covariant), ``grad_eta[i][α] = ∂_α η_i``, ``hess_eta3[α][β] = ∂_αβ η_3``;
    ``G`` needs the third derivatives of θ (for ``b^τ_{β|α}``).
    """
    r = range(2)
    C, b, bm, bd = G.christoffel, G.b_lower, G.b_mixed, G.b_covariant_derivative

    def cov(s: int, be: int) -> Any:  # η_{σ|β} = ∂_β η_σ − Γ^τ_βσ η_τ
        return grad_eta[s][be] - sum(C[t][be][s] * eta[t] for t in r)

    return [
        [
            hess_eta3[al][be]
            - sum(C[s][al][be] * grad_eta[2][s] for s in r)
            - sum(bm[al][s] * b[s][be] for s in r) * eta[2]
            + sum(bm[al][s] * cov(s, be) for s in r)
            + sum(bm[be][t] * cov(t, al) for t in r)
            + sum(bd[al][t][be] * eta[t] for t in r)
            for be in r
        ]
        for al in r
    ]


def bending_moment(G: Geometry, epsilon: Any, lam: Any, mu: Any, rho: Tensor2) -> Tensor2:
    """Contravariant bending moment ``m^{αβ} = (ε³/3) a^{αβστ} ρ_στ``."""
    A = G.a_upper
    lame = 4 * lam * mu / (lam + 2 * mu)
    trace = sum(A[s][t] * rho[s][t] for s in range(2) for t in range(2))
    scale = epsilon**3 / 3
    return [
        [
            scale
            * (
                lame * A[al][be] * trace
                + 2
                * mu
                * sum(
                    (A[al][s] * A[be][t] + A[al][t] * A[be][s]) * rho[s][t]
                    for s in range(2)
                    for t in range(2)
                )
            )
            for be in range(2)
        ]
        for al in range(2)
    ]


def normal_normal(m: Tensor2, n: Any) -> Any:
    """``m^{αβ} n_α n_β``."""
    return sum(m[al][be] * n[al] * n[be] for al in range(2) for be in range(2))


def facet_stiffness(G: Geometry, epsilon: Any, lam: Any, mu: Any, n: Any) -> Any:
    """``C_F = (ε³/3) √a a^{αβστ} n_α n_β n_σ n_τ`` (the bending stiffness across the facet)."""
    A = G.a_upper
    ann = sum(A[al][be] * n[al] * n[be] for al in range(2) for be in range(2))
    lame = 4 * lam * mu / (lam + 2 * mu)
    return (epsilon**3 / 3) * G.sqrt_a * (lame + 4 * mu) * ann * ann


def bending_energy(
    G: Geometry,
    epsilon: Any,
    lam: Any,
    mu: Any,
    zeta: Any,
    dx: ufl.Measure,
    sigma: Any,
    ds_clamped: ufl.Measure | None,
) -> ufl.Form:
    """The C⁰ interior-penalty bending energy ``E_b(ζ)`` of the module docstring (UFL).

    Args:
        G: UFL geometry of θ (with third derivatives).
        epsilon, lam, mu: half-thickness and Lamé constants.
        zeta: the displacement, a vector Lagrange function (covariant components).
        dx: cell measure (its quadrature degree is used on the facets too).
        sigma: the interior penalty ``σ`` (a number or a ``Constant``).
        ds_clamped: the boundary where ``∂_ν ζ_3 = 0`` is imposed (None: nowhere).
    """
    mesh = zeta.function_space.mesh
    degree = dx.metadata().get("quadrature_degree")
    meta = {"quadrature_degree": degree} if degree else {}
    dS = ufl.Measure("dS", domain=mesh, metadata=meta)
    eta = [zeta[i] for i in range(3)]
    grad = ufl.grad(zeta)
    grad_eta = [[grad[i, a] for a in range(2)] for i in range(3)]
    hess = ufl.grad(ufl.grad(zeta[2]))
    hess_eta3 = [[hess[a, b] for b in range(2)] for a in range(2)]
    rho = change_of_curvature(G, eta, grad_eta, hess_eta3)
    m = bending_moment(G, epsilon, lam, mu, rho)
    cells = 0.5 * (epsilon**3 / 3) * elastic_product(G, lam, mu, rho, rho) * G.sqrt_a * dx

    n = ufl.FacetNormal(mesh)
    h = ufl.CellDiameter(mesh)
    M_nn = G.sqrt_a * normal_normal(m, n)
    C_F = facet_stiffness(G, epsilon, lam, mu, n)
    jump = ufl.jump(ufl.grad(zeta[2]), n)
    h_avg = (h("+") + h("-")) / 2
    interior = (-ufl.avg(M_nn) * jump + 0.5 * (sigma / h_avg) * ufl.avg(C_F) * jump * jump) * dS
    energy = cells + interior
    if ds_clamped is not None:
        dn = ufl.dot(ufl.grad(zeta[2]), n)
        energy += (-M_nn * dn + 0.5 * (sigma / h) * C_F * dn * dn) * ds_clamped
    return energy
