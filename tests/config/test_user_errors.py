"""User errors found by fuzzing and by hand: each one exit 2 and one line, never a traceback.

A θ whose derivatives SymPy cannot evaluate (the Dirac delta of ``Abs``, an unevaluated
derivative), arithmetic on a condition, a config saved with a UTF-8 byte-order mark, an
expression of thousands of terms (the message echoes a bounded part of it) and a negative
number as an option's value (argparse took ``-1e-2`` for an option).
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

from mpi4py import MPI

import numpy as np
import pytest
import sympy as sp
from cli_helpers import assert_user_error, run

from shellobstacle.config.loader import load_config, to_toml
from shellobstacle.geometry.expressions import ExpressionError, parse, y1, y2
from shellobstacle.geometry.surface import Surface
from shellobstacle.geometry.translation import to_numpy, to_ufl
from shellobstacle.messages import ECHO_LIMIT, shown

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")

SMALL = Path(__file__).parents[2] / "examples" / "small.toml"
BASE: dict[str, Any] = tomllib.loads(SMALL.read_text())
BASE["domain"]["h"] = 0.1
NAMES = {"y1": y1, "y2": y2}


def write(folder: Path, changes: dict[str, Any], name: str = "c.toml") -> Path:
    """``examples/small.toml`` at h = 0.1 with ``{"section.key": value}`` applied (a θ by
    expression without the spherical cap's keys, which it does not read)."""
    data = copy.deepcopy(BASE)
    if changes.get("surface.kind") == "expression":
        data["surface"] = {}
    for dotted, value in changes.items():
        section, _, key = dotted.partition(".")
        data.setdefault(section, {})[key] = value
    path = folder / name
    path.write_text(to_toml(data))
    return path


# --------------------------------------------------------------------------- SymPy's failures

#: θ_3 with a kink: its second derivative holds DiracDelta(y1), which NumPy's printer names
#: but NumPy has not (a NameError in SymPy's generated code, "internal error (a bug)" before)
KINKED = ["y1", "y2", "0.3 - y1**2/2 - y2**2/2 + 0.01*Abs(y1)"]


def test_theta_with_a_kink_is_a_user_error(capsys, tmp_path) -> None:
    path = write(tmp_path, {"surface.kind": "expression", "surface.theta": KINKED})
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err, "surface.theta", "DiracDelta(y1)", "smooth")


@pytest.mark.parametrize(
    "theta3",
    [
        "0.3 - Abs(y1)",  # DiracDelta in ∂²θ
        "0.3 - Max(y1, y2)**2",  # Heaviside, then DiracDelta
        "(Abs((y1)**0.5))**2",  # an unevaluated Derivative (NumPy's printer refuses it)
    ],
)
def test_derivatives_without_a_value_raise_expression_error(theta3: str) -> None:
    surface = Surface.from_strings(["y1", "y2", theta3])
    pts = np.array([[0.1, 0.2], [-0.3, 0.1]])
    with pytest.raises(ExpressionError, match=r"surface\.theta"):
        surface.geometry_numpy(pts)
    with pytest.raises(ExpressionError, match=r"surface\.theta"):
        to_ufl(surface.d2[0][0][2], {y1: 0.0, y2: 0.0})


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


# --------------------------------------------------------------------------- the config file


def test_config_with_a_byte_order_mark_is_read(tmp_path) -> None:
    plain = write(tmp_path, {}, "plain.toml")
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    assert load_config(bom).resolved == load_config(plain).resolved


def test_check_reads_a_config_with_a_byte_order_mark(capsys, tmp_path) -> None:
    path = tmp_path / "bom.toml"
    path.write_bytes("\ufeff".encode() + to_toml(BASE).encode())
    code, out, err = run(capsys, "check", str(path))
    assert code == 0, err
    assert "immersion" in out


# --------------------------------------------------------------------------- long input


def test_shown_bounds_long_input() -> None:
    text = "y1 + " * 2000
    assert shown("y1") == "'y1'"
    assert shown(text) == f"{text[:ECHO_LIMIT]!r}… ({len(text)} characters)"
    assert shown(list(range(5000))).endswith(f"… ({len(repr(list(range(5000))))} characters)")


def test_expression_of_thousands_of_terms_gives_a_short_message(capsys, tmp_path) -> None:
    terms = " + ".join(f"{i}*y1**2" for i in range(6000)) + " + zz"
    path = write(tmp_path, {"load.p": ["0", "0", terms]})
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err, "load.p[3]", "'zz'", f"({len(terms)} characters)")
    assert len(err) < 600, len(err)


def test_choice_message_bounds_the_value(tmp_path) -> None:
    from shellobstacle.config.loader import ConfigError

    path = write(tmp_path, {"solver.method": "x" * 10_000})
    with pytest.raises(ConfigError, match=r"\(10000 characters\)") as info:
        load_config(path)
    assert len(str(info.value)) < 600


# --------------------------------------------------------------------------- negative values


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["koiter-limit", "--epsilons", "-1e-2"], "--epsilons"),
        (["koiter-limit", "--epsilons", "-1e-2,1e-3"], "--epsilons"),
        (["koiter-limit", "--edge-h", "-.5"], "--edge-h"),
        (["penalty", "--start", "-0.5"], "--start"),
        (["load", "--values", "-1,2", "--parameter", "nope"], "nope"),
    ],
)
def test_negative_number_as_an_option_value(capsys, tmp_path, monkeypatch, args, needle) -> None:
    """``--epsilons -1e-2`` reaches the option's check (before: argparse's usage, 14 lines)."""
    monkeypatch.chdir(tmp_path)
    batch, *options = args
    code, _, err = run(capsys, "experiment", batch, str(SMALL), *options)
    assert_user_error(code, err, needle)
    assert not any(tmp_path.iterdir()), "a refused command made a folder"
