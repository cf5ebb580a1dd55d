"""One declaration per option: a method's options dataclass declares each ``[solver]`` key on
its field (type, default, choices, meaning), and the config's schema, its reference, its
checks and the API's defaults are made from it. A method registered here, with options of its
own, is in the config reference, has its choices checked by the loader and solves."""

from __future__ import annotations

import dataclasses
import re
import tomllib
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import pytest
from cli_helpers import run
from conftest import CAP_ON_COARSE_DISK

from shellobstacle.config.loader import parse_config
from shellobstacle.config.schema import SCHEMA, reference_text
from shellobstacle.messages import ConfigError
from shellobstacle.solvers import METHODS, register
from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.options import check_choices, option, petsc_options_field
from shellobstacle.solvers.result import MethodResult, Step

#: the paper's cap on a coarse disk, solved by the test's method
CONFIG = (
    CAP_ON_COARSE_DISK
    + """

[load]
p = ["0", "0", "-1e-5"]

[output]
paraview = false
figures = false
"""
)


@dataclasses.dataclass(frozen=True)
class FillOptions:
    """The test method's options: three keys, one under another name than its field's, one
    shared with the package's methods, and a field the config does not set."""

    value: float = option(0.0, key="fill_value", help="the value every dof of ζ takes")
    sign: str = option("plus", choices=("plus", "minus"), help="the sign of that value")
    max_iterations: int = option(5, help="a test's cap")
    note: str = "API only"
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_choices(self)


class Fill(MethodBase):
    """ζ = ± a given value at every dof: a method whose options are its own."""

    name = "fill"
    penalized = False
    adaptive = False
    options_type = FillOptions
    summary = "ζ = ± a value (a test's method)"

    def solve(self, problem: Any, h: float, kappas: Sequence[float], options: Any) -> MethodResult:
        options = options or FillOptions()
        value = options.value if options.sign == "plus" else -options.value
        problem.zeta.x.array[:] = value
        return MethodResult([Step(0.0, 0, True, f"ζ = {value:g}", 0.0, 0.0, method=self.name)])


@pytest.fixture
def fill() -> Iterator[Fill]:
    method = register(Fill())  # the one registry line
    yield method
    del METHODS["fill"]


def _config(solver: str) -> Any:
    return parse_config(tomllib.loads(CONFIG + "[solver]\n" + solver), "fill.toml")


def test_a_registered_methods_keys_are_in_the_config_reference(capsys, fill: Fill) -> None:
    """Its keys, with the type, default, choices and meaning its fields declare; the key it
    shares with the package's methods shows each method's default and meaning."""
    code, out, _ = run(capsys, "config-reference")
    assert code == 0 and out.strip() == reference_text().strip()
    assert "| `fill_value` | float | 0.0 | fill: the value every dof of ζ takes |" in out
    assert "| `sign` | str | 'plus' | fill: the sign of that value (one of plus, minus) |" in out
    row = next(line for line in out.splitlines() if line.startswith("| `max_iterations`"))
    assert "| int | 100 (active-set: 200, fill: 5) |" in row
    assert row.endswith("a test's cap (fill) |")
    assert "note" not in SCHEMA["solver"] and "value" not in SCHEMA["solver"]


def test_a_registered_methods_keys_are_checked_by_the_loader(fill: Fill) -> None:
    """A choice it declares is accepted, another value refused by the loader and the API with
    one message; the fields no key sets keep their defaults; its keys are ignored, with a
    warning naming it, by another method."""
    cfg = _config('method = "fill"\nfill_value = 0.25\nsign = "minus"\nmax_iterations = 7\n')
    assert cfg.method_options == FillOptions(value=0.25, sign="minus", max_iterations=7)
    assert cfg.resolved["solver"]["fill_value"] == 0.25
    assert _config('method = "fill"\n').method_options == FillOptions()
    message = "solver.sign = 'times' is not one of 'plus', 'minus'"
    with pytest.raises(ConfigError, match=re.escape(message)):
        _config('method = "fill"\nsign = "times"\n')
    with pytest.raises(ValueError, match=re.escape(message)):
        FillOptions(sign="times")
    with pytest.warns(UserWarning, match=r"solver\.fill_value is ignored: .* \(read with 'fill'\)"):
        cfg = _config('method = "active-set"\nfill_value = 0.25\n')
    assert cfg.method_options == METHODS["active-set"].options_type()


def test_a_declaration_is_checked_when_it_is_registered(fill: Fill) -> None:
    """A key another method reads with another type, an annotation the config cannot read
    and options that are not a frozen dataclass are refused, naming the problem."""

    def method(name: str, **fields: Any) -> Fill:
        options = dataclasses.make_dataclass(
            name.title(), [(n, t, f) for n, (t, f) in fields.items()], frozen=True
        )
        return type(name.title(), (Fill,), {"name": name, "options_type": options})()

    bad = {
        "solver.max_iterations is of type int for solver.method = 'newton', not float": method(
            "floats", max_iterations=(float, option(1.0, help="a cap"))
        ),
        "a [solver] key is a float, int, bool or str": method(
            "lists", sizes=(list[int], option(None, help="sizes"))
        ),
    }
    for message, bad_method in bad.items():
        with pytest.raises(ValueError, match=re.escape(message)):
            register(bad_method)
    loose = type(
        "Loose",
        (Fill,),
        {"name": "loose", "options_type": dataclasses.dataclass(type("O", (), {}))},
    )
    with pytest.raises(ValueError, match="is not a frozen dataclass"):
        register(loose())
    assert not {"floats", "lists", "loose"} & set(METHODS)


@pytest.mark.mpi
def test_a_registered_method_solves_with_its_options(fill: Fill) -> None:
    """Through the config: the options its keys set reach its solve."""
    from shellobstacle.api import solve

    result = solve(_config('method = "fill"\nfill_value = 0.25\nsign = "minus"\n'))
    assert result.converged and result.method == "fill" and result.kappa == 0.0
    assert (result.problem.zeta.x.array == -0.25).all()
    assert [s.reason for s in result.steps] == ["ζ = -0.25"]
