"""A configuration key and how it binds to the API's dataclasses.

A :class:`Key` has a type, a default and a meaning. A key that sets a field of an options
dataclass takes its default and choices from that field (:func:`bound`); a ``[solver]`` key is
declared on the fields of the methods' options that it sets
(:func:`~shellobstacle.solvers.options.option`) and made from those declarations
(:func:`option_key`). So the command line and the Python API cannot drift.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from shellobstacle.solvers.options import key_type

__all__ = [
    "OPTIONAL",
    "REQUIRED",
    "ByValue",
    "Key",
    "RegistryKeys",
    "bound",
    "option_key",
]

REQUIRED = object()
OPTIONAL = None


class ByValue(dict):
    """A default that depends on the section's selector (:data:`SELECTORS`): value → default."""


@dataclass(frozen=True)
class Key:
    """One configuration key: its type, default (``REQUIRED`` if none, a :class:`ByValue` if
    it depends on the selector) and meaning; ``when``: the values of its section's selector
    (:data:`SELECTORS`) that use it, empty for every value."""

    type: str  # "float", "int", "str", "bool", "float[n]", "str|float[3]", "table", "points",
    # "options" (a table of PETSc options)
    default: Any
    help: str
    choices: Collection[str] = ()
    when: Sequence[str] = ()
    #: the dataclass fields the key sets: (class, field name) per selector value, or ("", ...)
    fields: Mapping[str, tuple[type, str]] = field(default_factory=dict)

    def default_for(self, selector: Any) -> Any:
        """The default when the section's selector is ``selector``."""
        if isinstance(self.default, ByValue):
            return self.default.get(selector)
        return self.default

    def used_by(self, selector: Any) -> bool:
        """Whether the key is read when the section's selector is ``selector``."""
        return not self.when or selector in self.when


def _default(f: dataclasses.Field) -> Any:
    """The default of the field ``f`` (``REQUIRED`` if it has none)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return REQUIRED


def bound(
    owner: type,
    name: str,
    type: str,
    help: str,
    *,
    choices: tuple[str, ...] | None = None,
    when: tuple[str, ...] = (),
) -> Key:
    """The key that sets the field ``owner.name``: its default and (unless narrowed by
    ``choices``) its choices are the field's."""
    f = {f.name: f for f in dataclasses.fields(owner)}[name]
    found = tuple(f.metadata.get("choices", ()))
    return Key(type, _default(f), help, found if choices is None else choices, when,
               {"": (owner, name)})  # fmt: skip


def option_key(readers: Mapping[str, tuple[type, dataclasses.Field]], every: bool) -> Key:
    """The ``[solver]`` key that sets, for each method of ``readers``, a field of its options
    (method → (options class, field), each field declared by
    :func:`~shellobstacle.solvers.options.option`): its type, each method's default (a
    :class:`ByValue` where they differ), one meaning (each method's, named, where they differ)
    and the choices the config offers; read by every method (``every``) or by those named."""
    declared = [(m, cls, f) for m, (cls, f) in readers.items()]
    defaults = ByValue({m: _default(f) for m, _, f in declared})
    values = list(defaults.values())
    default = values[0] if all(v == values[0] for v in values) else defaults
    helps: dict[str, list[str]] = {}
    for m, _, f in declared:
        helps.setdefault(f.metadata["help"], []).append(m)
    help = next(iter(helps))
    if len(helps) > 1:
        help = "; ".join(f"{text} ({', '.join(names)})" for text, names in helps.items())
    choices = tuple(dict.fromkeys(c for _, _, f in declared for c in f.metadata["offered"]))
    _, cls, f = declared[0]
    fields = {m: (cls, f.name) for m, cls, f in declared}
    return Key(key_type(cls, f), default, help, choices, () if every else tuple(readers), fields)


class RegistryKeys(Mapping[str, Key]):
    """The keys of a section made from a registry by ``make()``, made again when the registry
    has changed: a method or a shape registered later is in them."""

    def __init__(self, registry: Mapping[str, Any], make: Callable[[], dict[str, Key]]) -> None:
        self._registry, self._make = registry, make
        self._seen: tuple[tuple[str, Any], ...] | None = None
        self._keys_now: dict[str, Key] = {}

    def _keys(self) -> dict[str, Key]:
        seen = tuple(self._registry.items())
        if seen != self._seen:
            self._seen, self._keys_now = seen, self._make()
        return self._keys_now

    def __getitem__(self, name: str) -> Key:
        return self._keys()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys())

    def __len__(self) -> int:
        return len(self._keys())
