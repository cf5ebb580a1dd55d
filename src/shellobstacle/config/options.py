"""The options of every ``solver.method`` and of ``[adapt]``, built from the resolved config
(the fields no key sets keep their classes' defaults) and checked against each other
(:mod:`shellobstacle.config.loader` calls them)."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.messages import ConfigError
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.options import config_keys
from shellobstacle.solvers.registry import DEFAULT, METHODS, options_from
from shellobstacle.spec import Shell

__all__ = ["adapt_options", "method_options", "solver_options"]


def solver_options(method: str, sv: Mapping[str, Any], given: Collection[str]) -> Any:
    """The options of ``method`` from ``[solver]`` (None for a method that takes none), built
    by the method (:func:`~shellobstacle.solvers.registry.options_from`) from the keys its
    options declare (:func:`~shellobstacle.solvers.options.config_keys`) that are in ``sv``
    when it is ``sv["method"]``, else those in ``given``; the fields no key sets keep the
    options class's defaults."""
    chosen = METHODS[method]
    values = {
        k: sv[k]
        for k in config_keys(chosen.options_type)
        if k in sv and (method == sv["method"] or k in given)
    }
    return options_from(chosen, values)


def method_options(sv: Mapping[str, Any], given: Collection[str]) -> tuple[NewtonOptions, Any]:
    """The default method's options (:data:`~shellobstacle.solvers.registry.DEFAULT`: the
    experiments' Newton uses them whatever ``solver.method``) and those of ``solver.method``
    when it is another, from ``[solver]``; the given keys that only another method reads are
    checked by that method too."""
    method = sv["method"]
    chosen = None if method == DEFAULT else solver_options(method, sv, given)
    for other in METHODS:
        if other not in (method, DEFAULT):
            alone = [k for k in given if _readers(k) == [other]]
            solver_options(other, {**{k: sv[k] for k in alone}, "method": method}, alone)
    return solver_options(DEFAULT, sv, given), chosen


def _readers(key: str) -> list[str]:
    """The methods whose options declare the ``[solver]`` key ``key``."""
    return [name for name, m in METHODS.items() if key in config_keys(m.options_type)]


def adapt_options(
    r: Mapping[str, Any], shell: Shell, penalty: PenaltySpec | None, method: str
) -> AdaptOptions:
    """``[adapt]``, and the choices it cannot be combined with."""
    adapt = AdaptOptions(**r["adapt"])
    if shell.model != "membrane":
        raise ConfigError(
            "[adapt] refines by the membrane model's error indicators: remove [adapt] or set "
            "model.kind = 'membrane'"
        )
    if not METHODS[method].adaptive:
        names = " or ".join(repr(m.name) for m in METHODS.values() if m.adaptive)
        raise ConfigError(
            f"[adapt] solves each mesh by {names}, not solver.method = {method!r}: remove "
            "[adapt] or change solver.method"
        )
    if adapt.kappa != "largest" and penalty is not None and penalty.exponent is None:
        raise ConfigError(
            f"adapt.kappa = {adapt.kappa!r} makes κ = h^exponent follow the mesh, which needs "
            "penalty.exponent; with penalty.kappa the same κ is used on every mesh: remove "
            "adapt.kappa or give penalty.exponent"
        )
    return adapt
