"""The middle surface θ(ω̄) and its differential geometry (docs/model.md §1).

A :class:`Surface` holds the immersion ``θ(y1, y2)`` as three SymPy expressions.
Its first and second derivatives are taken symbolically, and :class:`Geometry`
turns them into every quantity of the theory. :class:`Geometry` is written once
on plain scalars, so the same code gives exact SymPy expressions (tests,
manufactured solutions), UFL expressions evaluated exactly at quadrature points
(the forms), and NumPy arrays at mesh nodes (assumption checks, output).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import sympy as sp

from shellobstacle.geometry.expressions import ExpressionError, parse, y1, y2
from shellobstacle.geometry.translation import to_numpy, to_ufl

__all__ = ["SURFACE_KINDS", "Geometry", "Surface"]

Vec = list[Any]  # three scalars (SymPy, UFL or NumPy)


def dot(u: Sequence[Any], v: Sequence[Any]) -> Any:
    """Euclidean inner product of two 3-vectors given as scalar lists."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def cross(u: Sequence[Any], v: Sequence[Any]) -> Vec:
    """Cross product ``u ∧ v`` of two 3-vectors given as scalar lists."""
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


class Geometry:
    """Bases, fundamental forms, Christoffel symbols and curvature of θ (docs/model.md §1;
    :eq:`covariant-basis`, :eq:`second-fundamental-form`).

    Built from ``theta`` (three scalars), ``d1[α][i] = ∂_α θ_i``,
    ``d2[α][β][i] = ∂_α ∂_β θ_i`` and, for the curvature terms of Koiter's model only,
    ``d3[α][β][γ][i] = ∂_α ∂_β ∂_γ θ_i``; ``sqrt`` is the square root of the backend
    (``sympy.sqrt``, ``numpy.sqrt`` or ``ufl.sqrt``). Indices are 0-based:
    ``a_cov[α]`` is ``a_α``, ``a_contra[j]`` is ``a^j``, ``christoffel[σ][α][β]``
    is ``Γ^σ_αβ``, ``b_mixed[α][β]`` is ``b_α^β``.
    """

    def __init__(
        self,
        theta: Sequence[Any],
        d1: Sequence[Sequence[Any]],
        d2: Sequence[Sequence[Sequence[Any]]],
        sqrt: Callable[[Any], Any],
        d3: Sequence[Sequence[Sequence[Sequence[Any]]]] | None = None,
    ) -> None:
        self.theta = list(theta)
        self.sqrt = sqrt
        self.d2, self._d3 = d2, d3  # ∂_α∂_β θ_i, kept for the finiteness check
        a1, a2 = list(d1[0]), list(d1[1])
        self.a_cov: list[Vec] = [a1, a2]
        normal = cross(a1, a2)
        self.sqrt_a = sqrt(dot(normal, normal))  # |a_1 ∧ a_2| = √a
        self.a3: Vec = [n / self.sqrt_a for n in normal]
        # first fundamental form a_αβ, a = det(a_αβ), inverse a^{αβ}
        self.a_lower = [[dot(self.a_cov[al], self.a_cov[be]) for be in range(2)] for al in range(2)]
        (a11, a12), (_, a22) = self.a_lower
        self.det_a = a11 * a22 - a12 * a12
        self.a_upper = [
            [a22 / self.det_a, -a12 / self.det_a],
            [-a12 / self.det_a, a11 / self.det_a],
        ]
        # contravariant basis a^α = a^{αβ} a_β, a^3 = a_3
        self.a_contra: list[Vec] = [
            [self.a_upper[al][0] * a1[i] + self.a_upper[al][1] * a2[i] for i in range(3)]
            for al in range(2)
        ]
        self.a_contra.append(self.a3)
        # second fundamental form b_αβ = ∂_α a_β · a_3, mixed b_α^β = a^{βσ} b_ασ
        self.b_lower = [[dot(d2[al][be], self.a3) for be in range(2)] for al in range(2)]
        self.b_mixed = [
            [sum(self.a_upper[be][s] * self.b_lower[al][s] for s in range(2)) for be in range(2)]
            for al in range(2)
        ]
        # Christoffel symbols Γ^σ_αβ = ∂_α a_β · a^σ
        self.christoffel = [
            [[dot(d2[al][be], self.a_contra[s]) for be in range(2)] for al in range(2)]
            for s in range(2)
        ]
        (b11, b12), (_, b22) = self.b_lower
        self.gaussian_curvature = (b11 * b22 - b12 * b12) / self.det_a
        self.mean_curvature = (self.b_mixed[0][0] + self.b_mixed[1][1]) / 2

    @cached_property
    def b_covariant_derivative(self) -> list[list[list[Any]]]:
        """``b^τ_{β|α} = ∂_α b^τ_β + Γ^τ_ασ b^σ_β − Γ^σ_αβ b^τ_σ`` as ``[α][τ][β]``
        (:eq:`b-covariant-derivative`).

        ``∂_α b^τ_β`` is taken from ``d3`` through ``∂_α a_3 = −b_α^σ a_σ`` (Weingarten) and
        ``∂_α a^{τσ} = −a^{τμ} (∂_α a_μν) a^{νσ}``: no differentiation of the backend's
        expressions. Needs ``d3``.
        """
        if self._d3 is None:
            raise ValueError("b^τ_{β|α} needs the third derivatives of θ (Geometry(d3=...))")
        d2, d3, A, b, C = self.d2, self._d3, self.a_upper, self.b_lower, self.christoffel
        r = range(2)
        # Γ_αβ,σ = ∂_α a_β · a_σ (lower Christoffel symbols)
        low = [[[dot(d2[al][be], self.a_cov[s]) for s in r] for be in r] for al in r]
        # ∂_γ b_βσ = ∂_γ∂_β a_σ·a_3 + ∂_β a_σ·∂_γ a_3 = d3·a_3 − b_γ^μ Γ_βσ,μ
        db = [
            [
                [
                    dot(d3[g][be][s], self.a3) - sum(self.b_mixed[g][m] * low[be][s][m] for m in r)
                    for s in r
                ]
                for be in r
            ]
            for g in r
        ]
        # ∂_γ a^{τσ} = −a^{τμ} (Γ_γμ,ν + Γ_γν,μ) a^{νσ}
        da = [
            [
                [
                    -sum(A[t][m] * (low[g][m][n] + low[g][n][m]) * A[n][s] for m in r for n in r)
                    for s in r
                ]
                for t in r
            ]
            for g in r
        ]
        # ∂_γ b^τ_β = ∂_γ a^{τσ} b_βσ + a^{τσ} ∂_γ b_βσ
        dbm = [
            [
                [sum(da[g][t][s] * b[be][s] + A[t][s] * db[g][be][s] for s in r) for be in r]
                for t in r
            ]
            for g in r
        ]
        bm = self.b_mixed  # b^σ_β = b_mixed[β][σ]
        return [
            [
                [
                    dbm[al][t][be]
                    + sum(C[t][al][s] * bm[be][s] for s in r)
                    - sum(C[s][al][be] * bm[s][t] for s in r)
                    for be in r
                ]
                for t in r
            ]
            for al in r
        ]

    def principal_curvatures(self) -> tuple[Any, Any]:
        """The eigenvalues ``H ∓ √(H² − K)`` of ``b_α^β``."""
        H, K = self.mean_curvature, self.gaussian_curvature
        disc = self.sqrt(H * H - K)
        return H - disc, H + disc

    def cartesian(self, eta: Sequence[Any]) -> Vec:
        """Cartesian components of the displacement ``η_i a^i``."""
        return [sum(eta[j] * self.a_contra[j][k] for j in range(3)) for k in range(3)]


SURFACE_KINDS = ("spherical_cap", "ellipsoid_cap", "elliptic_paraboloid", "expression")


@dataclass(frozen=True)
class Surface:
    """An immersion ``θ: ω̄ → E³`` given by three SymPy expressions in ``y1, y2``."""

    theta: tuple[sp.Expr, sp.Expr, sp.Expr]
    name: str = "surface"
    description: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def spherical_cap(cls, radius: float, offset: float) -> Surface:
        """The paper's (50): ``θ = (y1, y2, √(R² − y1² − y2²) − offset)``."""
        if not radius > 0:
            raise ValueError(f"surface.radius must be > 0, got {radius}")
        R = sp.Float(radius)
        z = sp.sqrt(R**2 - y1**2 - y2**2) - sp.Float(offset)
        return cls(
            (y1, y2, z),
            "spherical_cap",
            f"spherical cap, R = {radius}, offset = {offset}",
            {"radius": radius, "offset": offset},
        )

    @classmethod
    def ellipsoid_cap(cls, semi_axes: Sequence[float], offset: float) -> Surface:
        """``θ = (y1, y2, C √(1 − y1²/A² − y2²/B²) − offset)`` for semi-axes ``(A, B, C)``."""
        if len(semi_axes) != 3 or not all(v > 0 for v in semi_axes):
            raise ValueError(f"surface.semi_axes must be three numbers > 0, got {semi_axes}")
        A, B, C = (sp.Float(v) for v in semi_axes)
        z = C * sp.sqrt(1 - y1**2 / A**2 - y2**2 / B**2) - sp.Float(offset)
        return cls(
            (y1, y2, z),
            "ellipsoid_cap",
            f"ellipsoid cap, semi-axes = {tuple(semi_axes)}, offset = {offset}",
            {"semi_axes": list(semi_axes), "offset": offset},
        )

    @classmethod
    def elliptic_paraboloid(cls, height: float, curvatures: Sequence[float]) -> Surface:
        """``θ = (y1, y2, height − (k1 y1² + k2 y2²)/2)``: apex curvatures ``k1, k2``."""
        k1, k2 = (sp.Float(v) for v in curvatures)
        z = sp.Float(height) - (k1 * y1**2 + k2 * y2**2) / 2
        return cls(
            (y1, y2, z),
            "elliptic_paraboloid",
            f"elliptic paraboloid, height = {height}, curvatures = {tuple(curvatures)}",
            {"height": height, "curvatures": list(curvatures)},
        )

    @classmethod
    def from_strings(cls, theta: Sequence[str], what: str = "surface.theta") -> Surface:
        """A user immersion from three SymPy-syntax strings in ``y1, y2``."""
        if len(theta) != 3:
            raise ExpressionError(f"{what}: expected three components, got {len(theta)}")
        names = {"y1": y1, "y2": y2, "r": sp.sqrt(y1**2 + y2**2)}
        comps = tuple(parse(t, names, f"{what}[{i + 1}]") for i, t in enumerate(theta))
        return cls(comps, "expression", f"θ = ({', '.join(map(str, theta))})", {"theta": theta})

    @cached_property
    def d1(self) -> list[list[sp.Expr]]:
        """``∂_α θ_i`` (SymPy)."""
        return [[sp.diff(t, y) for t in self.theta] for y in (y1, y2)]

    @cached_property
    def d2(self) -> list[list[list[sp.Expr]]]:
        """``∂_α ∂_β θ_i`` (SymPy)."""
        return [[[sp.diff(t, ya, yb) for t in self.theta] for yb in (y1, y2)] for ya in (y1, y2)]

    @cached_property
    def d3(self) -> list[list[list[list[sp.Expr]]]]:
        """``∂_α ∂_β ∂_γ θ_i`` (SymPy; Koiter's change of curvature needs them)."""
        Y = (y1, y2)
        return [[[[sp.diff(t, a, b, c) for t in self.theta] for c in Y] for b in Y] for a in Y]

    def geometry_sympy(self) -> Geometry:
        """Exact symbolic geometry (for tests and manufactured solutions)."""
        return Geometry(list(self.theta), self.d1, self.d2, sp.sqrt, self.d3)

    def geometry_ufl(self, mesh: Any) -> Geometry:
        """Geometry as UFL expressions of the spatial coordinate: exact at quadrature points."""
        import ufl

        x = ufl.SpatialCoordinate(mesh)
        sym = {y1: x[0], y2: x[1]}

        def tr(e: sp.Expr) -> Any:
            return to_ufl(e, sym)

        theta = [tr(t) for t in self.theta]
        d1 = [[tr(e) for e in row] for row in self.d1]
        d2 = [[[tr(e) for e in col] for col in row] for row in self.d2]
        d3 = [[[[tr(e) for e in c] for c in col] for col in row] for row in self.d3]
        return Geometry(theta, d1, d2, ufl.sqrt, d3)

    def theta_numpy(self, points: np.ndarray) -> list[np.ndarray]:
        """``θ`` at ``points`` (shape ``(n, ≥2)``, columns y1, y2), three arrays of shape ``(n,)``
        (without the derivatives :meth:`geometry_numpy` evaluates)."""
        Y1, Y2 = np.asarray(points[:, 0], float), np.asarray(points[:, 1], float)
        with np.errstate(invalid="ignore", divide="ignore"):
            return [to_numpy(t)(Y1, Y2) for t in self.theta]

    def geometry_numpy(self, points: np.ndarray) -> Geometry:
        """Geometry evaluated at ``points`` (shape ``(n, ≥2)``, columns y1, y2) with NumPy."""
        Y1, Y2 = np.asarray(points[:, 0], float), np.asarray(points[:, 1], float)
        ev = self.theta_numpy(points)
        with np.errstate(invalid="ignore", divide="ignore"):
            d1 = [[to_numpy(e)(Y1, Y2) for e in row] for row in self.d1]
            d2 = [[[to_numpy(e)(Y1, Y2) for e in col] for col in row] for row in self.d2]
        return Geometry(ev, d1, d2, np.sqrt)
