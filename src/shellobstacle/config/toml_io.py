"""TOML text in and out: reading a config file, ``--set`` overrides, writing a resolved config.

:mod:`shellobstacle.config.loader` validates what is read here.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomli_w

from shellobstacle.messages import ConfigError

__all__ = ["apply_overrides", "apply_sections", "read_toml", "to_toml"]


def read_toml(path: Path) -> dict[str, Any]:
    """The TOML document in ``path`` (UTF-8, with or without a byte-order mark); a directory,
    a binary or unreadable file is refused."""
    if path.is_dir():
        raise ConfigError(f"config file {str(path)!r} is a directory: give a TOML file")
    if not path.exists():
        raise ConfigError(f"config file {str(path)!r} does not exist")
    if not path.is_file():
        raise ConfigError(f"config file {str(path)!r} is not a regular file: give a TOML file")
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise ConfigError(f"config file {str(path)!r} cannot be read: {err.strerror}") from None
    try:
        text = raw.decode("utf-8-sig")  # a byte-order mark (Windows editors write one) is dropped
    except UnicodeDecodeError as err:
        raise ConfigError(
            f"{path}: not a text file (byte {err.start} is not UTF-8): give a TOML config file"
        ) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None


#: keys of which a config gives one: a ``--set`` of one removes the other from the file
_EXCLUSIVE = {"penalty.kappa": "exponent", "penalty.exponent": "kappa"}


def apply_overrides(data: dict[str, Any], items: list[str]) -> dict[str, str]:
    """Apply ``section.key=value`` overrides in order (value in TOML syntax, bare words are
    strings; ``load.parameters.ell=3`` sets a key inside a table). A ``--set`` of
    ``penalty.kappa`` removes the file's ``penalty.exponent`` and conversely.

    Returns:
        dotted key → the ``--set`` text that gave it (errors about it name the ``--set``).
    """
    given: dict[str, str] = {}
    for item in items:
        lhs, sep, rhs = item.partition("=")
        parts = [part.strip() for part in lhs.split(".")]
        if not sep or len(parts) < 2 or not all(parts):
            raise ConfigError(f"--set {item!r}: expected section.key=value, e.g. domain.h=0.01")
        try:
            value = tomllib.loads(f"v = {rhs.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = rhs.strip()
        _put(data, parts, value, f"--set {item.strip()}", given)
    return given


def apply_sections(data: dict[str, Any], sections: Mapping[str, Any]) -> dict[str, str]:
    """Apply overrides given in Python as sections, ``domain={"h": 0.01}``, as
    :func:`apply_overrides` applies ``--set domain.h=0.01`` (a table's keys are set one by
    one: ``load={"parameters": {"ell": 3}}`` keeps the file's other parameters).

    Returns:
        dotted key → the override that gave it, e.g. ``domain={'h': 0.01}``.
    """
    given: dict[str, str] = {}
    for section, keys in sections.items():
        if not isinstance(keys, Mapping):
            raise ConfigError(
                f"{section}={keys!r}: give a section as a mapping of its keys, "
                "e.g. domain={'h': 0.01}"
            )
        for parts, value in _leaves([section], keys):
            text = f"{section}={_nested(parts[1:], value)}"
            _put(data, parts, value, text, given)
    return given


def _leaves(path: list[str], keys: Mapping[str, Any]) -> list[tuple[list[str], Any]]:
    """``(dotted path, value)`` of every value of ``keys`` that is not a mapping."""
    out = []
    for name, value in keys.items():
        if isinstance(value, Mapping) and value:
            out += _leaves([*path, str(name)], value)
        else:
            out.append(([*path, str(name)], value))
    return out


def _nested(parts: list[str], value: Any) -> str:
    """``{'parameters': {'ell': 3}}``: the mapping that sets ``value`` at ``parts``."""
    return repr(value) if not parts else f"{{{parts[0]!r}: {_nested(parts[1:], value)}}}"


def _put(
    data: dict[str, Any], parts: list[str], value: Any, text: str, given: dict[str, str]
) -> None:
    """Set ``data[parts[0]]…[parts[-1]] = value``, recording ``text`` as its origin."""
    table = data
    for i, part in enumerate(parts[:-1]):
        table = table.setdefault(part, {})
        if not isinstance(table, dict):
            where = ".".join(parts[: i + 1])
            raise ConfigError(f"{text}: {where} is not a table, it cannot hold '{parts[-1]}'")
    dotted = ".".join(parts)
    partner = _EXCLUSIVE.get(dotted)
    if partner is not None and f"penalty.{partner}" not in given:
        table.pop(partner, None)
    table[parts[-1]] = value
    given[dotted] = text


def to_toml(resolved: Mapping[str, Mapping[str, Any]]) -> str:
    """Serialize a resolved configuration (what was used, defaults included) by
    :mod:`tomli_w`: a table per section, a sub-table per table-valued key."""
    return tomli_w.dumps({section: keys for section, keys in resolved.items() if keys})
