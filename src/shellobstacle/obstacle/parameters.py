"""A parameter of an obstacle's shape: one key of ``[obstacle]``, declared once.

A shape (:mod:`shellobstacle.obstacle.shapes`) declares each argument of its constructor as a
:class:`Parameter`: its type in the config's words, its default, its range or choices and its
meaning. The Python API (:class:`~shellobstacle.spec.Obstacle`) checks a value with
:meth:`Parameter.check` and the config's schema and reference are generated from the
declarations, so the three say the same.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from shellobstacle.messages import finite, not_one_of

__all__ = ["TYPES", "Parameter"]

#: the types a parameter may have (the config's names for them)
TYPES = ("float", "float[3]", "str")


@dataclass(frozen=True)
class Parameter:
    """One key of ``[obstacle]`` that a shape reads, and the argument of its constructor.

    Attributes:
        name: the key, and the constructor's argument.
        type: ``"float"``, ``"float[3]"`` (three finite numbers, a tuple) or ``"str"``.
        help: what it is, in one line (the config reference).
        default: the value when the key is absent; None: the shape needs it.
        choices: the values a ``str`` may take (empty: any text).
        above: a ``float`` must be greater than this (None: any finite number).
        unit: for a ``float[3]`` that is divided by its norm (with a warning unless 1): what it
            defines and what it is, e.g. ``("axis", "direction")``, for the refusal of a zero
            vector (empty: taken as given).
        example: a value of a parameter without a default: every shape has an instance built
            from its defaults and examples (:func:`~shellobstacle.obstacle.shapes.example`).
    """

    name: str
    type: str
    help: str
    default: Any = None
    choices: tuple[str, ...] = ()
    above: float | None = None
    unit: tuple[str, str] | tuple[()] = ()
    example: Any = None

    def check(self, value: Any, what: str) -> Any:
        """``value`` as the shape takes it (a float, a tuple of three floats, a text), or a
        ValueError naming ``what`` (``obstacle.<name>``) and what is wrong."""
        if self.type == "float":
            out = finite(value, what)
            if self.above is not None and not out > self.above:
                raise ValueError(f"{what} must be > {self.above:g}, got {out!r}")
            return out
        if self.type == "float[3]":
            return _unit(value, what, *self.unit) if self.unit else _three(value, what)
        if not isinstance(value, str):
            raise ValueError(f"{what} must be a string, got {value!r}")
        if self.choices and value not in self.choices:
            raise ValueError(not_one_of(what, value, self.choices))
        return value

    def is_default(self, value: Any) -> bool:
        """Whether ``value`` is this parameter's default (a vector compared as numbers)."""
        if self.default is None or value is None:
            return value is self.default
        if isinstance(self.default, tuple):
            return (
                _numeric(value)
                and np.shape(value) == np.shape(self.default)
                and bool(np.array_equal(np.asarray(value, dtype=float), self.default))
            )
        return bool(value == self.default)


def _three(value: Any, what: str) -> tuple[float, float, float]:
    """Three finite numbers (not bools), or a ValueError naming ``what``."""
    if isinstance(value, str) or not _numeric(value) or np.shape(value) != (3,):
        raise ValueError(f"{what} must be three finite numbers, got {value!r}")
    x, y, z = (finite(v, f"{what}[{i + 1}]") for i, v in enumerate(value))
    return (x, y, z)


def _numeric(value: Any) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def _unit(value: Any, what: str, defines: str, vector: str) -> tuple[float, float, float]:
    """``value/|value|`` (a warning if ``|value| ≠ 1``), or a ValueError for a zero vector,
    which defines no ``defines``."""
    v = np.asarray(_three(value, what))
    largest = float(np.max(np.abs(v)))
    if largest == 0.0:
        raise ValueError(f"{what} = (0, 0, 0) defines no {defines}: give a nonzero {vector}")
    norm = largest * float(np.linalg.norm(v / largest))  # no overflow for huge entries
    if abs(norm - 1.0) > 1e-12:
        warnings.warn(
            f"{what} = {tuple(value)} has norm {norm:.6g}; using it divided by its norm",
            stacklevel=5,
        )
    unit = (v / largest) / float(np.linalg.norm(v / largest))
    return (float(unit[0]), float(unit[1]), float(unit[2]))
