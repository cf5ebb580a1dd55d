"""Exact line search for convex piecewise-quadratic energies (docs/model.md §6).

Along a descent direction δ the restriction ``φ(t) = J_κ(u + tδ)`` of such an energy is
convex and piecewise quadratic, so ``φ'`` is monotone and piecewise linear; its root on
``[0, 1]`` is the exact minimizer. Regula falsi in its Illinois variant finds it: once no
kink is left inside the bracket the secant lands exactly on the root.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["exact_step", "piecewise_linear_root"]


def piecewise_linear_root(
    slope: Callable[[float], float],
    slope0: float,
    tol: float,
    max_evaluations: int = 60,
    interval_rtol: float = 1e-14,
) -> tuple[float, int]:
    """Root in ``[0, 1]`` of the monotone ``φ'`` with ``φ'(0) = slope0 < 0``.

    Args:
        slope: ``t ↦ φ'(t)``.
        slope0: ``φ'(0)`` (negative: δ is a descent direction).
        tol: accept ``t`` once ``|φ'(t)| ≤ tol``.
        max_evaluations: cap on evaluations of ``slope`` after ``φ'(1)``.
        interval_rtol: stop when the bracket is this small relative to its right end.

    Returns:
        ``(t, evaluations)``; ``t = 1`` when ``φ'(1) ≤ tol`` (the minimizer lies at or beyond
        the full step).
    """
    lo, f_lo = 0.0, slope0
    hi, f_hi = 1.0, slope(1.0)
    evaluations = 1
    if f_hi <= tol:
        return 1.0, evaluations
    t, side = hi, 0
    for _ in range(max_evaluations):
        t = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        if not lo < t < hi:
            t = 0.5 * (lo + hi)
        f = slope(t)
        evaluations += 1
        if abs(f) <= tol:
            break
        if f < 0:
            lo, f_lo = t, f
            if side == -1:  # Illinois: halve the stale end so both ends move
                f_hi *= 0.5
            side = -1
        else:
            hi, f_hi = t, f
            if side == 1:
                f_lo *= 0.5
            side = 1
        if hi - lo <= interval_rtol * hi:
            break
    return t, evaluations


def exact_step(
    g: np.ndarray,
    Md: np.ndarray,
    Bd: np.ndarray,
    curvature: float,
    slope0: float,
    noise: float,
    kappa: float,
    total: Callable[[float], float],
) -> tuple[float, int]:
    """The step length of a penalized energy along δ: the root in ``[0, 1]`` of

    ``φ'(t) = φ'_el(0) + t δᵀKδ + (1/κ) (Mδ)·min(g + t Bδ, 0)``

    with the gaps ``g``, ``Mδ`` and ``Bδ`` at the points that can be active on ``[0, 1]``,
    ``curvature = δᵀKδ`` and ``slope0 = φ'(0)``; ``|φ'| ≤ noise`` counts as zero. ``total``
    sums a point sum over the ranks (or returns it, for points every rank holds).
    """
    elastic0 = slope0 - total(float(np.dot(Md, np.minimum(g, 0.0)))) / kappa

    def slope(t: float) -> float:
        local = float(np.dot(Md, np.minimum(g + t * Bd, 0.0)))
        return elastic0 + t * curvature + total(local) / kappa

    return piecewise_linear_root(slope, slope0, max(1e-10 * abs(slope0), noise))
