"""TOML configuration → validated objects, with errors that name the key and the fix.

Keys, types and defaults come from :mod:`shellobstacle.config.schema`.
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.config.keys import REQUIRED, Key
from shellobstacle.config.options import adapt_options, method_options, solver_options
from shellobstacle.config.origins import Origins, in_section
from shellobstacle.config.schema import OPTIONAL_SECTIONS, REQUIRED_SECTIONS, SCHEMA, SELECTORS
from shellobstacle.config.toml_io import apply_overrides, read_toml, to_toml
from shellobstacle.geometry.expressions import ExpressionError
from shellobstacle.geometry.surface import Surface
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.messages import ConfigError, not_one_of, suggest
from shellobstacle.obstacle.shapes import require_read
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.options import NewtonOptions
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import (
    Discretization,
    Load,
    Material,
    Obstacle,
    Shell,
    boolean,
    finite,
    integer,
)

__all__ = [
    "Config",
    "ConfigError",
    "apply_overrides",
    "load_config",
    "parse_config",
    "to_toml",
]


@dataclass(frozen=True)
class Config:
    """A validated configuration: the physical shell and every numerical choice
    (``method_options``: the options of ``method`` when it is not Newton's)."""

    shell: Shell
    domain: DomainSpec
    discretization: Discretization
    penalty: PenaltySpec | None  # None for the methods of κ = 0 (not METHODS[m].penalized)
    solver: NewtonOptions
    method: str
    output: Mapping[str, bool]
    resolved: Mapping[str, Mapping[str, Any]]
    source: str
    method_options: Any = None  # the options of solver.method when it is not Newton's
    adapt: AdaptOptions | None = None  # [adapt]: solve on adaptively refined meshes

    def options_of(self, method: str) -> Any:
        """The options of ``method`` (any of them, e.g. Brezis–Sibony beside Newton in an
        experiment) from the keys of ``[solver]`` it reads; the others keep its defaults."""
        return solver_options(method, self.resolved["solver"], self.resolved["solver"])


def _coerce(value: Any, key: Key, where: str, origin: str, dotted: str) -> Any:
    """Check and convert one value to the key's type (``where`` = ``origin: dotted``)."""

    def number(v: Any, what: str) -> float:
        return _checked(finite, v, what)

    t = key.type
    if t == "float":
        return number(value, where)
    if t == "int":
        return _checked(integer, value, where)
    if t == "bool":
        return _checked(boolean, value, where)
    if t == "str":
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        if key.choices and value not in key.choices:
            raise ConfigError(f"{origin}: {not_one_of(dotted, value, key.choices)}")
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
    if t == "options":
        if not isinstance(value, dict):
            raise ConfigError(
                f"{where} must be a table of PETSc options (name = value), got {value!r}"
            )
        out = {}
        for k, v in value.items():
            if isinstance(v, float):
                v = number(v, f"{where}.{k}")
            elif not isinstance(v, str | int | bool):
                raise ConfigError(
                    f"{where}.{k} must be a string, a number or true/false, got {v!r}"
                )
            out[k] = v
        return out
    raise AssertionError(t)


def _checked(check: Callable[[Any, str], Any], value: Any, what: str) -> Any:
    """``check(value, what)``, one of the API's checks of a value (:mod:`shellobstacle.spec`),
    its ValueError a ConfigError."""
    try:
        return check(value, what)
    except ValueError as err:
        raise ConfigError(str(err)) from None


def parse_config(
    data: Mapping[str, Any],
    source: str = "<config>",
    overrides: Mapping[str, str] | None = None,
    reads: Mapping[str, tuple[str, ...]] | None = None,
) -> Config:
    """Validate a parsed TOML document and build a :class:`Config`.

    A given key that the chosen kind or method does not read (``Key.when``) is reported in a
    warning naming the key and the choice.

    Args:
        data: the document.
        source: the file it came from, named in errors.
        overrides: dotted key → the ``--set`` text that gave it (:func:`apply_overrides`);
            errors about those keys name the ``--set`` instead of the file.
        reads: selector (e.g. ``"solver.method"``) → the other values whose keys the command
            reads too (an experiment that runs Brezis–Sibony beside the config's method).

    Raises:
        ConfigError: naming the file (or ``--set``), the section, the key and the fix.
    """
    origins = Origins(source, overrides)
    resolved: dict[str, dict[str, Any]] = {}
    for section in data:
        if section not in SCHEMA:
            raise ConfigError(
                f"{origins.of(section)}: unknown section [{section}]"
                + suggest(section, list(SCHEMA))
            )
        if not isinstance(data[section], dict):
            raise ConfigError(f"{origins.of(section)}: [{section}] must be a table of keys")
    for section in REQUIRED_SECTIONS:
        if section not in data:
            raise ConfigError(f"{source}: missing section [{section}]")
    koiter = isinstance(data.get("model"), dict) and data["model"].get("kind") == "koiter"
    selected = _selected(data, origins)
    given_keys: set[str] = set()
    for section, keys in SCHEMA.items():
        if section in OPTIONAL_SECTIONS and section not in data:
            continue
        given = dict(data.get(section, {}))
        if section == "discretization" and koiter:
            given.setdefault("degree", 2)  # Koiter's ζ_3 ∈ H² needs P2
        for name in given:
            if name not in keys:
                raise ConfigError(
                    f"{origins.of(f'{section}.{name}')}: unknown key '{name}' in [{section}]"
                    + suggest(name, list(keys))
                )
        selector, reason = SELECTORS.get(section, ("", ""))
        value = selected.get(selector)
        out: dict[str, Any] = {}
        for name, key in keys.items():
            dotted = f"{section}.{name}"
            origin = origins.of(dotted)
            if name in given:
                out[name] = _coerce(given[name], key, f"{origin}: {dotted}", origin, dotted)
                given_keys.add(name if section == "solver" else dotted)
                also = (reads or {}).get(selector, ())
                if selector and value is not None and not any(map(key.used_by, (value, *also))):
                    # another shape's key: the user meant another shape (unless a --set
                    # changed the shape, and the key is the file's for the old one)
                    changed = origins.of(selector) != source and origin == source
                    if section == "obstacle" and not changed:
                        try:  # the API's rule and message (shellobstacle.obstacle.shapes)
                            require_read(value, [name])
                        except ValueError as err:
                            raise ConfigError(f"{origin}: {err}") from None
                    if section == "obstacle":  # not read: not in the resolved config either
                        del out[name]
                    warnings.warn(
                        f"{origin}: {dotted} is ignored: {selector} = {value!r} {reason}"
                        + (f" (read with {' or '.join(map(repr, key.when))})" if key.when else ""),
                        stacklevel=2,
                    )
            elif key.default is REQUIRED:
                raise ConfigError(f"{source}: missing key '{name}' in [{section}] ({key.help})")
            elif key.used_by(value) and key.default_for(value) is not None:
                out[name] = copy.deepcopy(key.default_for(value))
        resolved[section] = out
    try:
        return _build(resolved, source, given_keys)
    except (ValueError, ExpressionError) as err:  # ConfigError is a ValueError
        section = getattr(err, "section", "")
        own = [n for n in data.get(section, {}) if origins.of(f"{section}.{n}") == source]
        raise ConfigError(f"{origins.named_in(str(err), section, own)}: {err}") from None


def _selected(data: Mapping[str, Any], origins: Origins) -> dict[str, Any]:
    """The value of every selector (:data:`~shellobstacle.config.schema.SELECTORS`) that ``data``
    gives or defaults: which keys of a section are read depends on it."""
    out: dict[str, Any] = {}
    for selector, _ in SELECTORS.values():
        section, name = selector.split(".")
        key = SCHEMA[section][name]
        if name in data.get(section, {}):
            origin = origins.of(selector)
            where = f"{origin}: {selector}"
            out[selector] = _coerce(data[section][name], key, where, origin, selector)
        elif key.default is not REQUIRED:
            out[selector] = key.default
    return out


def _need(sec: Mapping[str, Any], section: str, names: tuple[str, ...], why: str) -> None:
    for n in names:
        if n not in sec:
            raise ConfigError(f"[{section}] needs '{n}' for {why}")


def _surface(s: Mapping[str, Any]) -> Surface:
    """The surface of ``[surface]``."""
    kind = s["kind"]
    if kind == "spherical_cap":
        _need(s, "surface", ("radius", "offset"), "kind = 'spherical_cap'")
        return Surface.spherical_cap(s["radius"], s["offset"])
    if kind == "ellipsoid_cap":
        _need(s, "surface", ("semi_axes", "offset"), "kind = 'ellipsoid_cap'")
        return Surface.ellipsoid_cap(s["semi_axes"], s["offset"])
    if kind == "elliptic_paraboloid":
        _need(s, "surface", ("height", "curvatures"), "kind = 'elliptic_paraboloid'")
        return Surface.elliptic_paraboloid(s["height"], s["curvatures"])
    _need(s, "surface", ("theta",), "kind = 'expression'")
    return Surface.from_strings(s["theta"])


def _obstacle(o: Mapping[str, Any]) -> Obstacle:
    """The obstacle of ``[obstacle]`` (the keys its kind reads; vectors as tuples)."""
    return Obstacle(**{k: tuple(v) if isinstance(v, list) else v for k, v in o.items()})


def _build(r: dict[str, dict[str, Any]], source: str, given: set[str]) -> Config:
    """The objects of a resolved configuration; their constructors validate (the API's
    messages, which :func:`parse_config` prefixes with the file or the ``--set``). ``given``:
    the keys of ``[solver]`` and the dotted others the file or a ``--set`` gives."""
    with in_section("surface"):
        surface = _surface(r["surface"])
    m = r["material"]
    material = Material(m["epsilon"], m["lambda"], m["mu"])
    load = Load(tuple(r["load"]["p"]), dict(r["load"].get("parameters", {})))
    model = r["model"]["kind"]
    shell = Shell(surface, material, load, _obstacle(r["obstacle"]), model)
    shell.load_expressions()  # parse now: errors name the key

    d = dict(r["domain"])
    if "path" in d and not Path(d["path"]).is_absolute():
        # relative to the config; the resolved config (a result folder's config.toml) holds
        # the absolute path, so that it reruns from anywhere
        base = Path(source).parent if source not in ("<config>", "") else Path(".")
        d["path"] = r["domain"]["path"] = str((base / d["path"]).resolve())
    with in_section("domain"):
        if d["kind"] == "file" and "path" in d:
            _require_mesh_file(d["path"])
        domain = DomainSpec(**d)

    disc = Discretization(**r["discretization"])
    sv = r["solver"]
    if model == "koiter":
        _koiter_choices(sv, disc)

    p = r.get("penalty", {})
    penalty = None
    if not METHODS[sv["method"]].penalized:
        if disc.degree == 1:
            # the nodal methods' constraint is the one P1's vertex penalty has
            disc = dataclasses.replace(disc, penalty_quadrature="vertex")
            r["discretization"]["penalty_quadrature"] = "vertex"
        r["penalty"] = {}
    else:
        penalty = PenaltySpec(p.get("kappa"), p.get("exponent"), p["continuation"])
    solver, options = method_options(sv, given)
    adapt = adapt_options(r, shell, penalty, sv["method"]) if "adapt" in r else None
    return Config(
        shell,
        domain,
        disc,
        penalty,
        solver,
        sv["method"],
        dict(r["output"]),
        r,
        source,
        options,
        adapt,
    )


def _require_mesh_file(path: str) -> None:
    """A mesh file is a regular file: refused at loading, before any result folder."""
    p = Path(path)
    problem = "is a directory" if p.is_dir() else "does not exist" if not p.exists() else None
    if problem or not p.is_file():
        raise ConfigError(
            f"domain.path: mesh file {path!r} {problem or 'is not a regular file'}: give a "
            "gmsh .msh file (a relative path is relative to the config file)"
        )


def _koiter_choices(sv: Mapping[str, Any], disc: Discretization) -> None:
    """The solver and discretization choices Koiter's model cannot take."""
    if sv.get("linear_solver") == "iterative":
        raise ConfigError(
            "solver.linear_solver = 'iterative' preconditions ζ_3 as the membrane's L² "
            "unknown, not Koiter's bending: use linear_solver = 'direct' or 'multigrid'"
        )
    if sv.get("nested_iteration") == "on":
        raise ConfigError(
            "solver.nested_iteration relaxes ζ_3 as the membrane's L² unknown, which Koiter's "
            "bending differentiates: remove the key or set it to 'off'"
        )
    if disc.degree != 2:
        raise ConfigError(
            "model.kind = 'koiter' needs discretization.degree = 2 (ζ_3 ∈ H² by "
            f"C⁰ interior penalty), got {disc.degree}: remove the key or set it to 2"
        )
    if disc.transverse != "clamped":
        raise ConfigError(
            "model.kind = 'koiter' clamps ζ_3 and ∂_ν ζ_3 on γ: remove "
            "discretization.transverse or set it to 'clamped'"
        )


def load_config(
    path: str | Path,
    overrides: list[str] | None = None,
    reads: Mapping[str, tuple[str, ...]] | None = None,
) -> Config:
    """Read a TOML file, apply ``section.key=value`` overrides (:func:`apply_overrides`),
    validate (``reads``: see :func:`parse_config`).

    Raises:
        ConfigError: for a missing, unreadable or malformed file and every validation problem.
    """
    path = Path(path)
    data = read_toml(path)
    given = apply_overrides(data, overrides or [])
    return parse_config(data, str(path), given, reads)
