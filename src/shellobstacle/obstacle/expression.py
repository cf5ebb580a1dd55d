"""A user's obstacle ``{x : g(x) ≥ 0}``, ``g`` a formula in the ambient coordinates
``x1, x2, x3`` (docs/model.md :eq:`gap`).

``g`` goes through the safe parser of θ and the loads
(:func:`~shellobstacle.geometry.expressions.parse`); its gradient is derived symbolically, and
its Hessian decides whether it is affine (a plane written as a formula is solved as the plane
is, exactly).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import sympy as sp

from shellobstacle.geometry.expressions import ExpressionError, parse
from shellobstacle.geometry.surface import Geometry
from shellobstacle.geometry.translation import to_numpy, to_ufl
from shellobstacle.messages import shown
from shellobstacle.obstacle.base import Obstacle
from shellobstacle.obstacle.parameters import Parameter

__all__ = ["ExpressionObstacle", "X"]

X = sp.symbols("x1 x2 x3", real=True)
"""The ambient coordinates of ``g``."""


class ExpressionObstacle(Obstacle):
    """``g`` given as text (``"x3 + 0.2*(x1**2 + x2**2)"``) or a SymPy expression of :data:`X`.

    Raises:
        ExpressionError: ``g`` does not parse, names something other than ``x1, x2, x3`` and
            numbers, or cannot be differentiated to a formula with values at points.
    """

    kind = "expression"
    summary = "a formula, g(x1, x2, x3) ≥ 0"
    parameters = (
        Parameter(
            "g",
            "str",
            "g(x1, x2, x3), admissible where g ≥ 0 (x: ambient coordinates)",
            example="x3",
        ),
    )

    def __init__(self, g: str | sp.Expr, offset: float = 0.0) -> None:
        super().__init__(offset)
        names = {str(s): s for s in X}
        self.expr = parse(g, names, "obstacle.g") if isinstance(g, str) else sp.sympify(g)
        unknown = sorted(str(s) for s in self.expr.free_symbols if s not in X)
        if unknown:
            raise ExpressionError(
                f"obstacle.g = {shown(self.expr)} uses {', '.join(unknown)}: g is a formula "
                "in the ambient coordinates x1, x2, x3 and numbers only"
            )
        self.grad = [sp.diff(self.expr, s) for s in X]
        kinks = (sp.sign, sp.Heaviside, sp.DiracDelta, sp.Derivative, sp.Subs, sp.Piecewise)
        if any(d.has(*kinks) for d in self.grad):
            raise ExpressionError(
                f"obstacle.g = {shown(self.expr)} is not continuously differentiable (Abs, "
                "sign, Min, Max or Piecewise of x1, x2, x3): Newton's method needs ∇g, so "
                "write a smooth g, e.g. sqrt(x1**2 + c**2) for |x1|"
            )
        hessian = [sp.diff(d, s) for d in self.grad for s in X]
        self.affine = all(sp.simplify(h) == 0 for h in hessian)
        self.convex = True if self.affine else None  # a curved g: not decided here
        self._numpy = [to_numpy(e, X) for e in (self.expr, *self.grad)]
        self._hessian = [to_numpy(e, X) for e in hessian]

    def __repr__(self) -> str:
        return f"ExpressionObstacle(g={shown(self.expr)!r})"

    def _evaluate(self, G: Geometry, e: int, expr: sp.Expr, x: Sequence[Any]) -> Any:
        backend = _backend(G)
        if backend == "numpy":
            return self._numpy[e](*[np.asarray(v, dtype=float) for v in x])
        if backend == "ufl":
            return to_ufl(expr, dict(zip(X, x, strict=True)))
        return expr.subs(dict(zip(X, x, strict=True)))

    def value(self, G: Geometry, x: Sequence[Any]) -> Any:
        """``g(x)``."""
        return self._evaluate(G, 0, self.expr, x)

    def curvature_radius(self, x: np.ndarray) -> np.ndarray:
        """``1/max|k_i|``, ``k_i`` the principal curvatures of the level surface through
        ``x``: the eigenvalues of ``P H P / |∇g|`` (``H`` the Hessian of ``g``,
        ``P = I − n nᵀ``, ``n = ∇g/|∇g|``) on the tangent plane."""
        cols = [np.asarray(x[:, k], dtype=float) for k in range(3)]
        n = x.shape[0]
        full = lambda v: np.broadcast_to(np.asarray(v, dtype=float), (n,))  # noqa: E731
        with np.errstate(invalid="ignore", divide="ignore"):
            grad = np.stack([full(f(*cols)) for f in self._numpy[1:]], axis=1)
            H = np.stack([full(f(*cols)) for f in self._hessian], axis=1).reshape(n, 3, 3)
            norm = np.linalg.norm(grad, axis=1)
            unit = grad / norm[:, None]
            P = np.eye(3)[None] - unit[:, :, None] * unit[:, None, :]
            shape = P @ H @ P / norm[:, None, None]
            k = np.abs(np.linalg.eigvalsh(shape)).max(axis=1)
            return 1.0 / k

    def gradient(self, G: Geometry, x: Sequence[Any]) -> list[Any]:
        """``∇g(x)``, derived symbolically (constants stay numbers: a plane's UFL is a plane's)."""
        out = []
        for j, d in enumerate(self.grad):
            out.append(float(d) if d.is_Number else self._evaluate(G, j + 1, d, x))
        return out


def _backend(G: Geometry) -> str:
    """``"numpy"``, ``"ufl"`` or ``"sympy"``: the backend of ``G`` (its square root's)."""
    if G.sqrt is np.sqrt:
        return "numpy"
    if getattr(G.sqrt, "__module__", "").startswith("ufl"):
        return "ufl"
    return "sympy"
