"""The options of ``[solver]``'s non-Newton methods and of ``[adapt]``, built from the
resolved config and checked against each other (:mod:`shellobstacle.config.loader` calls them)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.messages import ConfigError
from shellobstacle.solvers.options import (
    ActiveSetOptions,
    BrezisSibonyOptions,
    ProximalGalerkinOptions,
    SnesVIOptions,
)
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import PenaltySpec, Shell

__all__ = ["adapt_options", "method_options"]


def method_options(sv: Mapping[str, Any]) -> Any:
    """The options of ``solver.method`` when it is not Newton's, from ``[solver]``; the keys
    of Brezis–Sibony and proximal Galerkin are checked whichever method is chosen."""
    if sv["bs_rtol"] < 0:
        raise ConfigError(f"solver.bs_rtol must be >= 0, got {sv['bs_rtol']}")
    method = sv["method"]
    brezis_sibony = {"xi": sv.get("xi"), "mass": sv["mass"], "start": sv["start"]}
    BrezisSibonyOptions(**brezis_sibony)
    proximal = {"tol": sv["proximal_tol"], "alpha_max": sv["proximal_alpha_max"]}
    ProximalGalerkinOptions(**proximal)
    if method == "brezis-sibony":
        return BrezisSibonyOptions(
            **brezis_sibony, max_iterations=sv["bs_max_iterations"], rtol=sv["bs_rtol"]
        )
    if method == "active-set":
        return ActiveSetOptions(max_iterations=sv["max_iterations"])
    if method == "snes-vi":
        return SnesVIOptions(
            vi_type=sv["vi_type"],
            line_search=sv["vi_line_search"],
            rtol=sv["rtol"],
            stol=sv["stol"],
            max_iterations=sv["max_iterations"],
            factorization=sv["factorization"],
        )
    if method == "proximal-galerkin":
        if not sv["rtol"] > 0:
            raise ConfigError(
                "solver.rtol must be > 0 with solver.method = 'proximal-galerkin' (the "
                f"Newton iteration of each proximal step stops there), got {sv['rtol']}"
            )
        return ProximalGalerkinOptions(
            **proximal,
            newton_rtol=sv["rtol"],
            max_iterations=sv["max_iterations"],
            factorization=sv["factorization"],
        )
    return None


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
