"""Membrane strain, elasticity tensor and stresses (docs/model.md §2; the model page's
:eq:`membrane-strain`, :eq:`elasticity-tensor`, :eq:`strong-form`); the gap is the
obstacle's (:mod:`shellobstacle.obstacle`).

Pure functions on scalar lists, usable with UFL (forms) and SymPy (manufactured
solutions). ``eta[i]`` are covariant displacement components ``η_i`` and
``grad_eta[i][α] = ∂_α η_i``; ``G`` is a :class:`~shellobstacle.geometry.surface.Geometry`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from shellobstacle.geometry.surface import Geometry

__all__ = [
    "elastic_product",
    "membrane_stress",
    "strain",
    "stress_divergence",
]

Tensor2 = list[list[Any]]


def strain(G: Geometry, eta: Sequence[Any], grad_eta: Sequence[Sequence[Any]]) -> Tensor2:
    """Linearized change of metric ``γ_αβ(η) = ½(∂_β η_α + ∂_α η_β) − Γ^σ_αβ η_σ − b_αβ η_3``
    (:eq:`membrane-strain`)."""
    return [
        [
            (grad_eta[al][be] + grad_eta[be][al]) / 2
            - G.christoffel[0][al][be] * eta[0]
            - G.christoffel[1][al][be] * eta[1]
            - G.b_lower[al][be] * eta[2]
            for be in range(2)
        ]
        for al in range(2)
    ]


def _elasticity_coefficient(G: Geometry, lam: Any, mu: Any, al: int, be: int, s: int, t: int):
    """``a^{αβστ} = (4λμ/(λ+2μ)) a^{αβ} a^{στ} + 2μ (a^{ασ} a^{βτ} + a^{ατ} a^{βσ})``
    (:eq:`elasticity-tensor`)."""
    A = G.a_upper
    return (4 * lam * mu / (lam + 2 * mu)) * A[al][be] * A[s][t] + 2 * mu * (
        A[al][s] * A[be][t] + A[al][t] * A[be][s]
    )


def membrane_stress(G: Geometry, epsilon: Any, lam: Any, mu: Any, gamma: Tensor2) -> Tensor2:
    """Contravariant membrane stress ``n^{αβ} = ε a^{αβστ} γ_στ``."""
    return [
        [
            epsilon
            * sum(
                _elasticity_coefficient(G, lam, mu, al, be, s, t) * gamma[s][t]
                for s in range(2)
                for t in range(2)
            )
            for be in range(2)
        ]
        for al in range(2)
    ]


def elastic_product(G: Geometry, lam: Any, mu: Any, gamma_s: Tensor2, gamma_t: Tensor2) -> Any:
    """``a^{αβστ} γ_στ(s) γ_αβ(t)``: the integrand of the membrane bilinear form (without ε√a).

    Uses the closed form ``(4λμ/(λ+2μ)) tr_a(γ_s) tr_a(γ_t) + 2μ (a^{ασ}a^{βτ} +
    a^{ατ}a^{βσ}) γ_στ(s) γ_αβ(t)`` with ``tr_a(γ) = a^{αβ} γ_αβ``.
    """
    A = G.a_upper
    tr_s = sum(A[al][be] * gamma_s[al][be] for al in range(2) for be in range(2))
    tr_t = sum(A[al][be] * gamma_t[al][be] for al in range(2) for be in range(2))
    shear = sum(
        (A[al][s] * A[be][t] + A[al][t] * A[be][s]) * gamma_s[s][t] * gamma_t[al][be]
        for al in range(2)
        for be in range(2)
        for s in range(2)
        for t in range(2)
    )
    return (4 * lam * mu / (lam + 2 * mu)) * tr_s * tr_t + 2 * mu * shear


def stress_divergence(G: Geometry, n: Tensor2, dn: Sequence[Sequence[Sequence[Any]]]) -> list[Any]:
    """Covariant divergence ``n^{αβ}|_β = ∂_β n^{αβ} + Γ^α_βτ n^{βτ} + Γ^β_βτ n^{ατ}``
    (:eq:`strong-form`).

    ``dn[α][β][σ] = ∂_σ n^{αβ}``.
    """
    C = G.christoffel
    return [
        sum(dn[al][be][be] for be in range(2))
        + sum(C[al][be][t] * n[be][t] for be in range(2) for t in range(2))
        + sum(C[be][be][t] * n[al][t] for be in range(2) for t in range(2))
        for al in range(2)
    ]
