"""The options of every ``solver.method`` and of ``[adapt]``, built from the resolved config
(the fields no key sets keep their classes' defaults) and checked against each other
(:mod:`shellobstacle.config.loader` calls them)."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.config.keys import METHOD_OPTIONS, SOLVER_FIELDS
from shellobstacle.messages import ConfigError
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.options import (
    NewtonOptions,
)
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import Shell

__all__ = ["adapt_options", "method_options", "solver_options"]


def solver_options(method: str, sv: Mapping[str, Any], given: Collection[str]) -> Any:
    """The options of ``method`` from ``[solver]``
    (:data:`~shellobstacle.config.keys.SOLVER_FIELDS`; None for a method that takes none):
    the keys it reads that are in ``sv`` when it is ``sv["method"]``, else those in ``given``;
    the fields no key sets keep the options class's defaults."""
    if method not in METHOD_OPTIONS:  # a method that takes no options
        return None
    names = [
        k
        for k, fields in SOLVER_FIELDS.items()
        if method in fields and k in sv and (method == sv["method"] or k in given)
    ]
    return METHOD_OPTIONS[method](**{SOLVER_FIELDS[k][method]: sv[k] for k in names})


def method_options(sv: Mapping[str, Any], given: Collection[str]) -> tuple[NewtonOptions, Any]:
    """Newton's options (the experiments' Newton uses them whatever ``solver.method``) and
    those of ``solver.method`` when it is not Newton's, from ``[solver]``; the given keys that
    only another method reads are checked too."""
    if sv.get("bs_rtol", 0) < 0:
        raise ConfigError(f"solver.bs_rtol must be >= 0, got {sv['bs_rtol']}")
    method = sv["method"]
    if method == "proximal-galerkin" and not sv["rtol"] > 0:
        raise ConfigError(
            "solver.rtol must be > 0 with solver.method = 'proximal-galerkin' (the "
            f"Newton iteration of each proximal step stops there), got {sv['rtol']}"
        )
    for other in METHOD_OPTIONS:
        if other not in (method, "newton"):
            alone = [k for k in given if list(SOLVER_FIELDS.get(k, ())) == [other]]
            solver_options(other, {**{k: sv[k] for k in alone}, "method": method}, alone)
    newton = solver_options("newton", sv, given)
    return newton, (None if method == "newton" else solver_options(method, sv, given))


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
