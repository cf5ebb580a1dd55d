"""The methods that solve the obstacle problem, by name: ``solver.method`` in the config.

A method is a small class (:class:`Method`) that solves one compiled problem and returns a
:class:`~shellobstacle.solvers.result.MethodResult`; :data:`METHODS` maps each name to one.
:func:`~shellobstacle.api.solve`, the adaptive loop and the experiments take the method
from here, the configuration takes its choices, and the documentation its table
(:func:`method_table`); the ``[solver]`` keys are those its options declare
(:func:`~shellobstacle.solvers.options.option`). Adding a method is one class, its options
dataclass and one :func:`register` call.

Importing this module loads neither DOLFINx nor PETSc: the methods import their solvers when
they solve.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

from shellobstacle.solvers.methods.base import build_options, keeping
from shellobstacle.solvers.options import config_keys, key_type
from shellobstacle.solvers.result import MethodResult
from shellobstacle.spec import Discretization

__all__ = [
    "DEFAULT",
    "METHODS",
    "Method",
    "discretization_for",
    "keeping",
    "method_help",
    "method_table",
    "options_for",
    "options_from",
    "register",
]


@runtime_checkable
class Method(Protocol):
    """A way to solve the obstacle problem on one compiled problem.

    Attributes:
        name: the value of ``solver.method`` that chooses it.
        penalized: it solves the penalized problem at κ > 0 (the config needs
            ``[penalty]``); False: the exact nodal problem (κ = 0, no ``[penalty]``).
        adaptive: it may solve the meshes of ``[adapt]`` (from the previous mesh's solution).
        options_type: the frozen dataclass of its options (None: it takes none); the fields
            declared by :func:`~shellobstacle.solvers.options.option` are its ``[solver]``
            keys.
        summary: one line on what it does (the config reference, the docs' table).

    Two members are optional:

    * ``options_from(values)``: its options from the config's ``[solver]`` values, for a
      method that checks them (:func:`options_from`; when absent,
      :func:`~shellobstacle.solvers.methods.base.build_options`).
    * ``keeping(problem)``: a context manager inside which ``solve`` may keep what it builds
      for ``problem`` and reuse it at the next solve of ``problem``, whose gap's linearization
      has moved in between (:func:`keeping`; the passes of
      :func:`~shellobstacle.solvers.linearization.solve_with`); when absent, nothing is kept.

    :class:`~shellobstacle.solvers.methods.base.MethodBase` gives both their defaults.
    """

    name: str
    penalized: bool
    adaptive: bool
    options_type: type | None
    summary: str

    def solve(
        self,
        problem: Any,
        h: float,
        kappas: Sequence[float],
        options: Any,
    ) -> MethodResult:
        """Solve ``problem`` (a :class:`~shellobstacle.models.problem.PenalizedProblem`) from its
        current ``zeta``, which then holds the answer (or the last iterate).

        Args:
            problem: the compiled problem.
            h: the mesh size.
            kappas: the κ ladder to go through, the target last (``[0.0]`` for a method
                that is not ``penalized``).
            options: an instance of ``options_type``, or None for its defaults.

        Progress goes to the ``shellobstacle`` logger (one record per line).

        Returns:
            The steps; a method that does not converge says so in the result (``converged``
            and ``error``), it does not raise.
        """
        ...


#: every method, by name (the order of the config reference and the docs' table)
METHODS: dict[str, Method] = {}
#: the default ``solver.method``, whose options the config always builds (the experiments'
#: Newton iteration uses them whatever the method)
DEFAULT = "newton"


def register(method: Method, replace: bool = False) -> Method:
    """Add ``method`` to :data:`METHODS` under ``method.name`` and return it.

    Raises:
        ValueError: the name is taken (unless ``replace``), ``method`` lacks part of the
            :class:`Method` protocol, or its options declare a key the config cannot read or
            that another method reads with another type.
    """
    if not isinstance(method, Method):
        raise ValueError(f"{method!r} is not a Method: it needs {', '.join(_PROTOCOL)}")
    if method.name in METHODS and not replace:
        raise ValueError(f"a method named {method.name!r} is already registered")
    problem = _options_problem(method)
    if problem:
        raise ValueError(f"solver.method = {method.name!r} cannot be registered: {problem}")
    METHODS[method.name] = method
    return method


_PROTOCOL = ("name", "penalized", "adaptive", "options_type", "summary", "solve")


def _options_problem(method: Method) -> str | None:
    """What is wrong with the declaration of ``method``'s options (None: nothing)."""
    kind = method.options_type
    if kind is None:
        return None
    if not (dataclasses.is_dataclass(kind) and kind.__dataclass_params__.frozen):
        return f"its options_type {kind!r} is not a frozen dataclass"
    try:
        types = {key: key_type(kind, f) for key, f in config_keys(kind).items()}
    except ValueError as err:
        return str(err)
    for other in METHODS.values():
        for key, f in config_keys(other.options_type).items():
            theirs = key_type(other.options_type, f)
            if other.name != method.name and key in types and types[key] != theirs:
                return (
                    f"solver.{key} is of type {theirs} for solver.method = {other.name!r}, "
                    f"not {types[key]}: give the option another key"
                )
    return None


def options_for(method: Method, given: Any, fallback: Any = None) -> Any:
    """The options ``method`` solves with: ``given`` (which must be of its ``options_type``),
    else ``fallback`` when it is (e.g. Newton's options for Newton), else None (its defaults).

    Raises:
        TypeError: ``given`` is not of the method's options type.
    """
    kind = method.options_type
    if given is not None:
        if kind is None or not isinstance(given, kind):
            expected = "no options" if kind is None else kind.__name__
            raise TypeError(
                f"solver.method = {method.name!r} takes {expected}, got {type(given).__name__}"
            )
        return given
    if kind is not None and isinstance(fallback, kind):
        return fallback
    return None


def discretization_for(method: Method, disc: Discretization) -> Discretization:
    """``disc`` as ``method`` solves on it: a method of the nodal problem (not ``penalized``)
    imposes the constraint at the nodes, which for P1 is the vertex penalty rule's set of
    points (docs/model.md §5), so its P1 takes ``penalty_quadrature = "vertex"``."""
    if not method.penalized and disc.degree == 1:
        return dataclasses.replace(disc, penalty_quadrature="vertex")
    return disc


def options_from(method: Method, values: Mapping[str, Any]) -> Any:
    """The options of ``method`` from the config's ``[solver]`` values: its own
    ``options_from(values)`` when it has one, else
    :func:`~shellobstacle.solvers.methods.base.build_options`.

    Raises:
        ValueError: a value the options refuse (a
            :class:`~shellobstacle.messages.ConfigError` names the key).
    """
    own = getattr(method, "options_from", None)
    return own(values) if own is not None else build_options(method, values)


def method_table() -> str:
    """The Markdown table of :data:`METHODS` (the user guide's, between its markers)."""
    lines = [
        "| `solver.method` | κ | options | what it solves |",
        "|---|---|---|---|",
    ]
    for m in METHODS.values():
        kappa = "κ > 0 (`[penalty]`)" if m.penalized else "κ = 0 (no `[penalty]`)"
        options = "—" if m.options_type is None else f"`{m.options_type.__name__}`"
        lines.append(f"| `{m.name}` | {kappa} | {options} | {m.summary} |")
    return "\n".join(lines)


def method_help() -> str:
    """What each method does, in one line (``solver.method`` in the config reference)."""
    return "; ".join(
        f"{m.name}: {m.summary}" + ("" if m.penalized else " (κ = 0, no [penalty])")
        for m in METHODS.values()
    )


def _builtin() -> None:
    """Register the package's methods."""
    from shellobstacle.solvers.methods.brezis_sibony import BrezisSibonyMethod
    from shellobstacle.solvers.methods.newton import NewtonContinuation
    from shellobstacle.solvers.methods.nodal_vi import (
        ActiveSetMethod,
        ProximalGalerkinMethod,
        SnesVIMethod,
    )

    register(NewtonContinuation())
    register(BrezisSibonyMethod())
    register(ActiveSetMethod())
    register(SnesVIMethod())
    register(ProximalGalerkinMethod())


_builtin()
