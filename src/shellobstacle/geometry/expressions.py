"""User expressions: safe SymPy parsing.

Surfaces ``θ(y)`` and loads ``p^{i,ε}(y)`` are written by users as strings in
SymPy syntax. They are parsed against a whitelist of names (no arbitrary code is
evaluated), differentiated symbolically where needed, and then translated into UFL or
NumPy (:mod:`shellobstacle.geometry.translation`).

Whatever SymPy raises on a user's text (while parsing or evaluating its constants) becomes an
:class:`ExpressionError`: the calls into SymPy are wrapped here, one by one, and the messages
echo the text cut to a line (:func:`~shellobstacle.messages.shown`).
"""

from __future__ import annotations

import ast
import keyword
import math
import re
import tokenize
import warnings
from collections.abc import Iterator, Mapping
from io import StringIO
from typing import Any

import sympy as sp
from sympy.parsing.sympy_parser import (
    convert_xor,
    parse_expr,
    standard_transformations,
)
from sympy.utilities.exceptions import SymPyDeprecationWarning

from shellobstacle.messages import cut, shown

__all__ = [
    "FUNCTIONS",
    "ExpressionError",
    "is_safe_name",
    "parse",
    "reason",
    "y1",
    "y2",
]

y1, y2 = sp.symbols("y1 y2", real=True)

#: Functions and constants a user expression may call.
FUNCTIONS: dict[str, Any] = {
    "sqrt": sp.sqrt,
    "exp": sp.exp,
    "log": sp.log,
    "sin": sp.sin,
    "cos": sp.cos,
    "tan": sp.tan,
    "asin": sp.asin,
    "acos": sp.acos,
    "atan": sp.atan,
    "atan2": sp.atan2,
    "sinh": sp.sinh,
    "cosh": sp.cosh,
    "tanh": sp.tanh,
    "abs": sp.Abs,
    "Abs": sp.Abs,
    "Piecewise": sp.Piecewise,
    "Min": sp.Min,
    "Max": sp.Max,
    "And": sp.And,
    "Or": sp.Or,
    "pi": sp.pi,
    "E": sp.E,
}

_SYMPY_INTERNALS = {"Integer": sp.Integer, "Float": sp.Float, "Rational": sp.Rational}
#: Operators an expression may contain (no attribute access, indexing, strings, assignment).
_OPERATORS = {"+", "-", "*", "/", "**", "^", "(", ")", ",", "<", ">", "<=", ">=", "==", "!="}
#: Largest exponent of a constant power (SymPy evaluates integer powers exactly).
_MAX_EXPONENT = 1000
_RESERVED = {*_SYMPY_INTERNALS, "Symbol", "True", "False", "None"}
_SAFE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class ExpressionError(ValueError):
    """A user expression that cannot be parsed or uses names it may not use."""


def _rename_keywords(text: str, what: str) -> tuple[str, dict[str, str]]:
    """Rename Python keywords used as names (``lambda``) so the parser accepts them."""
    renamed: dict[str, str] = {}
    out = []
    try:
        tokens = list(tokenize.generate_tokens(StringIO(text).readline))
    except (tokenize.TokenError, SyntaxError, UnicodeError, ValueError) as err:
        raise ExpressionError(f"{what}: cannot read {shown(text)}: {err}") from None
    for tok in tokens:
        if tok.type == tokenize.NAME and tok.string in ("True", "False"):
            out.append((tok.type, tok.string))
        elif tok.type == tokenize.NAME and keyword.iskeyword(tok.string):
            if tok.string in ("and", "or", "not", "if", "else"):
                raise ExpressionError(
                    f"{what}: {shown(text)}: Python's {tok.string!r} is not allowed; "
                    "use Piecewise((value, condition), (other, True)), And(...), Or(...)"
                )
            new = f"{tok.string}_"
            renamed[new] = tok.string
            out.append((tok.type, new))
        else:
            out.append((tok.type, tok.string))
    return tokenize.untokenize(out), renamed


def parse(text: str | float | int, names: Mapping[str, Any], what: str = "expression") -> sp.Expr:
    """Parse ``text`` (SymPy syntax) allowing only ``names`` and :data:`FUNCTIONS`.

    Args:
        text: the expression, e.g. ``"sqrt(1 - y1**2 - y2**2) - 0.85"``; numbers pass.
        names: the symbols or values the expression may use (``y1``, ``epsilon``, ...).
        what: how to call the expression in error messages (``"load.p[3]"``).

    Raises:
        ExpressionError: for syntax errors, unknown names and unsafe input.
    """
    if isinstance(text, bool):
        raise ExpressionError(f"{what}: expected an expression, got the boolean {text}")
    if isinstance(text, int | float):
        return sp.Float(text) if isinstance(text, float) else sp.Integer(text)
    if not isinstance(text, str):
        raise ExpressionError(f"{what}: expected a string expression, got {type(text).__name__}")
    if "__" in text or any(c in text for c in ";`$\\"):
        raise ExpressionError(f"{what}: {shown(text)} contains characters that are not allowed")
    if not text.strip():
        raise ExpressionError(f"{what}: the expression is empty")
    code, renamed = _rename_keywords(text, what)
    local: dict[str, Any] = {}
    for name, value in names.items():
        key = f"{name}_" if keyword.iskeyword(name) else name
        local[key] = value
    allowed = set(local) | set(FUNCTIONS) | {"True", "False"}
    ignorable = {
        tokenize.NEWLINE,
        tokenize.NL,
        tokenize.ENDMARKER,
        tokenize.INDENT,
        tokenize.DEDENT,
    }
    try:
        tokens = list(tokenize.generate_tokens(StringIO(code).readline))
    except (tokenize.TokenError, SyntaxError, UnicodeError, ValueError) as err:
        raise ExpressionError(f"{what}: cannot read {shown(text)}: {err}") from None
    for tok in tokens:
        if tok.type == tokenize.NAME:
            if tok.string not in allowed:
                known = ", ".join(sorted(str(n) for n in names))
                raise ExpressionError(
                    f"{what}: unknown name {shown(renamed.get(tok.string, tok.string))} in "
                    f"{shown(text)}; "
                    f"allowed are {known} and the functions {', '.join(sorted(FUNCTIONS))}"
                )
        elif tok.type == tokenize.OP:
            if tok.string not in _OPERATORS:
                raise ExpressionError(
                    f"{what}: the operator {tok.string!r} is not allowed in {shown(text)} "
                    f"(allowed: {' '.join(sorted(_OPERATORS))})"
                )
        elif tok.type == tokenize.NUMBER:
            if tok.string.lower().endswith("j"):
                raise ExpressionError(f"{what}: complex numbers are not allowed in {shown(text)}")
        elif tok.type not in ignorable:
            raise ExpressionError(
                f"{what}: {shown(tok.string)} is not allowed in {shown(text)} (strings, comments "
                "and other tokens are refused: write numbers, names, operators and function calls)"
            )
    global_dict = {"__builtins__": {}, **FUNCTIONS, **_SYMPY_INTERNALS}

    # the unevaluated build names SymPy's node classes; no string literal can reach them
    unevaluated = {
        "Add": sp.Add, "Mul": sp.Mul, "Pow": sp.Pow, "Lt": sp.Lt, "Le": sp.Le, "Gt": sp.Gt,
        "Ge": sp.Ge, "Eq": sp.Eq, "Ne": sp.Ne,
    }  # fmt: skip

    def build(evaluate: bool, source: str = code) -> Any:
        with warnings.catch_warnings():
            # ``True*y1``: arithmetic on a condition, which SymPy only warns about
            warnings.simplefilter("error", SymPyDeprecationWarning)
            return parse_expr(
                source,
                local_dict=local,
                global_dict=global_dict if evaluate else {**global_dict, **unevaluated},
                transformations=(*standard_transformations, convert_xor),
                evaluate=evaluate,
            )

    try:
        # before SymPy evaluates 9**9**9 exactly: the powers as written, else SymPy's
        # unevaluated tree
        if not _check_written(code, local, lambda part: build(False, part), what, text):
            _check_powers(build(False), what, text)
        expr = build(True)
        _check_expr(expr, what, text)
    except ExpressionError:
        raise
    except SymPyDeprecationWarning:
        raise _with_condition(what, text) from None
    except Exception as err:  # SymPy raises many types for malformed input
        raise ExpressionError(f"{what}: cannot parse {shown(text)}: {reason(err)}") from None
    return expr


def _with_condition(what: str, text: str) -> ExpressionError:
    return ExpressionError(
        f"{what}: {shown(text)} computes with a condition (True, False or a comparison): "
        "write Piecewise((value, condition), (other, True))"
    )


def reason(err: Exception) -> str:
    """SymPy's message for ``err``, on one line and bounded (it may quote the input)."""
    return cut(" ".join(str(err).split()) or type(err).__name__, 200)


def _check_expr(expr: Any, what: str, text: str) -> None:
    """Refuse a parsed ``expr`` that is no finite real scalar defined everywhere."""
    if not isinstance(expr, sp.Expr):
        raise ExpressionError(f"{what}: {shown(text)} is not a scalar expression")
    if expr.has(sp.zoo, sp.oo, -sp.oo, sp.nan):
        raise ExpressionError(
            f"{what}: {shown(text)} is not finite (it evaluates to {shown(expr)})"
        )
    _check_constants(expr, what, text)
    for pw in expr.atoms(sp.Piecewise):
        if pw.args[-1].cond != sp.true:
            raise ExpressionError(
                f"{what}: the Piecewise in {shown(text)} needs a last branch (value, True) so "
                "that it is defined everywhere"
            )


def _check_constants(expr: sp.Expr, what: str, text: str) -> None:
    """Refuse constant parts that are no finite real double (``exp(1000)``, ``1e400``): the
    forms and the checks evaluate them in double precision. A part that occurs many times
    (SymPy shares equal subexpressions) is checked once."""
    for node in _distinct_parts(expr):
        if not isinstance(node, sp.Expr) or node.free_symbols or node in (sp.pi, sp.E):
            continue
        try:
            value = complex(node.evalf(20))
        except (TypeError, ValueError, OverflowError):
            continue  # not a number (a condition's parts are checked on their own)
        if not (math.isfinite(value.real) and math.isfinite(value.imag)):
            part = f"{node.evalf(4)}" if node.is_Number else f"{shown(node)} ≈ {node.evalf(4)}"
            raise ExpressionError(
                f"{what}: {part} in {shown(text)} overflows double precision (at most 1.8e308): "
                "rescale the expression"
            )
        if value.imag != 0.0:
            raise ExpressionError(
                f"{what}: {shown(node)} in {shown(text)} is not real ({value:.6g})"
            )


def _distinct_parts(tree: sp.Basic) -> Iterator[sp.Basic]:
    """The parts of ``tree`` in preorder, each distinct one once: below a part equal to one
    already yielded nothing is yielded again (a check of it has seen all of it)."""
    seen: set[sp.Basic] = set()
    nodes = sp.preorder_traversal(tree)
    for node in nodes:
        if node in seen:
            nodes.skip()
            continue
        seen.add(node)
        yield node


def _check_powers(tree: Any, what: str, text: str) -> None:
    """Refuse constant powers with huge exponents (an unevaluated tree is walked; a part that
    occurs many times is checked once)."""
    if not isinstance(tree, sp.Basic):
        return
    for node in _distinct_parts(tree):
        if isinstance(node, sp.Pow) and not node.exp.free_symbols:
            size = _size(node.exp)
            if not size <= _MAX_EXPONENT:
                raise ExpressionError(
                    f"{what}: the exponent {node.exp} in {shown(text)} is too large "
                    f"(at most {_MAX_EXPONENT})"
                )


def _check_written(
    code: str, local: Mapping[str, Any], unevaluated: Any, what: str, text: str
) -> bool:
    """Refuse arithmetic on a condition and constant powers with huge exponents, walking
    Python's syntax tree of ``code`` (SymPy's unevaluated parse of a long text costs more than
    its evaluated one); an exponent that is no plain number is parsed alone by
    ``unevaluated``. False when Python cannot read ``code`` (the caller then walks SymPy's
    unevaluated tree)."""
    source = code.replace("^", "**")  # SymPy's convert_xor; strings are refused before
    try:
        tree = ast.parse(source, mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError):
        return False
    symbolic = {n for n, v in local.items() if isinstance(v, sp.Basic) and v.free_symbols}
    parts: dict[str, tuple[str, float]] = {}  # an exponent as SymPy shows it, its size
    for node in ast.walk(tree):
        operands = (
            [node.left, node.right] if isinstance(node, ast.BinOp)
            else [node.operand] if isinstance(node, ast.UnaryOp) else []
        )  # fmt: skip
        if any(_is_condition(operand) for operand in operands):
            raise _with_condition(what, text)
        if not (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow)):
            continue
        exponent = node.right
        if any(isinstance(n, ast.Name) and n.id in symbolic for n in ast.walk(exponent)):
            continue  # depends on y (as SymPy's ``free_symbols``)
        size = _number_size(exponent)
        if size is None:
            written = ast.unparse(exponent)  # the subtree alone (a source segment costs a split)
            if written not in parts:
                part = unevaluated(written)
                if isinstance(part, bool | sp.logic.boolalg.Boolean):
                    raise _with_condition(what, text)
                parts[written] = (str(part), _size(part))
            written, size = parts[written]
        elif not size <= _MAX_EXPONENT:
            written = ast.get_source_segment(source, exponent) or ""
        if not size <= _MAX_EXPONENT:
            raise ExpressionError(
                f"{what}: the exponent {written} in {shown(text)} is too large "
                f"(at most {_MAX_EXPONENT})"
            )
    return True


def _is_condition(node: ast.expr) -> bool:
    """A written ``True``, ``False`` or comparison."""
    return isinstance(node, ast.Compare) or (
        isinstance(node, ast.Constant) and isinstance(node.value, bool)
    )


def _number_size(node: ast.expr) -> float | None:
    """``|n|`` of a written number ``n`` or ``±n`` (None for anything else)."""
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        node = node.operand
    value = node.value if isinstance(node, ast.Constant) else None
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        return abs(float(value))
    except OverflowError:
        return math.inf


def _size(exponent: Any) -> float:
    """``|exponent|`` of a constant SymPy exponent (inf when it cannot be evaluated)."""
    try:
        return abs(complex(sp.sympify(exponent).evalf(15)))
    except (TypeError, ValueError, OverflowError):
        return math.inf


def is_safe_name(name: str) -> bool:
    """Whether ``name`` may be used as a user parameter name in expressions."""
    return (
        bool(_SAFE_NAME.match(name))
        and name not in FUNCTIONS
        and name not in _RESERVED
        and not keyword.iskeyword(name)
        and "__" not in name
    )
