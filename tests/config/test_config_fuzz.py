"""Property tests: any config dict and any expression text is accepted or refused cleanly.

``parse_config`` must return a :class:`Config` or raise :class:`ConfigError` for every input,
and :func:`shellobstacle.geometry.expressions.parse` a SymPy ``Expr`` or :class:`ExpressionError`:
never another exception, and never run code hidden in the input. The configs start from
``examples/paper.toml`` and are mutated (keys and sections deleted, renamed with typos,
values replaced by values of random types, unknown sections added). ``parse_config`` parses
expressions with SymPy but neither meshes nor solves, so hundreds of examples take seconds.
"""

from __future__ import annotations

import contextlib
import copy
import math
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path
from typing import Any

from mpi4py import MPI

import pytest
import sympy as sp
from conftest import examples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shellobstacle.config.loader import Config, ConfigError, parse_config
from shellobstacle.config.schema import SCHEMA
from shellobstacle.geometry.expressions import FUNCTIONS, ExpressionError, parse, y1, y2

pytestmark = [
    pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="fuzz tests run serially"),
    # e.g. sqrt(True): SymPy warns about non-Expr arguments, parse still answers
    pytest.mark.filterwarnings("ignore::sympy.utilities.exceptions.SymPyDeprecationWarning"),
    # random obstacle normals are normalized with a warning (and may overflow)
    pytest.mark.filterwarnings("ignore:obstacle.q:UserWarning"),
    pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning"),
]

PAPER = Path(__file__).parents[2] / "examples" / "paper.toml"
BASE: dict[str, Any] = tomllib.loads(PAPER.read_text())
FUZZ = settings(
    max_examples=examples(300),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
#: where an injected payload would leave its trace (created once per test session)
SENTINEL_DIR = Path(tempfile.mkdtemp(prefix="shellobstacle-fuzz-"))
SENTINEL = SENTINEL_DIR / "pwned"


def _payloads(target: Path) -> list[str]:
    """Code-injection attempts the parser must refuse (each would create ``target``)."""
    p = str(target)
    return [
        f"__import__('os').system('touch {p}')",
        f"__import__('pathlib').Path('{p}').touch()",
        f"open('{p}', 'w')",
        f"exec(\"open('{p}', 'w')\")",
        f"eval(\"open('{p}', 'w')\")",
        "().__class__.__bases__[0].__subclasses__()",
        "y1.__class__.__mro__",
        "[c for c in ().__class__.__base__.__subclasses__()]",
        "lambda: 0",
        "import os",
        "globals()",
        "getattr(y1, 'func')",
        f"Piecewise((open('{p}', 'w'), True))",
        f"y1; open('{p}', 'w')",
        f"f\"{{open('{p}', 'w')}}\"",
        f"sin(open('{p}', 'w'))",
        f"exp(__import__('os').system('touch {p}'))",
        "$HOME",
        "`ls`",
        "y1 \\\n + 1",
    ]


PAYLOADS = _payloads(SENTINEL)


@pytest.fixture(scope="module", autouse=True)
def _remove_sentinel_dir():
    yield
    shutil.rmtree(SENTINEL_DIR, ignore_errors=True)


SYMPY_LIKE = [
    "y1",
    "y2",
    "r",
    "epsilon",
    "lambda*mu",
    "sqrt(1 - y1**2 - y2**2) - 0.85",
    "Piecewise((-(2*epsilon/25)*(0.295 - 5*r**2), r < 0.06), (0, True))",
    "Piecewise((1, y1 < 0))",
    "exp(-100*r**2)",
    "1/0",
    "0**-1",
    "log(0)",
    "sqrt(-1)",
    "y1^2",
    "y1 < 1",
    "And(y1 < 0, y2 < 0)",
    "True",
    "1 if y1 else 2",
    "y1 and y2",
    "not y1",
    "sin",
    "atan2(y1)",
    "Min()",
    "Max(y1, y2, 3)",
    "(1, 2)",
    "[y1]",
    "{y1: 1}",
    "y1(2)",
    "y1[0]",
    "y1.y2",
    "1e999",
    "-1e999",
    "nan",
    "oo",
    "zoo",
    "x",
    "theta",
    "",
    " ",
    "((",
    ")",
    "1 +* 2",
    "'text'",
    '"y1"',
    "# comment",
    "y1 # comment",
    "y1\ny2",
    "\ty1",
    "y1 = 2",
    "y1 := 2",
    "*y1",
    "**y1",
    "ε",
    "y₁",
    "0x1F",
    "1_000",
    "1j",
    "2**1000",
    "(y1 + y2)**40",
]


# --------------------------------------------------------------------------- strategies


def _finite_floats() -> st.SearchStrategy[float]:
    return st.floats(allow_nan=False, allow_infinity=False)


#: Integers TOML can hold, including ones too large for a float.
INTS = st.one_of(
    st.integers(-5, 5),
    st.integers(-(2**63), 2**63 - 1),
    st.sampled_from([0, 1, 2, 3, -1, 10**30, -(10**30), 10**300, 10**400, -(10**400)]),
)
FLOATS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 5e-324, 1e300, -1e300, 0.5, 1.5, 2.0]),
)


ATOMS = ["y1", "y2", "r", "epsilon", "lambda", "mu", "pi", "E", "ell", "x", "0", "2.5", "True"]


@st.composite
def _expression(draw: st.DrawFn, depth: int = 3) -> str:
    """A random SymPy-like expression with small exponents (no 9**9**9 towers)."""
    atoms = st.sampled_from(ATOMS)
    if depth == 0 or draw(st.booleans()):
        return draw(atoms)
    kind = draw(st.sampled_from(["binop", "pow", "call", "piecewise", "neg", "compare"]))
    a = draw(_expression(depth - 1))
    if kind == "binop":
        op = draw(st.sampled_from(["+", "-", "*", "/"]))
        return f"({a} {op} {draw(_expression(depth - 1))})"
    if kind == "pow":
        return f"({a})**{draw(st.sampled_from(['2', '3', '0.5', '-1', 'y1', '(-2)']))}"
    if kind == "call":
        fn = draw(st.sampled_from([*sorted(FUNCTIONS), "foo", "eval", "print"]))
        args = [a] + [draw(_expression(depth - 1)) for _ in range(draw(st.integers(0, 2)))]
        return f"{fn}({', '.join(args)})"
    if kind == "piecewise":
        return f"Piecewise(({a}, r < 0.1), ({draw(_expression(depth - 1))}, True))"
    if kind == "compare":
        return f"{a} {draw(st.sampled_from(['<', '>=', '==']))} {draw(_expression(depth - 1))}"
    return f"-{a}"


TEXTS = st.one_of(
    st.text(max_size=40),
    st.text(alphabet="y12r+-*/()., ^<>=_ePiexpsqrtabc0123456789'\"\n\t", max_size=40),
    st.sampled_from(SYMPY_LIKE),
    st.sampled_from(PAYLOADS),
    _expression(),
)

SCALARS = st.one_of(st.booleans(), INTS, FLOATS, TEXTS, st.dates(), st.datetimes(), st.times())
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.dictionaries(st.text(max_size=8), inner, max_size=3),
    ),
    max_leaves=8,
)


def _typo(draw: st.DrawFn, name: str) -> str:
    """``name`` with one character inserted, deleted, replaced or two swapped."""
    if not name:
        return "x"
    i = draw(st.integers(0, len(name) - 1))
    how = draw(st.sampled_from(["insert", "delete", "replace", "swap", "case", "space"]))
    c = draw(st.sampled_from("abcdefghijklmnopqrstuvwxyz_"))
    if how == "insert":
        return name[:i] + c + name[i:]
    if how == "delete":
        return name[:i] + name[i + 1 :] or "_"
    if how == "replace":
        return name[:i] + c + name[i + 1 :]
    if how == "swap" and i + 1 < len(name):
        return name[:i] + name[i + 1] + name[i] + name[i + 2 :]
    if how == "case":
        return name.upper()
    return f" {name}"


PARAMETER_NAMES = ["ell", "amp", "Float", "sin", "lambda", "y1", "if", "True"]


def _schema_value(draw: st.DrawFn, section: str, key: str) -> Any:
    """A value that is plausible for the key (right type, random content) or anything."""
    spec = SCHEMA.get(section, {}).get(key)
    t = spec.type if spec else "any"
    if t == "float":
        return draw(st.one_of(FLOATS, INTS))
    if t == "int":
        return draw(INTS)
    if t == "bool":
        return draw(st.booleans())
    if t == "str":
        return draw(st.one_of(st.sampled_from(list(spec.choices) or ["x"]), TEXTS))
    if t.startswith(("float[", "str[", "str|float[")):
        n = int(t[t.index("[") + 1 : -1])
        length = draw(st.sampled_from([n, n, n, 0, n - 1, n + 1]))
        item = st.one_of(FLOATS, INTS, TEXTS) if "str" in t else st.one_of(FLOATS, INTS)
        return draw(st.lists(item, min_size=length, max_size=length))
    if t == "points":
        return draw(st.lists(st.lists(st.one_of(FLOATS, INTS), max_size=3), max_size=6))
    if t == "table":
        names = st.one_of(st.sampled_from(PARAMETER_NAMES), st.text(max_size=6))
        return draw(st.dictionaries(names, st.one_of(FLOATS, INTS, TEXTS), max_size=3))
    return draw(VALUES)


@st.composite
def mutated_configs(draw: st.DrawFn) -> dict[str, Any]:
    """``examples/paper.toml`` after 1-6 random mutations."""
    data = copy.deepcopy(BASE)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(
            st.sampled_from(
                [
                    "delete_section",
                    "delete_key",
                    "typo_key",
                    "typo_section",
                    "replace_value",
                    "plausible_value",
                    "add_key",
                    "add_section",
                    "section_not_table",
                    "schema_key",
                ]
            )
        )
        sections = sorted(data)
        if not sections:
            data[draw(st.sampled_from(sorted(SCHEMA)))] = {}
            continue
        section = draw(st.sampled_from(sections))
        table = data[section] if isinstance(data[section], dict) else None
        keys = sorted(table) if table else []
        if op == "delete_section":
            del data[section]
        elif op == "typo_section":
            data[_typo(draw, section)] = data.pop(section)
        elif op == "section_not_table":
            data[section] = draw(SCALARS)
        elif op == "add_section":
            data[draw(st.text(min_size=1, max_size=10))] = draw(
                st.dictionaries(st.text(max_size=6), VALUES, max_size=2)
            )
        elif table is None:
            continue
        elif op == "delete_key" and keys:
            del table[draw(st.sampled_from(keys))]
        elif op == "typo_key" and keys:
            key = draw(st.sampled_from(keys))
            table[_typo(draw, key)] = table.pop(key)
        elif op == "replace_value" and keys:
            table[draw(st.sampled_from(keys))] = draw(VALUES)
        elif op == "plausible_value" and keys:
            key = draw(st.sampled_from(keys))
            table[key] = _schema_value(draw, section, key)
        elif op == "schema_key" and section in SCHEMA:
            key = draw(st.sampled_from(sorted(SCHEMA[section])))
            table[key] = _schema_value(draw, section, key)
        elif op == "add_key":
            table[draw(st.text(min_size=1, max_size=10))] = draw(VALUES)
    return data


# --------------------------------------------------------------------------- properties


def _parses_cleanly(data: dict[str, Any]) -> Config | None:
    """Run ``parse_config``; only a Config or a ConfigError with a message is acceptable."""
    try:
        cfg = parse_config(data, "fuzz.toml")
    except ConfigError as err:
        assert str(err).strip(), "a ConfigError needs a message"
        assert "fuzz.toml" in str(err) or "[domain]" in str(err), str(err)
        return None
    assert isinstance(cfg, Config)
    return cfg


def test_the_base_config_is_valid() -> None:
    """The starting point of the mutations parses."""
    cfg = parse_config(copy.deepcopy(BASE), "fuzz.toml")
    assert cfg.shell.material.epsilon == BASE["material"]["epsilon"]


@FUZZ
@given(mutated_configs())
def test_mutated_configs_parse_or_raise_config_error(data: dict[str, Any]) -> None:
    """Every mutated config gives a Config or a ConfigError, and injected code never runs."""
    _parses_cleanly(data)
    assert not SENTINEL.exists(), f"code injected through the config ran: {data}"


@FUZZ
@given(
    st.dictionaries(
        st.one_of(st.sampled_from(sorted(SCHEMA)), st.text(max_size=8)),
        st.one_of(
            st.dictionaries(
                st.one_of(
                    st.sampled_from(sorted({k for keys in SCHEMA.values() for k in keys})),
                    st.text(max_size=8),
                ),
                VALUES,
                max_size=6,
            ),
            VALUES,
        ),
        max_size=6,
    )
)
def test_random_configs_parse_or_raise_config_error(data: dict[str, Any]) -> None:
    """Random documents built from the schema's names (and others) are refused cleanly."""
    _parses_cleanly(data)
    assert not SENTINEL.exists()


@FUZZ
@given(st.sampled_from(["surface", "load"]), st.integers(0, 2), TEXTS)
def test_expression_keys_parse_or_raise_config_error(section: str, i: int, text: str) -> None:
    """Any text in an expression key (θ or p) gives a Config or a ConfigError."""
    data = copy.deepcopy(BASE)
    if section == "surface":
        data["surface"] = {"kind": "expression", "theta": ["y1", "y2", "0.3 - r**2"]}
        data["surface"]["theta"][i] = text
    else:
        data["load"]["p"][i] = text
    _parses_cleanly(data)
    assert not SENTINEL.exists(), f"code injected through {section} ran: {text!r}"


# ids without the session's temporary path: the same on every process (pytest-xdist's
# workers must collect the same names)
@pytest.mark.parametrize(
    "payload", PAYLOADS, ids=[p.replace(str(SENTINEL), "SENTINEL") for p in PAYLOADS]
)
@pytest.mark.parametrize("where", ["load", "surface"])
def test_injection_payloads_are_refused(payload: str, where: str) -> None:
    """Known injection attempts raise ConfigError and leave no trace."""
    data = copy.deepcopy(BASE)
    if where == "load":
        data["load"]["p"] = ["0", "0", payload]
    else:
        data["surface"] = {"kind": "expression", "theta": ["y1", "y2", payload]}
    with pytest.raises(ConfigError):
        parse_config(data, "fuzz.toml")
    assert not SENTINEL.exists()


#: "\r" then a non-ASCII character: see test_carriage_return_before_non_ascii_...

#: every byte as a character (control characters, NBSP, ...)
LATIN1 = st.binary(max_size=20).map(lambda b: b.decode("latin-1"))

NAMES = {
    "y1": y1,
    "y2": y2,
    "r": sp.sqrt(y1**2 + y2**2),
    "epsilon": sp.Float(0.001),
    "lambda": sp.Float(0.4),
    "mu": sp.Float(0.012),
    "ell": sp.Symbol("ell", real=True),
}


@FUZZ
@given(st.one_of(TEXTS, st.text(max_size=80), LATIN1))
def test_parse_returns_an_expr_or_raises_expression_error(text: str) -> None:
    """``parse`` on random text: a SymPy Expr or an ExpressionError, nothing else."""
    try:
        expr = parse(text, NAMES, "fuzz")
    except ExpressionError as err:
        assert str(err).startswith("fuzz"), str(err)
    else:
        assert isinstance(expr, sp.Expr)
        assert expr.free_symbols <= {y1, y2, NAMES["ell"]}
    assert not SENTINEL.exists(), f"code injected through parse ran: {text!r}"


@FUZZ
@given(st.one_of(st.booleans(), INTS, FLOATS, st.none(), st.lists(st.integers(), max_size=2)))
def test_parse_non_text(value: Any) -> None:
    """Numbers become SymPy numbers; other objects raise ExpressionError."""
    try:
        expr = parse(value, NAMES, "fuzz")
    except ExpressionError:
        assert isinstance(value, bool | list) or value is None
    else:
        assert isinstance(expr, sp.Expr)
        if isinstance(value, float) and math.isfinite(value):
            assert float(expr) == value


# --------------------------------------------------------------------------- known bugs


def _string_payload(target: Path) -> str:
    """A string literal, assembled at run time to dodge the ``__`` filter, fed to ``exp``."""
    return f'exp("_" + "_import_" + "_(\'pathlib\').Path(\'{target.name}\').touch()")'


def test_string_literal_in_an_expression_runs_no_code(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``exp("...")`` with a string built at run time must not execute it."""
    monkeypatch.chdir(tmp_path)  # the payload names ./pwned-by-string
    target = tmp_path / "pwned-by-string"
    data = copy.deepcopy(BASE)
    data["load"]["p"] = ["0", "0", _string_payload(target)]
    with contextlib.suppress(ConfigError):
        parse_config(data, "fuzz.toml")
    assert not target.exists(), "the payload created a file: arbitrary code ran"
    with pytest.raises(ExpressionError):
        parse('exp("1")', NAMES, "fuzz")


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [("material", "epsilon", 10**400), ("load", "p", [0, 0, 10**400])],
)
def test_huge_integer_is_a_config_error(section: str, key: str, value: Any) -> None:
    data = copy.deepcopy(BASE)
    data[section][key] = value
    with pytest.raises(ConfigError):
        parse_config(data, "fuzz.toml")


@pytest.mark.filterwarnings("ignore")
def test_huge_obstacle_normal_is_normalized_or_refused() -> None:
    data = copy.deepcopy(BASE)
    data["obstacle"]["q"] = [1e200, 1e200, 1e200]
    try:
        cfg = parse_config(data, "fuzz.toml")
    except ConfigError:
        return
    assert math.isclose(math.hypot(*cfg.shell.obstacle.q), 1.0)


def test_non_finite_expression_is_refused() -> None:
    with pytest.raises(ExpressionError):
        parse("1/0", NAMES, "fuzz")


def test_parameter_named_float_is_refused_or_works() -> None:
    data = copy.deepcopy(BASE)
    data["load"]["parameters"] = {"Float": 1.0}
    data["load"]["p"] = ["0", "0", "-2.5e-4*Float"]
    try:
        parse_config(data, "fuzz.toml")
    except ConfigError as err:
        assert "Float" in str(err) and "not callable" not in str(err), str(err)


def test_power_tower_returns_quickly() -> None:
    """``9**9**9`` is refused, not evaluated (which would take hours): the parse's own CPU
    time, measured in a fresh process after its imports, is under a second (SymPy's first
    import may compile its modules, and the machine may be busy: neither is the parse's)."""
    code = (
        "import time\n"
        "from shellobstacle.geometry.expressions import parse, ExpressionError, y1\n"
        "t = time.process_time()\n"
        "try:\n    parse('9**9**9', {'y1': y1}, 'fuzz')\nexcept ExpressionError:\n    pass\n"
        "print(time.process_time() - t)\n"
    )
    try:
        done = subprocess.run(
            [sys.executable, "-c", code], timeout=300, check=True, capture_output=True, text=True
        )
    except subprocess.TimeoutExpired:
        pytest.fail("parse('9**9**9') did not return within 300 s")
    assert float(done.stdout) < 1.0, f"parse('9**9**9') took {done.stdout.strip()} s of CPU"


@pytest.mark.parametrize("text", ["y1\ré", "\r\x9d", "y1 +\rµ"])
def test_carriage_return_before_non_ascii_is_an_expression_error(text: str) -> None:
    with pytest.raises(ExpressionError):
        parse(text, NAMES, "fuzz")


def test_large_penalty_exponent_is_refused_or_gives_positive_kappas() -> None:
    data = copy.deepcopy(BASE)
    data["penalty"]["exponent"] = 400.0
    try:
        cfg = parse_config(data, "fuzz.toml")
    except ConfigError as err:
        assert "penalty.exponent" in str(err)
        return
    ladder = cfg.penalty.ladder(0.1)
    assert len(ladder) < 100 and all(k > 0 for k in ladder)
