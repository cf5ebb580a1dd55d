"""Wording shared by the config loader and the Python API, so both raise the same text, and
the error type of a problem the user can fix (:class:`ConfigError`), and the checks of a single
value that both make (:func:`finite`, :func:`integer`, :func:`boolean`).

A value outside its choices is reported as ``key = 'value' is not one of 'a', 'b'; did you
mean 'a'?`` wherever it is caught: :mod:`shellobstacle.config.loader` prefixes the file (or the
``--set``) that gave it, the dataclasses of the API raise the bare text.
"""

from __future__ import annotations

import difflib
import math
import numbers
from collections.abc import Sequence
from typing import Any

__all__ = [
    "ECHO_LIMIT",
    "ConfigError",
    "boolean",
    "cut",
    "finite",
    "integer",
    "not_one_of",
    "shown",
    "suggest",
]

#: The most characters of user input a message echoes.
ECHO_LIMIT = 80


def cut(text: str, limit: int = ECHO_LIMIT) -> str:
    """``text``, or its first ``limit`` characters and ``… (N characters)``."""
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} characters)"


def shown(value: object, limit: int = ECHO_LIMIT) -> str:
    """``repr(value)`` (a text quoted), cut after ``limit`` characters of the text or the
    representation (:func:`cut`): a message about a huge input stays one line."""
    if not isinstance(value, str):
        return cut(repr(value), limit)
    if len(value) <= limit:
        return repr(value)
    return f"{value[:limit]!r}… ({len(value)} characters)"


def suggest(name: str, options: Sequence[str], what: str = "valid keys") -> str:
    """``; did you mean 'x'?`` for a close option, else ``; <what>: a, b, c``."""
    close = difflib.get_close_matches(name, list(options), n=1, cutoff=0.5)
    return f"; did you mean {close[0]!r}?" if close else f"; {what}: {', '.join(options)}"


def not_one_of(key: str, value: object, choices: Sequence[str]) -> str:
    """The message for ``key = value`` outside ``choices`` (with a suggestion)."""
    text = f"{key} = {shown(value)} is not one of {', '.join(map(repr, choices))}"
    close = difflib.get_close_matches(str(value), list(choices), n=1, cutoff=0.5)
    return text + (f"; did you mean {close[0]!r}?" if isinstance(value, str) and close else "")


class ConfigError(ValueError):
    """A configuration problem the user can fix; the message names file, key and fix."""


def finite(value: Any, what: str) -> float:
    """``value`` as a float if it is a finite number (not a bool), else a ValueError naming
    ``what``: the check of every number of the config and of the API's dataclasses."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{what} must be a number, got {value!r}")
    try:
        out = float(value)
    except OverflowError:
        raise ValueError(f"{what} is too large to be a floating-point number") from None
    if not math.isfinite(out):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return out


def boolean(value: Any, what: str) -> bool:
    """``value`` if it is true or false, else a ValueError naming ``what``."""
    if not isinstance(value, bool):
        raise ValueError(f"{what} must be true or false, got {value!r}")
    return value


def integer(value: Any, what: str) -> int:
    """``value`` if it is an integer (not a bool), else a ValueError naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{what} must be an integer, got {value!r}")
    return int(value)
