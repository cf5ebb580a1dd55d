"""What the package's methods share: their options, built from the config's ``[solver]``
values by the keys their options declare (the optional members of
:class:`~shellobstacle.solvers.registry.Method`)."""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from contextlib import AbstractContextManager
from typing import Any

from shellobstacle.solvers.options import config_keys

__all__ = ["MethodBase", "build_options", "keeping"]


def build_options(method: Any, values: Mapping[str, Any]) -> Any:
    """``method``'s ``options_type`` with the fields its keys set
    (:func:`~shellobstacle.solvers.options.config_keys`) from ``values`` (``[solver]`` key →
    value; the fields of keys not in ``values`` keep their defaults); None for a method that
    takes no options."""
    kind = method.options_type
    if kind is None:
        return None
    keys = config_keys(kind)
    return kind(**{f.name: values[key] for key, f in keys.items() if key in values})


def keeping(method: Any, problem: Any) -> AbstractContextManager[Any]:
    """``method.keeping(problem)`` when the method has it, else a context that keeps nothing:
    the solves of ``problem`` inside it may reuse what the method built for it."""
    own = getattr(method, "keeping", None)
    return own(problem) if own is not None else contextlib.nullcontext()


class MethodBase:
    """The defaults of a method's optional members: its options built by
    :func:`build_options`, and nothing kept between solves."""

    def options_from(self, values: Mapping[str, Any]) -> Any:
        """The options from the config's ``[solver]`` values (:func:`build_options`)."""
        return build_options(self, values)

    def keeping(self, problem: Any) -> AbstractContextManager[Any]:
        """Inside it, :meth:`solve` may keep what it builds for ``problem`` for its next solve
        (:func:`keeping`); by default nothing is kept."""
        return contextlib.nullcontext()
