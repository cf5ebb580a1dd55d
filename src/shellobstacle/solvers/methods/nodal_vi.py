"""``active-set``, ``snes-vi``, ``proximal-galerkin``: the exact nodal variational
inequality (κ = 0, the constraint at the Lagrange nodes, docs/model.md §5)."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

from shellobstacle.messages import ConfigError
from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.result import ConvergenceError, MethodResult, Step
from shellobstacle.solvers.vi.options import (
    ActiveSetOptions,
    ProximalGalerkinOptions,
    SnesVIOptions,
)

__all__ = ["ActiveSetMethod", "NodalMethod", "ProximalGalerkinMethod", "SnesVIMethod"]

log = logging.getLogger(__name__)


class NodalMethod(MethodBase):
    """What the three solvers of the nodal problem share: one step with the KKT record, and
    the multiplier and contact pressure in the result's ``extra``."""

    name = ""
    penalized = False
    adaptive = False
    options_type: type | None = None
    summary = ""

    def solver(self, problem: Any, options: Any = None) -> Any:
        """The solver of this method on ``problem`` (its ``solve()`` returns a
        :class:`~shellobstacle.solvers.vi.nodal_qp.NodalResult`)."""
        raise NotImplementedError

    def solve(
        self,
        problem: Any,
        h: float,
        kappas: Sequence[float],
        options: Any,
    ) -> MethodResult:
        """Solve the nodal problem from ``problem.zeta``; a failure is reported in the
        result with the solver's last record."""
        log.info(
            f"h = {h:.4g}, {problem.num_dofs} dofs; the exact nodal problem (κ = 0) by {self.name}"
        )
        out = MethodResult()
        t0 = time.perf_counter()
        try:
            r = self.solver(problem, options).solve()
        except ConvergenceError as err:
            out.converged, out.error = False, str(err)
            r = err.result
            if r is None:  # failed before iterating: no record
                return out
        seconds = time.perf_counter() - t0
        rel = r.kkt.get("stationarity", math.nan)  # ‖Kζ − f − Bᵀλ‖ / ‖f‖
        norms = list(getattr(r, "residual_norms", []))
        out.steps = [
            Step(
                0.0, r.iterations, r.converged, r.reason, rel, seconds, norms, r.details(),
                self.name, r,
            )
        ]  # fmt: skip
        out.extra["multiplier"] = r.multiplier
        out.extra["contact_pressure"] = r.contact_pressure
        nodes = r.active_nodes
        log.info(f"{self.name}: {r.iterations} linear solves, {nodes} active nodes, KKT {r.kkt}")
        return out


class ActiveSetMethod(NodalMethod):
    """A soft-penalty path, then primal–dual active-set steps."""

    name = "active-set"
    adaptive = True
    options_type = ActiveSetOptions
    summary = "the exact nodal variational inequality by a primal–dual active-set method"

    def solver(self, problem: Any, options: ActiveSetOptions | None = None) -> Any:
        """:class:`~shellobstacle.solvers.vi.active_set.ActiveSetSolver` on ``problem``."""
        from shellobstacle.solvers.vi.active_set import ActiveSetSolver

        return ActiveSetSolver(problem, options)


class SnesVIMethod(NodalMethod):
    """PETSc's VI Newton methods on the bounds of the rotated unknowns."""

    name = "snes-vi"
    options_type = SnesVIOptions
    summary = "the same nodal problem by PETSc's VI Newton (reduced space or semismooth)"

    def solver(self, problem: Any, options: SnesVIOptions | None = None) -> Any:
        """:class:`~shellobstacle.solvers.vi.snes_vi.SnesVISolver` on ``problem``."""
        from shellobstacle.solvers.vi.snes_vi import SnesVISolver

        return SnesVISolver(problem, options)


class ProximalGalerkinMethod(NodalMethod):
    """Keith & Surowiec's latent-variable proximal point method."""

    name = "proximal-galerkin"
    options_type = ProximalGalerkinOptions
    summary = "the same nodal problem by Keith & Surowiec's latent-variable proximal point method"

    def options_from(self, values: Mapping[str, Any]) -> ProximalGalerkinOptions:
        """Its options from ``[solver]``; ``rtol`` (its Newton iteration's) must be > 0."""
        if "rtol" in values and not values["rtol"] > 0:
            raise ConfigError(
                f"solver.rtol must be > 0 with solver.method = {self.name!r} (the Newton "
                f"iteration of each proximal step stops there), got {values['rtol']}"
            )
        return super().options_from(values)

    def solver(self, problem: Any, options: ProximalGalerkinOptions | None = None) -> Any:
        """:class:`~shellobstacle.solvers.vi.proximal_galerkin.ProximalGalerkinSolver` on
        ``problem``."""
        from shellobstacle.solvers.vi.proximal_galerkin import ProximalGalerkinSolver

        return ProximalGalerkinSolver(problem, options)
