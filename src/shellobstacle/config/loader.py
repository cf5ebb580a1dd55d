"""TOML configuration → validated objects, with errors that name the key and the fix.

Keys, types and defaults come from :mod:`shellobstacle.config.schema`.
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from shellobstacle.config.build import build
from shellobstacle.config.keys import REQUIRED, Key
from shellobstacle.config.origins import Origins
from shellobstacle.config.schema import (
    ARRAY_SECTIONS,
    OPTIONAL_SECTIONS,
    REQUIRED_SECTIONS,
    SCHEMA,
    SELECTORS,
)
from shellobstacle.config.toml_io import apply_overrides, apply_sections, read_toml, to_toml
from shellobstacle.config.validated import Config, default_degree, method_of
from shellobstacle.geometry.expressions import ExpressionError
from shellobstacle.messages import ConfigError, not_one_of, suggest
from shellobstacle.obstacle.shapes import require_read
from shellobstacle.solvers.registry import DEFAULT
from shellobstacle.spec import (
    boolean,
    finite,
    integer,
)

__all__ = [
    "Config",
    "ConfigError",
    "apply_overrides",
    "as_config",
    "load_config",
    "method_of",
    "parse_config",
    "to_toml",
]


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
        if section in ARRAY_SECTIONS:
            if not isinstance(data[section], list) or not all(
                isinstance(t, dict) for t in data[section]
            ):
                raise ConfigError(
                    f"{origins.of(section)}: write each {section} as a table [[{section}]]"
                )
        elif not isinstance(data[section], dict):
            raise ConfigError(f"{origins.of(section)}: [{section}] must be a table of keys")
    for section in REQUIRED_SECTIONS:
        if section not in data:
            raise ConfigError(f"{source}: missing section [{section}]")
    koiter = isinstance(data.get("model"), dict) and data["model"].get("kind") == "koiter"
    selected = _selected(data, origins)
    given_keys: set[str] = set()
    for section, keys in SCHEMA.items():
        if section in ARRAY_SECTIONS:
            if data.get(section):
                resolved[section] = _array_section(data[section], section, keys, origins)
            continue
        if section in OPTIONAL_SECTIONS and section not in data:
            continue
        given = dict(data.get(section, {}))
        if section == "discretization" and koiter:
            given.setdefault("degree", default_degree("koiter"))  # ζ_3 ∈ H² needs P2
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
        config = build(resolved, source, given_keys)
    except (ValueError, ExpressionError) as err:  # ConfigError is a ValueError
        section = getattr(err, "section", "")
        own = [n for n in data.get(section, {}) if origins.of(f"{section}.{n}") == source]
        raise ConfigError(f"{origins.named_in(str(err), section, own)}: {err}") from None
    return dataclasses.replace(config, document=copy.deepcopy(dict(data)))


def _array_section(
    tables: list[Mapping[str, Any]], section: str, keys: Mapping[str, Key], origins: Origins
) -> list[dict[str, Any]]:
    """The tables of ``[[section]]``, each key checked and coerced (no defaults: an absent
    key stays absent)."""
    out = []
    for k, table in enumerate(tables, start=1):
        entry: dict[str, Any] = {}
        for name, value in table.items():
            dotted = f"{section}.{name}"
            where = f"{origins.of(section)}: [[{section}]] number {k}"
            if name not in keys:
                raise ConfigError(f"{where}: unknown key '{name}'" + suggest(name, list(keys)))
            entry[name] = _coerce(
                value, keys[name], f"{where}: {dotted}", origins.of(section), dotted
            )
        for name, key in keys.items():
            if key.default is REQUIRED and name not in entry:
                raise ConfigError(
                    f"{origins.of(section)}: [[{section}]] number {k} needs '{name}' ({key.help})"
                )
        out.append(entry)
    return out


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


def as_config(
    spec: Config | str | Path | Mapping[str, Any], overrides: Mapping[str, Any] | None = None
) -> Config:
    """The validated :class:`Config` of ``spec`` with ``overrides`` applied.

    Args:
        spec: a :class:`Config`, the path of a TOML file, or a mapping shaped like one.
        overrides: section → a mapping of its keys (``{"domain": {"h": 0.02}}``), applied
            and validated as ``--set domain.h=0.02`` is (:func:`apply_sections`). ``solver``
            may instead be an options object, which chooses the method whose
            ``options_type`` it is (:meth:`Config.with_options`).

    Raises:
        ConfigError: naming the override (or the file, or the key) and the fix.
    """
    sections = dict(overrides or {})
    options = sections.pop("solver") if _is_options(sections.get("solver")) else None
    if isinstance(spec, Config):
        moved = options is not None and method_of(options, spec.method) != spec.method
        if moved and spec.document is not None:
            sections["solver"] = {}  # re-read for the method the options choose
        if not sections:
            return spec if options is None else spec.with_options(options)
        if spec.document is None:
            raise ConfigError(
                f"overrides {', '.join(map(repr, sections))} need a config read from TOML or "
                "given as a mapping: change a Config built in Python by dataclasses.replace"
            )
        data, source = _plain(spec.document), spec.source
    elif isinstance(spec, str | Path):
        data, source = read_toml(Path(spec)), str(spec)
    elif isinstance(spec, Mapping):
        data, source = _plain(spec), "<config>"
    else:
        raise TypeError(
            f"a spec is a Config, a TOML file's path or a mapping, not {type(spec).__name__}"
        )
    if options is not None:  # the options choose the method: the config reads its keys
        current = data.get("solver", {}).get("method", DEFAULT)
        sections["solver"] = {**sections.get("solver", {}), "method": method_of(options, current)}
    config = parse_config(data, source, apply_sections(data, sections))
    return config if options is None else config.with_options(options)


def _is_options(value: object) -> bool:
    """``value`` is a dataclass instance (a method's options), not a mapping of keys."""
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def _plain(document: Mapping[str, Any]) -> dict[str, Any]:
    """A deep copy of ``document`` whose mappings are dicts (what the overrides edit)."""
    return {
        k: _plain(v) if isinstance(v, Mapping) else copy.deepcopy(v) for k, v in document.items()
    }
