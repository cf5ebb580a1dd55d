"""The method registry: a method is one class plus one ``register`` line, and everything that
lists the methods (the config's choices, the config reference, the user guide) reads it."""

from __future__ import annotations

import dataclasses
import logging
import re
import tomllib
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest
from conftest import CAP_ON_COARSE_DISK

from shellobstacle.config.loader import parse_config
from shellobstacle.config.schema import reference_text
from shellobstacle.messages import ConfigError
from shellobstacle.solvers import METHODS, register
from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.options import option, petsc_options_field
from shellobstacle.solvers.registry import method_table, options_for
from shellobstacle.solvers.result import ConvergenceError, MethodResult, Step

DOCS = Path(__file__).parents[2] / "docs"

CONFIG = (
    CAP_ON_COARSE_DISK
    + """

[load]
p = ["0", "0", "-1e-5"]

[solver]
method = "zero"

[output]
paraview = false
figures = false
"""
)


class Zero:
    """ζ = 0: the whole of a method, which the registry takes as it is."""

    name = "zero"
    penalized = False
    adaptive = False
    options_type = None
    summary = "ζ = 0 (a test's method)"

    def solve(
        self,
        problem: Any,
        h: float,
        kappas: Sequence[float],
        options: Any,
    ) -> MethodResult:
        problem.zeta.x.array[:] = 0.0
        logging.getLogger("shellobstacle.zero").info(f"zero: {problem.num_dofs} dofs set to 0")
        return MethodResult([Step(0.0, 0, True, "ζ = 0", 0.0, 0.0, method=self.name)])


@pytest.fixture
def zero() -> Iterator[Zero]:
    method = register(Zero())  # the one registry line
    yield method
    del METHODS["zero"]


@pytest.mark.mpi
def test_a_registered_method_solves_through_the_config(zero: Zero, caplog) -> None:
    from shellobstacle.api import solve

    cfg = parse_config(tomllib.loads(CONFIG))
    assert cfg.method == "zero" and cfg.penalty is None  # not penalized: no [penalty]
    with caplog.at_level(logging.INFO, logger="shellobstacle"):
        result = solve(cfg)
    lines = caplog.messages
    assert result.converged and result.method == "zero"
    assert result.kappa == result.solved_kappa == 0.0
    assert not result.problem.zeta.x.array.any()
    assert [s.as_dict() for s in result.steps] == [
        {
            "method": "zero",
            "kappa": 0.0,
            "converged": True,
            "iterations": 0,
            "reason": "ζ = 0",
            "relative_residual": 0.0,
            "seconds": 0.0,
        }
    ]
    assert f"zero: {result.problem.num_dofs} dofs set to 0" in lines
    assert "solve" in result.timings


def test_an_unregistered_method_is_refused_with_the_registered_ones() -> None:
    data = tomllib.loads(CONFIG)
    with pytest.raises(ConfigError, match=r"solver\.method = 'zero' is not one of") as err:
        parse_config(data)
    for name in METHODS:
        assert repr(name) in str(err.value)


def test_a_name_is_registered_once(zero: Zero) -> None:
    with pytest.raises(ValueError, match="already registered"):
        register(Zero())
    with pytest.raises(ValueError, match="is not a Method"):
        register(object())  # type: ignore[arg-type]


def test_every_method_is_in_the_config_reference_and_the_user_guide(zero: Zero) -> None:
    """The config reference lists every registered method, the test's too; the user guide's
    table is the registry's (without the test's)."""
    row = next(line for line in reference_text().splitlines() if line.startswith("| `method`"))
    choices = re.search(r"\(one of ([^)]*)\) \|$", row)
    assert choices is not None and choices.group(1).split(", ") == list(METHODS)
    del METHODS["zero"]
    try:
        text = (DOCS / "user-guide.md").read_text()
        table = re.search(r"<!-- methods: [^\n]*-->\n(.*?)<!-- end of methods -->", text, re.S)
        assert table is not None
        assert table.group(1).strip() == method_table(), (
            "regenerate the table between the markers of docs/user-guide.md with: python -c "
            "'from shellobstacle.solvers.registry import method_table; print(method_table())'"
        )
        for name in METHODS:
            assert f"| `{name}` |" in table.group(1)
    finally:
        register(zero)


@dataclasses.dataclass(frozen=True)
class CapOptions:
    cap: int = option(5, key="max_iterations", help="a test's cap")
    petsc_options: Mapping[str, Any] = petsc_options_field()


class Capped(MethodBase, Zero):
    """A method with options: which ``[solver]`` keys set them is its options' declaration,
    and it may check their values itself."""

    name = "capped"
    options_type = CapOptions

    def options_from(self, values: Mapping[str, Any]) -> CapOptions:
        if values.get("max_iterations", 1) > 100:
            raise ConfigError("solver.max_iterations must be <= 100 with solver.method = 'capped'")
        return super().options_from(values)


@pytest.fixture
def capped() -> Iterator[Capped]:
    method = register(Capped())
    yield method
    del METHODS["capped"]


def test_a_method_builds_its_options_from_the_config(capped: Capped) -> None:
    with_cap = CONFIG.replace('method = "zero"', 'method = "capped"\nmax_iterations = 7')
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the key is the method's: no "is ignored" warning
        cfg = parse_config(tomllib.loads(with_cap))
    assert cfg.method_options == CapOptions(cap=7)
    cfg = parse_config(tomllib.loads(CONFIG.replace('method = "zero"', 'method = "capped"')))
    assert cfg.method_options == CapOptions()  # the fields no key sets keep their defaults
    with pytest.raises(ConfigError, match=r"must be <= 100 with solver\.method = 'capped'"):
        parse_config(tomllib.loads(with_cap.replace("= 7", "= 101")))


def test_a_method_without_options_gets_none(zero: Zero) -> None:
    assert parse_config(tomllib.loads(CONFIG)).method_options is None


def test_options_are_the_methods_own() -> None:
    from shellobstacle.solvers.newton.options import NewtonOptions
    from shellobstacle.solvers.vi.options import ActiveSetOptions

    newton, active = METHODS["newton"], METHODS["active-set"]
    assert options_for(newton, None, NewtonOptions(rtol=1e-9)) == NewtonOptions(rtol=1e-9)
    assert options_for(active, None, NewtonOptions()) is None  # Newton's are not its own
    assert options_for(active, ActiveSetOptions(max_iterations=3)).max_iterations == 3
    with pytest.raises(TypeError, match="'active-set' takes ActiveSetOptions"):
        options_for(active, NewtonOptions())


def test_the_failure_carries_its_history_as_fields() -> None:
    first = Step(1e-1, 4, True, "converged", 1e-12, 0.1)
    err = ConvergenceError("Newton did not converge", result="the failed κ's record")
    later = err.after([first])
    assert (str(later), later.result, later.steps) == (str(err), err.result, [first])
    assert err.steps == []  # the original is left as it was
