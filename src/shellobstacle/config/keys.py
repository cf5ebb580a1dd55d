"""A configuration key and how it binds to the API's dataclasses.

A :class:`Key` has a type, a default and a meaning. A key that sets a field of an options
dataclass takes its default and choices from that field (:func:`bound`); a ``[solver]`` key
sets a field of the options of every method that reads it (:data:`SOLVER_FIELDS`, from each
method's ``solver_fields``), and its default is that method's (:func:`solver_key`). So the
command line and the Python API cannot drift.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from shellobstacle.solvers.registry import METHODS, solver_fields

__all__ = [
    "METHOD_OPTIONS",
    "OPTIONAL",
    "REQUIRED",
    "SOLVER_FIELDS",
    "ByValue",
    "Key",
    "bound",
    "solver_key",
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
    choices: Collection[str] = ()  # a live view for solver.method (the registry's names)
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


def _default(owner: type, name: str) -> Any:
    """The default of the field ``owner.name`` (``REQUIRED`` if it has none)."""
    f = {f.name: f for f in dataclasses.fields(owner)}[name]
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
    return Key(type, _default(owner, name), help, found if choices is None else choices, when,
               {"": (owner, name)})  # fmt: skip


class _MethodOptions(Mapping[str, type]):
    """``solver.method`` → its options class, read from the registry (a live view: a method
    registered later is in it; a method that takes no options is not)."""

    def __getitem__(self, name: str) -> type:
        cls = METHODS[name].options_type
        if cls is None:
            raise KeyError(name)
        return cls

    def __iter__(self) -> Iterator[str]:
        return (name for name, m in METHODS.items() if m.options_type is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


#: the options class of each ``solver.method``
METHOD_OPTIONS: Mapping[str, type] = _MethodOptions()
_ALL = tuple(METHOD_OPTIONS)


class _SolverFields(Mapping[str, Mapping[str, str]]):
    """``[solver]`` key → the field it sets in the options of each method that reads it, read
    from the methods' ``solver_fields`` (a live view, like :data:`METHOD_OPTIONS`)."""

    def _all(self) -> dict[str, dict[str, str]]:
        out: dict[str, dict[str, str]] = {}
        for name, method in METHODS.items():
            for key, field_name in solver_fields(method).items():
                out.setdefault(key, {})[name] = field_name
        return out

    def __getitem__(self, key: str) -> Mapping[str, str]:
        return self._all()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())


#: ``[solver]`` key → the field it sets in the options of each method that reads it
SOLVER_FIELDS: Mapping[str, Mapping[str, str]] = _SolverFields()


def solver_key(name: str, type: str, help: str, choices: tuple[str, ...] | None = None) -> Key:
    """The ``[solver]`` key ``name``: the default of each method that reads it is the field's
    of that method's options (:data:`SOLVER_FIELDS`)."""
    fields = {m: (METHOD_OPTIONS[m], f) for m, f in SOLVER_FIELDS[name].items()}
    defaults = ByValue({m: _default(cls, f) for m, (cls, f) in fields.items()})
    values = list(defaults.values())
    default = values[0] if all(v == values[0] for v in values) else defaults
    if choices is None:
        found = [
            {f.name: f for f in dataclasses.fields(cls)}[f].metadata.get("choices", ())
            for cls, f in fields.values()
        ]
        choices = tuple(found[0])
    when = () if set(fields) == set(_ALL) else _ReadBy(name)
    return Key(type, default, help, choices, when, fields)


class _ReadBy(Sequence[str]):
    """The methods that read the ``[solver]`` key ``key`` (a live view of
    :data:`SOLVER_FIELDS`: a method registered later that reads it is in it)."""

    def __init__(self, key: str) -> None:
        self.key = key

    def _names(self) -> tuple[str, ...]:
        return tuple(SOLVER_FIELDS.get(self.key, ()))

    def __getitem__(self, i: Any) -> Any:
        return self._names()[i]

    def __len__(self) -> int:
        return len(self._names())

    def __repr__(self) -> str:
        return repr(self._names())
