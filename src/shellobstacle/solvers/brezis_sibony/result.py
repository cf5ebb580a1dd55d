"""What a run of the Brezis–Sibony iteration (:mod:`shellobstacle.solvers.brezis_sibony.iteration`)
did:
its stopping reason, its step and the contraction bound it guarantees, the contraction it
observed, and the increments' history."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

__all__ = ["BrezisSibonyResult"]


@dataclass
class BrezisSibonyResult:
    """What a Brezis–Sibony run did.

    Attributes:
        converged: a stopping criterion was met (``False`` at the iteration cap or on
            divergence; the last iterate is in ``problem.zeta`` either way).
        iterations: number of steps (38) taken.
        reason: why it stopped.
        xi: ``Ξ = τ / h⁴``.
        tau: the step ``τ``.
        lambda_max: largest eigenvalue of ``(K + P_all) v = λ M v`` (NaN if not estimated).
        lambda_min: smallest eigenvalue of ``K v = λ M v`` (NaN if not estimated).
        contraction_bound: ``max(|1 − τ λ_min|, |1 − τ λ_max|)``, the guaranteed contraction
            of error and increments per step in the (``M``-)L² norm.
        contraction_factor: observed, over the whole run: the geometric mean of the ratios of
            successive L² increments, ``(Δ_n / Δ_1)^{1/(n−1)}``.
        contraction_factor_tail: the same over the last ``options.tail`` steps (the
            asymptotic rate).
        max_ratio: the largest ratio ``Δ_{k+1} / Δ_k`` over the run (all steps, not thinned).
        increments: ``Δ_k = ‖ψ_k − ψ_{k−1}‖_{L²}`` for ``k = 1, 1 + stride, 1 + 2 stride, …``.
        increment_stride: the ``stride`` of ``increments``.
        relative_increment: the last ``Δ_k / ‖ψ_{k−1}‖_{L²}``.
        relative_residual: ``‖R(ψ)‖ / ‖R(0)‖`` at the returned iterate.
        error_estimate: a posteriori bound ``ρ/(1 − ρ) Δ_n`` of ``‖ψ_n − ζ_κ^h‖_{L²}``.
        seconds: wall time of
            :meth:`~shellobstacle.solvers.brezis_sibony.iteration.BrezisSibonySolver.solve` (setup
            included).
        setup_seconds: the part spent on the spectrum estimate and the start.
    """

    converged: bool
    iterations: int
    reason: str
    xi: float
    tau: float
    lambda_max: float = math.nan
    lambda_min: float = math.nan
    contraction_bound: float = math.nan
    contraction_factor: float = math.nan
    contraction_factor_tail: float = math.nan
    max_ratio: float = math.nan
    increments: list[float] = field(default_factory=list)
    increment_stride: int = 1
    relative_increment: float = math.nan
    relative_residual: float = math.nan
    error_estimate: float = math.nan
    seconds: float = 0.0
    setup_seconds: float = 0.0

    def as_dict(self, history: bool = False) -> dict[str, Any]:
        """JSON-friendly record (the increment history only if ``history``)."""
        out = {k: v for k, v in self.__dict__.items() if k != "increments"}
        if history:
            out["increments"] = list(self.increments)
        return out
