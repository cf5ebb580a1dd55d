"""The expressions of a config (``load.p``, ``surface.theta``) that are refused, in one line
with exit code 2 naming the key, never a traceback: text that does not parse or names unknown
symbols, code that must never run, a ``Piecewise`` without a last branch, values that overflow
double precision, derivatives SymPy cannot evaluate, arithmetic on a condition, constant
powers with huge exponents, and input so long that the message echoes only a bounded part.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from cli_helpers import assert_user_error, check_error, run, serial, write_config

from shellobstacle.geometry.expressions import ExpressionError, parse, y1, y2
from shellobstacle.geometry.translation import to_numpy
from shellobstacle.messages import ECHO_LIMIT, shown

pytestmark = serial

NAMES = {"y1": y1, "y2": y2}

# --------------------------------------------------------------------------- unparsable, unsafe


@pytest.mark.parametrize(
    ("changes", "needles"),
    [
        ({"load.p": ["0", "0", "1 +* y1"]}, ("load.p[3]: cannot parse '1 +* y1'",)),
        ({"load.p": ["0", "(", "0"]}, ("load.p[2]: cannot read '('",)),
        ({"load.p": ["", "0", "0"]}, ("load.p[1]: the expression is empty",)),
        ({"load.p": ["0", "0", "x*y1"]}, ("load.p[3]: unknown name 'x'", "allowed are")),
        ({"load.p": ["0", "0", "y1 < 0"]}, ("load.p[3]", "is not a scalar expression")),
        (
            {"load.p": ["0", "0", "1 if y1 < 0 else 0"]},
            ("load.p[3]", "Python's 'if' is not allowed", "Piecewise"),
        ),
        (
            {"surface": {"kind": "expression", "theta": ["y1", "y2", "0.3 - y1**2 -"]}},
            ("surface.theta[3]: cannot parse",),
        ),
        (
            {"surface": {"kind": "expression", "theta": ["y1", "y2", "0.3 - epsilon*y1**2"]}},
            ("surface.theta[3]: unknown name 'epsilon'",),
        ),
    ],
)
def test_unparsable_expression(capsys, tmp_path, changes, needles) -> None:
    check_error(capsys, tmp_path, changes, *needles)


@pytest.mark.parametrize(
    ("template", "needle"),
    [
        ("__import__('os').system('touch {p}')", "contains characters that are not allowed"),
        ("open('{p}', 'w')", "unknown name 'open'"),
        ("eval(\"open('{p}', 'w')\")", "unknown name 'eval'"),
        ("exp(y1); open('{p}', 'w')", "contains characters that are not allowed"),
        ("y1.__class__", "contains characters that are not allowed"),
        ("lambda: open('{p}', 'w')", "is not allowed"),
    ],
)
def test_unsafe_expression(capsys, tmp_path, monkeypatch, template: str, needle: str) -> None:
    """Code in an expression is refused and never runs."""
    monkeypatch.chdir(tmp_path)  # the payloads would create ./pwned
    target = tmp_path / "pwned"
    text = template.format(p="pwned")
    check_error(capsys, tmp_path, {"load.p": ["0", "0", text]}, "load.p[3]", needle)
    assert not target.exists()


def test_string_literal_payload_never_runs(capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    target = tmp_path / "pwned"
    text = 'exp("_" + "_import_" + "_(\'pathlib\').Path(\'pwned\').touch()")'
    path = write_config(tmp_path, {"load.p": ["0", "0", text]})
    code, _, err = run(capsys, "check", str(path))
    assert not target.exists(), "arbitrary code ran"
    assert_user_error(code, err, "load.p[3]")


def test_piecewise_without_a_default_branch(capsys, tmp_path) -> None:
    """ExpressionError from the translation to UFL (at solve time) is a user error too."""
    err = check_error(
        capsys,
        tmp_path,
        {"load.p": ["0", "0", "Piecewise((-1e-4, r < 0.1))"]},
        "needs a last branch (value, True)",
        command="solve",
    )
    assert "Piecewise" in err


def test_piecewise_without_a_default_branch_names_the_key(capsys, tmp_path) -> None:
    check_error(
        capsys, tmp_path, {"load.p": ["0", "0", "Piecewise((-1e-4, r < 0.1))"]}, "load.p[3]"
    )


# --------------------------------------------------------------------------- overflow


@pytest.mark.parametrize(
    ("changes", "needles"),
    [
        ({"load.p": ["0", "0", "exp(1000)"]}, ("load.p[3]", "exp(1000)", "overflows")),
        ({"load.p": ["0", "0", "1e400*y1"]}, ("load.p[3]", "overflows double precision")),
        (
            {"surface": {"kind": "expression", "theta": ["y1", "y2", "exp(1000) - r**2"]}},
            ("surface.theta[3]", "exp(1000)", "overflows"),
        ),
        ({"load.p": ["0", "0", "exp(2000*y1)"]}, ("load.p[3]: p^3 = inf at y = (",)),
    ],
)
@pytest.mark.parametrize("command", ["check", "solve"])
def test_expression_that_overflows(capsys, tmp_path, changes, needles, command) -> None:
    extra = ["-o", str(tmp_path / "out"), "-q"] if command == "solve" else []
    code, _, err = run(capsys, command, str(write_config(tmp_path, changes)), *extra)
    assert_user_error(code, err, *needles)


# --------------------------------------------------------------------------- SymPy's failures


def test_numpy_evaluation_of_an_unknown_function_is_an_expression_error() -> None:
    """What SymPy's NumPy code cannot evaluate (a function NumPy lacks) is refused."""
    f = sp.Function("f")
    with pytest.raises(ExpressionError, match="cannot evaluate"):
        to_numpy(f(y1) + y2)(np.array([0.1]), np.array([0.2]))


@pytest.mark.parametrize("text", ["-1e-4 + True*y1", "sqrt(True)", "False + y1"])
def test_arithmetic_on_a_condition_is_refused(text: str) -> None:
    """SymPy only warns (a multi-line deprecation text on stderr) and computes on."""
    with pytest.raises(ExpressionError, match="condition"):
        parse(text, NAMES, "load.p[3]")


POWERS = {  # text: the exponent the refusal names (None: accepted)
    "9**9**9": "9**9", "2**1001": "1001", "y1^1001": "1001", "y1**(-1001)": "-1001",
    "2**(10**4)": "10**4", "y1**(-(10**4))": "-1*10**4", "(y1**2)**(3**7)": "3**7",
    "exp(1)**(epsilon*1e7)": "0.001*10000000.0", "y1**(sqrt(2)*1000)": "sqrt(2)*1000",
    "y1**1e400": "1e400", "y1**2": None, "y1**y2": None, "2**1000": None, "y1**(-1000)": None,
    "(1+y1)**0.5": None, "y1**(epsilon*1000)": None, "y1**(y1 - y1 + 5000)": None,
    "2**2**2**2": None, "y1**-(3/2)": None,
}  # fmt: skip


@pytest.mark.parametrize("text", POWERS)
def test_constant_powers_with_huge_exponents_are_refused(text: str) -> None:
    """An exponent without y larger than 1000 in size is refused before SymPy evaluates it, as
    written (Python's syntax tree) and, for a text Python cannot read, on SymPy's unevaluated
    tree: both walks give the same verdict and name the same exponent."""
    import shellobstacle.geometry.expressions as expressions

    names = {**NAMES, "epsilon": 1e-3}
    verdicts = []
    for written in (True, False):
        check = expressions._check_written if written else (lambda *a: False)
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(expressions, "_check_written", check)
            try:
                parse(text, names, "load.p[3]")
                verdicts.append(None)
            except ExpressionError as err:
                verdicts.append(str(err))
    if POWERS[text] is None:
        assert verdicts == [None, None]
    else:
        assert f"the exponent {POWERS[text]} in" in verdicts[0], verdicts[0]
        assert "is too large (at most 1000)" in verdicts[1], verdicts[1]
        if text != "y1**1e400":  # SymPy's tree writes 1e400 out in 400 digits
            assert verdicts[0] == verdicts[1]


# --------------------------------------------------------------------------- long input


def test_shown_bounds_long_input() -> None:
    text = "y1 + " * 2000
    assert shown("y1") == "'y1'"
    assert shown(text) == f"{text[:ECHO_LIMIT]!r}… ({len(text)} characters)"
    assert shown(list(range(5000))).endswith(f"… ({len(repr(list(range(5000))))} characters)")


def test_expression_of_thousands_of_terms_gives_a_short_message(capsys, tmp_path) -> None:
    terms = " + ".join(f"{i}*y1**2" for i in range(6000)) + " + zz"
    path = write_config(tmp_path, {"load.p": ["0", "0", terms]})
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err, "load.p[3]", "'zz'", f"({len(terms)} characters)")
    assert len(err) < 600, len(err)
