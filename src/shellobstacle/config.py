"""TOML configuration → validated objects, with errors that name the key and the fix.

Keys, types and defaults come from :mod:`shellobstacle.schema`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shellobstacle.domains import DomainSpec
from shellobstacle.expressions import ExpressionError
from shellobstacle.model import (
    Discretization,
    Load,
    Material,
    Obstacle,
    PenaltySpec,
    Shell,
)
from shellobstacle.schema import REQUIRED, REQUIRED_SECTIONS, SCHEMA, Key
from shellobstacle.solvers.options import NewtonOptions
from shellobstacle.surface import Surface

__all__ = ["Config", "ConfigError", "load_config", "parse_config", "to_toml"]


class ConfigError(ValueError):
    """A configuration problem the user can fix; the message names file, key and fix."""


@dataclass(frozen=True)
class Config:
    """A validated configuration: the physical shell and every numerical choice."""

    shell: Shell
    domain: DomainSpec
    discretization: Discretization
    penalty: PenaltySpec | None  # None for the exact solver (solver.method = "active-set")
    solver: NewtonOptions
    method: str
    output: Mapping[str, bool]
    resolved: Mapping[str, Mapping[str, Any]]
    source: str


def _suggest(name: str, options: list[str]) -> str:
    close = difflib.get_close_matches(name, options, n=1, cutoff=0.5)
    return f"; did you mean {close[0]!r}?" if close else f"; valid keys: {', '.join(options)}"


def _coerce(value: Any, key: Key, where: str) -> Any:
    """Check and convert one value to the key's type."""

    def number(v: Any, what: str) -> float:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ConfigError(f"{what} must be a number, got {v!r}")
        try:
            value = float(v)
        except OverflowError:
            raise ConfigError(f"{what} is too large to be a floating-point number") from None
        if not math.isfinite(value):
            raise ConfigError(f"{what} must be finite, got {v!r}")
        return value

    t = key.type
    if t == "float":
        return number(value, where)
    if t == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return value
    if t == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if t == "str":
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        if key.choices and value not in key.choices:
            raise ConfigError(
                f"{where} = {value!r} is not one of {', '.join(map(repr, key.choices))}"
                + _suggest(value, list(key.choices)).replace("valid keys", "choices")
            )
        return value
    if t.startswith(("float[", "str[", "str|float[")):
        n = int(t[t.index("[") + 1 : -1])
        if not isinstance(value, list | tuple) or len(value) != n:
            raise ConfigError(f"{where} must be a list of {n} values, got {value!r}")
        if t.startswith("float"):
            return tuple(number(v, f"{where}[{i + 1}]") for i, v in enumerate(value))
        out = []
        for i, v in enumerate(value):
            if isinstance(v, str) or (
                t.startswith("str|") and not isinstance(v, bool) and isinstance(v, int | float)
            ):
                out.append(v if isinstance(v, str) else repr(number(v, f"{where}[{i + 1}]")))
            else:
                raise ConfigError(f"{where}[{i + 1}] must be a string expression, got {v!r}")
        return tuple(out)
    if t == "points":
        if not isinstance(value, list) or not all(
            isinstance(p, list | tuple) and len(p) == 2 for p in value
        ):
            raise ConfigError(f"{where} must be a list of [y1, y2] pairs, got {value!r}")
        return tuple(
            (number(p[0], f"{where}[{i + 1}][1]"), number(p[1], f"{where}[{i + 1}][2]"))
            for i, p in enumerate(value)
        )
    if t == "table":
        if not isinstance(value, dict):
            raise ConfigError(f"{where} must be a table of name = number, got {value!r}")
        return {k: number(v, f"{where}.{k}") for k, v in value.items()}
    raise AssertionError(t)


def parse_config(data: Mapping[str, Any], source: str = "<config>") -> Config:
    """Validate a parsed TOML document and build a :class:`Config`.

    Raises:
        ConfigError: naming ``source``, the section, the key and the fix.
    """
    resolved: dict[str, dict[str, Any]] = {}
    for section in data:
        if section not in SCHEMA:
            raise ConfigError(
                f"{source}: unknown section [{section}]" + _suggest(section, list(SCHEMA))
            )
        if not isinstance(data[section], dict):
            raise ConfigError(f"{source}: [{section}] must be a table of keys")
    for section in REQUIRED_SECTIONS:
        if section not in data:
            raise ConfigError(f"{source}: missing section [{section}]")
    koiter = isinstance(data.get("model"), dict) and data["model"].get("kind") == "koiter"
    for section, keys in SCHEMA.items():
        given = dict(data.get(section, {}))
        if section == "discretization" and koiter:
            given.setdefault("degree", 2)  # Koiter's ζ_3 ∈ H² needs P2
        for name in given:
            if name not in keys:
                raise ConfigError(
                    f"{source}: unknown key '{name}' in [{section}]" + _suggest(name, list(keys))
                )
        out: dict[str, Any] = {}
        for name, key in keys.items():
            where = f"{source}: {section}.{name}"
            if name in given:
                out[name] = _coerce(given[name], key, where)
            elif key.default is REQUIRED:
                raise ConfigError(f"{source}: missing key '{name}' in [{section}] ({key.help})")
            elif key.default is not None:
                out[name] = key.default
        resolved[section] = out
    try:
        return _build(resolved, source)
    except ConfigError:
        raise
    except (ValueError, ExpressionError) as err:
        raise ConfigError(f"{source}: {err}") from None


def _need(
    sec: Mapping[str, Any], section: str, names: tuple[str, ...], why: str, source: str
) -> None:
    for n in names:
        if n not in sec:
            raise ConfigError(f"{source}: [{section}] needs '{n}' for {why}")


def _build(r: dict[str, dict[str, Any]], source: str) -> Config:
    s = r["surface"]
    kind = s["kind"]
    if kind == "spherical_cap":
        _need(s, "surface", ("radius", "offset"), "kind = 'spherical_cap'", source)
        surface = Surface.spherical_cap(s["radius"], s["offset"])
    elif kind == "ellipsoid_cap":
        _need(s, "surface", ("semi_axes", "offset"), "kind = 'ellipsoid_cap'", source)
        surface = Surface.ellipsoid_cap(s["semi_axes"], s["offset"])
    elif kind == "elliptic_paraboloid":
        _need(s, "surface", ("height", "curvatures"), "kind = 'elliptic_paraboloid'", source)
        surface = Surface.elliptic_paraboloid(s["height"], s["curvatures"])
    else:
        _need(s, "surface", ("theta",), "kind = 'expression'", source)
        surface = Surface.from_strings(s["theta"])

    m = r["material"]
    material = Material(m["epsilon"], m["lambda"], m["mu"])
    load = Load(tuple(r["load"]["p"]), dict(r["load"].get("parameters", {})))
    model = r["model"]["kind"]
    shell = Shell(surface, material, load, Obstacle(tuple(r["obstacle"]["q"])), model)
    shell.load_expressions()  # parse now: errors name the key

    d = dict(r["domain"])
    if d["kind"] != "file" and "h" not in d:
        raise ConfigError(
            f"{source}: [domain] needs 'h' (target mesh size) for kind = '{d['kind']}'"
        )
    if "h" in d and not d["h"] > 0:
        raise ConfigError(f"{source}: domain.h must be > 0, got {d['h']}")
    if "path" in d and not Path(d["path"]).is_absolute():
        # relative to the config; the resolved config (a result folder's config.toml) holds
        # the absolute path, so that it reruns from anywhere
        base = Path(source).parent if source not in ("<config>", "") else Path(".")
        d["path"] = r["domain"]["path"] = str((base / d["path"]).resolve())
    if not 0 <= d["refinements"] <= 8:
        raise ConfigError(
            f"{source}: domain.refinements must be in 0..8 (each multiplies the cells by 4), "
            f"got {d['refinements']}"
        )
    domain = DomainSpec(**d)

    disc = Discretization(**r["discretization"])
    sv = r["solver"]
    if model == "koiter":
        if sv["method"] == "active-set":
            raise ConfigError(
                f"{source}: solver.method = 'active-set' imposes g ≥ 0 at the vertices of P1, "
                "and Koiter's model needs P2: use solver.method = 'newton' with a small κ"
            )
        if sv["linear_solver"] == "iterative":
            raise ConfigError(
                f"{source}: solver.linear_solver = 'iterative' preconditions ζ_3 as the "
                "membrane's L² unknown, not Koiter's bending: use linear_solver = 'direct'"
            )
        if disc.degree != 2:
            raise ConfigError(
                f"{source}: model.kind = 'koiter' needs discretization.degree = 2 (ζ_3 ∈ H² by "
                f"C⁰ interior penalty), got {disc.degree}: remove the key or set it to 2"
            )
        if disc.transverse != "clamped":
            raise ConfigError(
                f"{source}: model.kind = 'koiter' clamps ζ_3 and ∂_ν ζ_3 on γ: remove "
                "discretization.transverse or set it to 'clamped'"
            )

    p = r.get("penalty", {})
    penalty = None
    if sv["method"] == "active-set":
        if "kappa" in p or "exponent" in p:
            warnings.warn(
                f"{source}: solver.method = 'active-set' solves the constraint exactly (κ = 0); "
                "penalty.kappa / penalty.exponent are ignored",
                stacklevel=2,
            )
        if disc.degree != 1:
            raise ConfigError(
                f"{source}: solver.method = 'active-set' imposes g ≥ 0 at the vertices of P1: "
                "set discretization.degree = 1"
            )
        # the exact solver's constraint is the nodal one, whatever the penalty would use
        disc = dataclasses.replace(disc, penalty_quadrature="vertex")
        r["discretization"]["penalty_quadrature"] = "vertex"
        r["penalty"] = {}
    else:
        penalty = PenaltySpec(p.get("kappa"), p.get("exponent"), p["continuation"])
    if sv.get("xi") is not None and not sv["xi"] > 0:
        raise ConfigError(f"{source}: solver.xi must be > 0, got {sv['xi']}")

    for key in ("rtol", "stol", "bs_rtol"):
        if sv[key] < 0:
            raise ConfigError(f"{source}: solver.{key} must be >= 0, got {sv[key]}")
    solver = NewtonOptions(
        rtol=sv["rtol"],
        stol=sv["stol"],
        max_iterations=sv["max_iterations"],
        linear_solver=sv["linear_solver"],
        factorization=sv["factorization"],
        contact_zone=sv["contact_zone"],
    )
    return Config(shell, domain, disc, penalty, solver, sv["method"], dict(r["output"]), r, source)


def load_config(path: str | Path, overrides: list[str] | None = None) -> Config:
    """Read a TOML file, apply ``section.key=value`` overrides, validate.

    Raises:
        ConfigError: for a missing or malformed file and every validation problem.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file {str(path)!r} does not exist")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    for item in overrides or []:
        apply_override(data, item, str(path))
    return parse_config(data, str(path))


def apply_override(data: dict[str, Any], item: str, source: str = "--set") -> None:
    """Apply ``section.key=value`` (value in TOML syntax; bare words are strings)."""
    if "=" not in item or "." not in item.split("=", 1)[0]:
        raise ConfigError(f"--set {item!r}: expected section.key=value, e.g. domain.h=0.01")
    lhs, rhs = item.split("=", 1)
    section, key = lhs.strip().split(".", 1)
    try:
        value = tomllib.loads(f"v = {rhs.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = rhs.strip()
    data.setdefault(section, {})[key] = value


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {v!r} to TOML")


def to_toml(resolved: Mapping[str, Mapping[str, Any]]) -> str:
    """Serialize a resolved configuration (what was used, defaults included)."""
    parts = []
    for section, keys in resolved.items():
        if not keys:
            continue
        parts.append(f"[{section}]")
        parts += [f"{k} = {_toml_value(v)}" for k, v in keys.items()]
        parts.append("")
    return "\n".join(parts)
