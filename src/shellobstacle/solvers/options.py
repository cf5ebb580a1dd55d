"""How a method declares its options: one frozen dataclass whose fields carry their
``[solver]`` key (:func:`option`), from which the configuration's schema, its reference and
its checks are generated; and the PETSc options every method takes.

The options of each family live beside its solvers
(:class:`~shellobstacle.solvers.newton.options.NewtonOptions`,
:class:`~shellobstacle.solvers.brezis_sibony.options.BrezisSibonyOptions`,
:mod:`shellobstacle.solvers.vi.options`). Plain data, importable without DOLFINx or PETSc.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from shellobstacle.messages import not_one_of

__all__ = [
    "FACTORIZATIONS",
    "FACTORIZATION_HELP",
    "KEY_TYPES",
    "PETSC_OPTIONS_HELP",
    "check_choices",
    "check_petsc_options",
    "config_keys",
    "key_type",
    "option",
    "petsc_options_field",
]

FACTORIZATIONS = ("cholesky", "lu")
#: what ``factorization`` is, for every method that factorizes by MUMPS
FACTORIZATION_HELP = (
    "direct solver: Cholesky (LDLᵀ of a symmetric matrix; half the memory of LU), or LU"
)
#: what ``petsc_options`` is, in every options class and in the config reference
PETSC_OPTIONS_HELP = (
    "PETSc options (names without the leading '-', e.g. ksp_type, pc_factor_mat_solver_type, "
    "mat_mumps_icntl_14) set on the main linear solver of the method under its own prefix "
    "shellobstacle_<kind><n>_ (kind: newton and zone for newton, bs_mass and bs_linearized "
    "for brezis-sibony, as for active-set, vi for snes-vi: the SNES, its KSP and PC, pg for "
    "proximal-galerkin); an option no object reads is reported in a warning"
)
#: the type of a ``[solver]`` key (the config's name of it) by the field's annotation
KEY_TYPES: dict[type, str] = {float: "float", int: "int", bool: "bool", str: "str"}
_OPTION_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def option(
    default: Any = dataclasses.MISSING,
    *,
    help: str,
    key: str | None = None,
    choices: Sequence[str] = (),
    offered: Sequence[str] | None = None,
    factory: Callable[[], Any] | None = None,
) -> Any:
    """A field of a method's options that a ``[solver]`` key sets: the one declaration of
    that key (its type is the field's annotation, its default the field's).

    Args:
        default: the field's default (the API's and the config's).
        help: the key's meaning, one line of the config reference.
        key: the key's name when it is not the field's (e.g. ``bs_rtol`` for Brezis–Sibony's
            ``rtol``).
        choices: the values the field takes (:func:`check_choices`).
        offered: those the config accepts, when fewer (default: all of ``choices``).
        factory: makes the default instead of ``default`` (a mutable one, e.g. ``dict``).
    """
    metadata = {
        "help": help,
        "key": key,
        "choices": tuple(choices),
        "offered": tuple(choices if offered is None else offered),
    }
    if factory is not None:
        return dataclasses.field(default_factory=factory, hash=False, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def petsc_options_field() -> Any:
    """The ``petsc_options`` field of an options class: a table of PETSc options."""
    return option(help=PETSC_OPTIONS_HELP, factory=dict)


def config_keys(options_type: type | None) -> dict[str, dataclasses.Field]:
    """``[solver]`` key → the field of ``options_type`` it sets (the fields declared by
    :func:`option`; empty for None)."""
    if options_type is None:
        return {}
    return {
        f.metadata["key"] or f.name: f
        for f in dataclasses.fields(options_type)
        if "help" in f.metadata
    }


def key_type(options_type: type, f: dataclasses.Field) -> str:
    """The type of the key that sets the field ``f``: ``float``, ``int``, ``bool``, ``str``
    (optionally ``| None``) or ``options`` (a table of PETSc options, a mapping).

    Raises:
        ValueError: an annotation the config cannot read.
    """
    hint = typing.get_type_hints(options_type)[f.name]
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        hint = args[0] if len(args) == 1 else hint
    if hint in KEY_TYPES:
        return KEY_TYPES[hint]
    origin = typing.get_origin(hint) or hint
    if isinstance(origin, type) and issubclass(origin, Mapping):
        return "options"
    raise ValueError(
        f"{options_type.__name__}.{f.name}: a [solver] key is a float, int, bool or str (or "
        f"None) or a mapping of PETSc options, not {hint}"
    )


def check_choices(options: Any) -> None:
    """Raise ValueError for a field of ``options`` whose value is not one of its declared
    ``choices``, naming its ``[solver]`` key (its own name for a field no key sets)."""
    for f in dataclasses.fields(options):
        choices = f.metadata.get("choices")
        value = getattr(options, f.name)
        if choices and value not in choices:
            name = f"solver.{f.metadata['key'] or f.name}" if "help" in f.metadata else f.name
            raise ValueError(not_one_of(name, value, choices))


def check_petsc_options(values: Mapping[str, Any]) -> None:
    """Raise ValueError for a name that is not a PETSc option name or a value PETSc cannot
    take (a string, a number or a boolean)."""
    if not isinstance(values, Mapping):
        raise ValueError(f"solver.petsc_options must be a table of options, got {values!r}")
    for name, value in values.items():
        if not isinstance(name, str) or not _OPTION_NAME.fullmatch(name):
            raise ValueError(
                f"solver.petsc_options: {name!r} is not a PETSc option name (letters, digits "
                "and _, without the leading '-' and without a prefix, e.g. ksp_type)"
            )
        if not isinstance(value, str | int | float | bool):
            raise ValueError(
                f"solver.petsc_options.{name} must be a string, a number or true/false, "
                f"got {value!r}"
            )
