"""The command line and the Python API share every default: a config that leaves a key out
builds the same objects as the API's dataclasses constructed with their defaults.

The fields are found by introspection, so a new field of an options class fails here until
the schema sets it (:func:`shellobstacle.config.keys.bound`) or it is listed as one the config
does not expose (``API_ONLY``); a method's options declare their keys on their fields
(:func:`shellobstacle.solvers.options.option`), and every declared key is in ``[solver]``.
"""

from __future__ import annotations

import copy
import dataclasses
import tomllib
import warnings
from pathlib import Path
from typing import Any

import pytest

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.config.keys import REQUIRED
from shellobstacle.config.loader import parse_config
from shellobstacle.config.schema import SCHEMA, reference_text
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.obstacle.shapes import SHAPES, example
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.brezis_sibony.options import BrezisSibonyOptions
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.options import config_keys
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

PAPER = Path(__file__).parents[2] / "examples" / "paper.toml"
#: the least a config must give (paper.toml without its optional sections and keys)
MINIMAL: dict[str, Any] = {
    section: values
    for section, values in tomllib.loads(PAPER.read_text()).items()
    if section in ("surface", "domain", "material", "load", "penalty")
}

#: fields of the API's dataclasses that no config key sets (the config keeps their defaults)
API_ONLY: dict[type, set[str]] = {
    Discretization: set(),
    AdaptOptions: set(),
    PenaltySpec: set(),
    DomainSpec: {"kind"},  # required, its choices in the schema
    Obstacle: set(),
    Load: {"p"},  # required
    Shell: {"surface", "material", "load", "obstacle", "edges"},  # sections, not keys
    Material: {"epsilon", "lam", "mu"},  # required
}
#: the options class of each method that takes options
METHOD_OPTIONS = {name: m.options_type for name, m in METHODS.items() if m.options_type}
#: keys with a default that set no field of the API (application-level choices)
CONFIG_ONLY = {"solver.method", "output.paraview", "output.figures", "output.pictures"}


def _config(method: str = "newton", extra: dict[str, Any] | None = None) -> Any:
    data = copy.deepcopy(MINIMAL)
    data["solver"] = {"method": method}
    if not METHODS[method].penalized:
        del data["penalty"]
    data.update(extra or {})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the minimal config uses every key it gives
        return parse_config(data, "minimal.toml")


def _differences(built: Any, api: Any, skip: set[str] = frozenset()) -> list[str]:
    """Every field (by introspection) whose value differs between ``built`` and ``api``."""
    return [
        f"{type(api).__name__}.{f.name}: config {getattr(built, f.name)!r}, API "
        f"{getattr(api, f.name)!r}"
        for f in dataclasses.fields(api)
        if f.name not in skip and getattr(built, f.name) != getattr(api, f.name)
    ]


@pytest.mark.parametrize("method", list(METHOD_OPTIONS))
def test_solver_options_of_every_method_are_the_apis(method: str) -> None:
    """Newton's options and the chosen method's equal the classes' defaults, field by field."""
    cfg = _config(method)
    assert _differences(cfg.solver, NewtonOptions()) == []
    if method == "newton":
        assert cfg.method_options is None
    else:
        assert _differences(cfg.method_options, METHOD_OPTIONS[method]()) == []


@pytest.mark.parametrize("method", list(METHOD_OPTIONS))
def test_the_resolved_config_records_the_apis_defaults(method: str) -> None:
    """Each key of ``config.toml`` (the resolved config) that sets a field of the chosen
    method's options holds that field's default."""
    cfg = _config(method)
    for name, value in cfg.resolved["solver"].items():
        cls_field = SCHEMA["solver"][name].fields.get(method)
        if cls_field is not None:
            cls, field = cls_field
            assert value == getattr(cls(), field), (name, method)


def test_the_other_sections_are_the_apis() -> None:
    """Discretization, penalty, adapt, domain, obstacle and model: the API's defaults."""
    cfg = _config(extra={"adapt": {}})
    assert _differences(cfg.discretization, Discretization()) == []
    assert _differences(cfg.adapt, AdaptOptions()) == []
    exponent = MINIMAL["penalty"]["exponent"]
    assert _differences(cfg.penalty, PenaltySpec(exponent=exponent)) == []
    given = {k: tuple(v) if isinstance(v, list) else v for k, v in MINIMAL["domain"].items()}
    assert _differences(cfg.domain, DomainSpec(**given)) == []
    assert _differences(cfg.shell.obstacle, Obstacle()) == []
    assert cfg.shell.model == Shell.__dataclass_fields__["model"].default
    assert dict(cfg.shell.load.parameters) == {}
    nodal = _config("active-set")
    # the one difference the config makes on purpose: P1's nodal constraint
    assert _differences(nodal.discretization, Discretization(), {"penalty_quadrature"}) == []


def test_every_field_is_set_by_a_key_or_declared_api_only() -> None:
    """A new field must be bound to a config key (its default then comes from the field) or
    be listed in API_ONLY; a stale API_ONLY entry fails too."""
    bound: dict[type, set[str]] = {cls: set() for cls in API_ONLY}
    for section, keys in SCHEMA.items():
        for key in keys.values():
            for cls, name in key.fields.values():
                if section != "solver":
                    bound.setdefault(cls, set()).add(name)
    for cls, names in bound.items():
        fields = {f.name for f in dataclasses.fields(cls)}
        assert names <= fields, (cls.__name__, names - fields)
        missing = fields - names - API_ONLY.get(cls, set())
        assert not missing, f"{cls.__name__}: fields neither in the schema nor API_ONLY: {missing}"
        stale = API_ONLY.get(cls, set()) & names
        assert not stale, f"{cls.__name__}: API_ONLY names fields the schema sets: {stale}"


@pytest.mark.parametrize("method", list(METHOD_OPTIONS))
def test_every_declared_option_is_a_solver_key(method: str) -> None:
    """The ``[solver]`` keys that set a field of a method's options are exactly the fields
    its options declare with ``option``; the others are the API's alone."""
    cls = METHOD_OPTIONS[method]
    declared = {key: f.name for key, f in config_keys(cls).items()}
    in_schema = {
        name: key.fields[method][1]
        for name, key in SCHEMA["solver"].items()
        if method in key.fields
    }
    assert in_schema == declared
    assert all(
        key.fields[method][0] is cls for key in SCHEMA["solver"].values() if method in key.fields
    )


def test_every_default_of_the_schema_is_a_fields() -> None:
    """No key writes a default of its own: each default is read from the field it sets (for
    every method of a ``[solver]`` key), except the application's own keys."""
    for section, keys in SCHEMA.items():
        for name, key in keys.items():
            dotted = f"{section}.{name}"
            if key.default is REQUIRED or (key.default is None and not key.fields):
                continue
            if dotted in CONFIG_ONLY:
                assert not key.fields, dotted
                continue
            assert key.fields, f"{dotted} has a default but sets no field of the API"
            for selector, (cls, field) in key.fields.items():
                if (cls, field) == (Obstacle, "parameters"):  # the shape's declaration's
                    declared = {p.name: p for p in SHAPES[selector].parameters}[name]
                    assert key.default_for(selector) == declared.default, (dotted, selector)
                    continue
                f = cls.__dataclass_fields__[field]
                api = f.default_factory() if f.default is dataclasses.MISSING else f.default
                assert key.default_for(selector or None) == api, (dotted, selector)


def _build(cls: type, field: str, value: Any, key: str, selector: str) -> Any:
    """``cls`` with ``field = value``; an obstacle is built with its shape's examples (the
    shape: ``kind`` itself, or the key's selector for a shape's parameter ``key``)."""
    if cls is not Obstacle:
        return cls(**{field: value})
    if field == "parameters":
        return Obstacle(kind=selector, **{**example(selector), key: value})
    return Obstacle(**{field: value}, **(example(value) if value in SHAPES else {}))


def test_every_choice_is_one_the_api_accepts() -> None:
    """The choices the schema offers are the values the dataclasses accept; another value is
    refused by both."""
    for section, keys in SCHEMA.items():
        for name, key in keys.items():
            for selector, (cls, field) in key.fields.items():
                if not key.choices or cls in (Shell, DomainSpec):
                    continue
                for choice in key.choices:
                    _build(cls, field, choice, name, selector)
                with pytest.raises(ValueError, match=rf"{section}\.{name}"):
                    _build(cls, field, "no such choice", name, selector)


def test_brezis_sibony_stops_at_the_apis_tolerance() -> None:
    """The drift that made the CLI stop Brezis–Sibony at 1e-9 and the API at 1e-12."""
    cfg = _config("brezis-sibony")
    assert cfg.method_options.rtol == BrezisSibonyOptions().rtol == 1e-12
    assert cfg.resolved["solver"]["bs_rtol"] == 1e-12
    assert "| `bs_rtol` | float | 1e-12 |" in reference_text()
    # active-set's cap of linear solves is its own (the API's), not Newton's
    assert "| `max_iterations` | int | 100 (active-set: 200) |" in reference_text()
    assert _config("active-set").method_options.max_iterations == 200
