"""θ, its first and second derivatives and the load must be finite on ω̄.

Where they are not (a square root of a negative number, a sphere narrower than ω, an
overflow, a division by zero), nothing of the theory applies, and the assumption table would
only show NaN. :func:`require_finite` evaluates them at the points the checks sample and
raises one :class:`~shellobstacle.geometry.expressions.ExpressionError` naming the key, the quantity
and the point of the mesh nearest the origin where it fails, identical on every rank.
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import numpy as np
import sympy as sp

from shellobstacle.geometry.expressions import ExpressionError, y1, y2
from shellobstacle.geometry.surface import Geometry
from shellobstacle.geometry.translation import to_numpy
from shellobstacle.spec import Shell

__all__ = ["SURFACE_NAMES", "Failure", "first_failure", "require_finite"]

#: (group: 0 surface, 1 load; ``|y|²``; y1; y2; the quantity's index in its group; its value)
Failure = tuple[int, float, float, float, int, float]

_PAIRS = [(a, b) for a in range(2) for b in range(a, 2)]
#: the names of the surface's quantities, in the order of :func:`_surface_values`
SURFACE_NAMES = (
    [f"θ_{i + 1}" for i in range(3)]
    + [f"∂_{a + 1}θ_{i + 1}" for a in range(2) for i in range(3)]
    + [f"∂_{a + 1}∂_{b + 1}θ_{i + 1}" for a, b in _PAIRS for i in range(3)]
)


def _surface_values(G: Geometry) -> list[Any]:
    """θ_i, ∂_α θ_i and ∂_α∂_β θ_i (α ≤ β) as evaluated in ``G`` (order of SURFACE_NAMES)."""
    return (
        [G.theta[i] for i in range(3)]
        + [G.a_cov[a][i] for a in range(2) for i in range(3)]
        + [G.d2[a][b][i] for a, b in _PAIRS for i in range(3)]
    )


def _load_values(shell: Shell, pts: np.ndarray) -> list[Any]:
    """``p^i`` at ``pts`` with the load parameters at their given values (constant
    components, checked when parsed, as 0)."""
    names = sorted(shell.load.parameters)
    args = (y1, y2, *(sp.Symbol(n, real=True) for n in names))
    values = [float(shell.load.parameters[n]) for n in names]
    return [
        to_numpy(expr, args)(pts[:, 0], pts[:, 1], *values) if expr.free_symbols else 0.0
        for expr in shell.load_expressions()
    ]


def first_failure(shell: Shell, G: Geometry, pts: np.ndarray) -> Failure | None:
    """The first non-finite quantity at the point of ``pts`` nearest the origin (surface
    before load), or None when all are finite."""
    found: list[Failure] = []
    r2 = pts[:, 0] ** 2 + pts[:, 1] ** 2
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        groups = (_surface_values(G), _load_values(shell, pts))
    for group, values in enumerate(groups):
        for index, value in enumerate(values):
            v = np.broadcast_to(np.asarray(value, dtype=float), (len(pts),))
            bad = np.flatnonzero(~np.isfinite(v))
            if bad.size:
                k = bad[np.lexsort((pts[bad, 1], pts[bad, 0], r2[bad]))[0]]
                found.append((group, float(r2[k]), float(pts[k, 0]), float(pts[k, 1]), index,
                              float(v[k])))  # fmt: skip
    return min(found) if found else None


def require_finite(shell: Shell, failures: list[Failure | None], comm: MPI.Comm) -> None:
    """Raise :class:`ExpressionError` for the first of the ranks' ``failures`` (one line,
    the same on every rank); nothing when every quantity is finite everywhere."""
    gathered = [f for part in comm.allgather([f for f in failures if f]) for f in part]
    if not gathered:
        return
    group, _, p1, p2, index, value = min(gathered)
    at = f"y = ({p1:.4g}, {p2:.4g}), a point of the mesh"
    if group == 1:
        i = index + 1
        raise ExpressionError(
            f"load.p[{i}]: p^{i} = {value} at {at}{_with(shell)}: the load must be finite on "
            f"ω̄ (an overflow, a division by zero?); change load.p[{i}]"
        )
    raise ExpressionError(_surface_message(shell, f"{SURFACE_NAMES[index]} = {value} at {at}"))


def _with(shell: Shell) -> str:
    """`` with ell = 0`` for the load parameters, if any."""
    params = ", ".join(f"{k} = {v:g}" for k, v in sorted(shell.load.parameters.items()))
    return f" with {params}" if params else ""


def _surface_message(shell: Shell, what: str) -> str:
    """The key and the fix for a surface not finite somewhere on ω̄."""
    s = shell.surface
    if s.name == "spherical_cap":
        R = s.parameters["radius"]
        return (
            f"surface.radius: the cap θ_3 = √(R² − |y|²) − offset is not smooth on ω̄: {what}: "
            f"the sphere of radius R = {R:g} must cover ω̄ with room (|y| < R everywhere); raise "
            "surface.radius or shrink [domain]"
        )
    if s.name == "ellipsoid_cap":
        A, B, _ = s.parameters["semi_axes"]
        return (
            f"surface.semi_axes: the cap θ_3 = C√(1 − y1²/A² − y2²/B²) − offset is not smooth on "
            f"ω̄: {what}: the ellipse y1²/A² + y2²/B² < 1 (A = {A:g}, B = {B:g}) must contain "
            "ω̄; raise A and B or shrink [domain]"
        )
    return (
        f"surface.theta: θ is not smooth on ω̄: {what} (a root or a logarithm of a negative "
        "number, a division by zero?): θ and its derivatives must be finite on all of ω̄; "
        "change surface.theta or shrink [domain]"
    )
