"""Parsed user expressions (:mod:`shellobstacle.geometry.expressions`) translated into UFL
(exact values at quadrature points) and into NumPy functions (values at mesh nodes for the
checks and the postprocessing).

What SymPy or its NumPy printer raises while translating an expression or its derivatives
becomes an :class:`~shellobstacle.geometry.expressions.ExpressionError`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import sympy as sp

from shellobstacle.geometry.expressions import ExpressionError, reason, y1, y2
from shellobstacle.messages import shown

__all__ = ["to_numpy", "to_ufl"]


def _ufl_relational(expr: sp.Basic, rec: Callable[[sp.Basic], Any]) -> Any:
    import ufl

    ops = {
        sp.StrictLessThan: ufl.lt,
        sp.LessThan: ufl.le,
        sp.StrictGreaterThan: ufl.gt,
        sp.GreaterThan: ufl.ge,
        sp.Equality: ufl.eq,
        sp.Unequality: ufl.ne,
    }
    if isinstance(expr, sp.And | sp.Or):
        combine = ufl.And if isinstance(expr, sp.And) else ufl.Or
        conds = [_ufl_relational(a, rec) for a in expr.args]
        out = conds[0]
        for c in conds[1:]:
            out = combine(out, c)
        return out
    if isinstance(expr, sp.Not):
        return ufl.Not(_ufl_relational(expr.args[0], rec))
    for cls, op in ops.items():
        if isinstance(expr, cls):
            return op(rec(expr.lhs), rec(expr.rhs))
    raise ExpressionError(f"cannot translate the condition {shown(expr)} to UFL")


def to_ufl(expr: sp.Expr, symbols: Mapping[sp.Symbol, Any]) -> Any:
    """Translate a SymPy expression into a UFL expression.

    Args:
        expr: the expression.
        symbols: UFL values for its free symbols (``y1 -> x[0]``, ``ell -> Constant``).
    """
    import ufl

    unary = {
        sp.exp: ufl.exp,
        sp.log: ufl.ln,
        sp.sin: ufl.sin,
        sp.cos: ufl.cos,
        sp.tan: ufl.tan,
        sp.asin: ufl.asin,
        sp.acos: ufl.acos,
        sp.atan: ufl.atan,
        sp.sinh: ufl.sinh,
        sp.cosh: ufl.cosh,
        sp.tanh: ufl.tanh,
        sp.Abs: abs,
        sp.sign: ufl.sign,
    }
    cache: dict[sp.Basic, Any] = {}
    _require_values(expr)

    def rec(e: sp.Basic) -> Any:
        if e in cache:
            return cache[e]
        out = _translate(e)
        cache[e] = out
        return out

    def _translate(e: sp.Basic) -> Any:
        if e in symbols:
            return symbols[e]
        if e.is_Number or e in (sp.pi, sp.E):
            return float(e)
        if isinstance(e, sp.Symbol):
            raise ExpressionError(f"no value for the symbol {e} in {shown(expr)}")
        if isinstance(e, sp.Add):
            terms = [rec(a) for a in e.args]
            out = terms[0]
            for t in terms[1:]:
                out = out + t
            return out
        if isinstance(e, sp.Mul):
            factors = [rec(a) for a in e.args]
            out = factors[0]
            for f in factors[1:]:
                out = out * f
            return out
        if isinstance(e, sp.Pow):
            base, ex = e.args
            if ex == sp.Rational(1, 2):
                return ufl.sqrt(rec(base))
            if ex == -sp.Rational(1, 2):
                return 1.0 / ufl.sqrt(rec(base))
            if ex.is_Integer and ex < 0:
                return 1.0 / rec(base) ** int(-ex)
            if ex.is_Integer:
                return rec(base) ** int(ex)
            return rec(base) ** rec(ex)
        if e.func in unary:
            return unary[e.func](rec(e.args[0]))
        if isinstance(e, sp.atan2):
            return ufl.atan2(rec(e.args[0]), rec(e.args[1]))
        if isinstance(e, sp.Min | sp.Max):
            fn = ufl.min_value if isinstance(e, sp.Min) else ufl.max_value
            out = rec(e.args[0])
            for a in e.args[1:]:
                out = fn(out, rec(a))
            return out
        if isinstance(e, sp.Piecewise):
            out = None
            for value, cond in reversed(e.args):
                if cond == sp.true:
                    out = rec(value)
                elif out is None:
                    raise ExpressionError(
                        f"Piecewise {shown(e)} needs a final (value, True) branch to be "
                        "defined everywhere"
                    )
                else:
                    out = ufl.conditional(_ufl_relational(cond, rec), rec(value), out)
            return out
        raise ExpressionError(f"cannot translate {e.func.__name__} in {shown(expr)} to UFL")

    return rec(sp.sympify(expr))


#: SymPy objects without a value at a point: the derivatives of a kink or a jump (of Abs,
#: sign, Min, Max) and derivatives SymPy could not carry out. Only derivatives of θ can hold
#: them (no user expression can name them, and the load is not differentiated).
_NO_VALUE = (sp.DiracDelta, sp.Derivative, sp.Subs)


def _require_values(expr: sp.Basic) -> None:
    """Refuse an expression holding one of :data:`_NO_VALUE` (a θ that is not smooth)."""
    found = sorted(sp.sympify(expr).atoms(*_NO_VALUE), key=str)
    if found:
        raise ExpressionError(
            f"surface.theta: a derivative of θ, {shown(expr)}, holds {shown(found[0])}, which "
            "has no value at a point: θ has a kink or a jump (Abs, sign, Min or Max of y1, y2); "
            "θ must be smooth on ω̄ (twice differentiable, three times for Koiter's model): "
            "write it without them, e.g. sqrt(y1**2 + c**2) for |y1|"
        )


@functools.lru_cache(maxsize=1024)
def _lambdified(expr: sp.Expr, args: tuple[sp.Symbol, ...]) -> Callable[..., Any]:
    """``sympy.lambdify`` of ``expr``, made once per expression (lambdifying the geometry's
    42 expressions again in every chunk of the checks and every output would dominate)."""
    _require_values(expr)
    try:
        return sp.lambdify(args, expr, modules="numpy")
    except Exception as err:  # SymPy's printers raise several types for what they lack
        raise ExpressionError(f"cannot evaluate {shown(expr)} with NumPy: {reason(err)}") from None


def to_numpy(expr: sp.Expr, args: tuple[sp.Symbol, ...] = (y1, y2)) -> Callable[..., np.ndarray]:
    """A vectorized NumPy function of ``args`` evaluating ``expr`` (broadcast to the inputs).

    Raises:
        ExpressionError: ``expr`` holds what has no value at a point (:data:`_NO_VALUE`) or
            what SymPy's NumPy printer cannot translate (when made or first evaluated).
    """
    fn = _lambdified(sp.sympify(expr), tuple(args))

    def evaluate(*values: np.ndarray) -> np.ndarray:
        try:
            raw = fn(*values)  # the code SymPy generated: a name it printed may not exist
        except (NameError, AttributeError, TypeError) as err:
            raise ExpressionError(
                f"cannot evaluate {shown(expr)} with NumPy: {reason(err)}"
            ) from None
        out = np.asarray(raw, dtype=float)
        return np.broadcast_to(out, np.broadcast(*values).shape).copy()

    return evaluate
