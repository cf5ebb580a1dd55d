"""PETSc options prefixes of the solvers: one per solver object, never reused.

A prefix made from ``id()`` can come back once its object is freed, and with it whatever
options an earlier solver put in PETSc's global options database.
"""

from __future__ import annotations

import itertools
import weakref
from typing import Any

from petsc4py import PETSc

__all__ = ["set_options", "unique_prefix"]

_NUMBERS = itertools.count()


def unique_prefix(kind: str) -> str:
    """``shellobstacle_<kind><n>_`` with ``n`` never used before in this process."""
    return f"shellobstacle_{kind}{next(_NUMBERS)}_"


def _forget(names: list[str]) -> None:
    options = PETSc.Options()
    for name in names:
        options.delValue(name)


def set_options(owner: object, prefix: str, values: dict[str, Any]) -> None:
    """Put ``values`` under ``prefix`` in the options database until ``owner`` is freed."""
    options = PETSc.Options()
    for key, value in values.items():
        options[prefix + key] = value
    weakref.finalize(owner, _forget, [prefix + key for key in values])
