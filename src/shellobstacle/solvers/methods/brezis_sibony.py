"""``brezis-sibony``: the paper's iteration (38) at the target κ."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

from shellobstacle.messages import ConfigError
from shellobstacle.solvers.brezis_sibony.options import BrezisSibonyOptions
from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.result import MethodResult, Step

__all__ = ["BrezisSibonyMethod"]

log = logging.getLogger(__name__)


class BrezisSibonyMethod(MethodBase):
    """:class:`~shellobstacle.solvers.brezis_sibony.iteration.BrezisSibonySolver` at the last
    κ of the ladder (no continuation); reaching its iteration cap is reported, not raised."""

    name = "brezis-sibony"
    penalized = True
    adaptive = False
    options_type = BrezisSibonyOptions
    summary = "the penalized problem at the target κ by the paper's iteration (38)"

    def options_from(self, values: Mapping[str, Any]) -> BrezisSibonyOptions:
        """Its options from ``[solver]``; a negative ``bs_rtol`` is named by its key."""
        if values.get("bs_rtol", 0) < 0:
            raise ConfigError(f"solver.bs_rtol must be >= 0, got {values['bs_rtol']}")
        return super().options_from(values)

    def solve(
        self,
        problem: Any,
        h: float,
        kappas: Sequence[float],
        options: BrezisSibonyOptions | None,
    ) -> MethodResult:
        """The iteration (38) at ``kappas[-1]`` from ``options.start``."""
        from shellobstacle.solvers.brezis_sibony.iteration import BrezisSibonySolver

        kappa = kappas[-1]
        log.info(
            f"h = {h:.4g}, {problem.num_dofs} dofs; solving for 1 value of κ = {kappa:.3e} "
            "by Brezis–Sibony (no continuation)"
        )
        problem.set_kappa(kappa)
        solver = BrezisSibonySolver(problem, h, options)

        def progress(k: int, increment: float) -> None:
            log.info(f"Brezis–Sibony step {k}: ‖ψ_k − ψ_(k−1)‖_L² = {increment:.3e}")

        r = solver.solve(progress)
        details = r.as_dict()
        for key in ("converged", "iterations", "reason", "relative_residual"):
            details.pop(key, None)
        step = Step(
            kappa, r.iterations, r.converged, r.reason, r.relative_residual, r.seconds, [],
            details, self.name, r,
        )  # fmt: skip
        log.info(
            f"Brezis–Sibony: {r.iterations} steps, {r.reason}; contraction observed "
            f"{r.contraction_factor:.6f}, bound {r.contraction_bound:.6f}"
        )
        if not r.converged:
            return MethodResult([step], False, f"Brezis–Sibony did not converge: {r.reason}")
        return MethodResult([step])
