"""The nonlinear Koiter shell against its obstacle (docs/model.md §11.3): the load stepped to
1 at the first κ of the penalty ladder, then the ladder continued at load 1.

At the first (largest) κ the penalty is softest: :class:`~.load_stepping.LoadStepping` follows
the load path with the contact it meets; each later κ is Newton's
(:class:`~.newton.EnergyNewton`) from the previous κ's ``ζ``, as the linear continuation.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Sequence

from shellobstacle.solvers.nonlinear.load_stepping import LoadStepping
from shellobstacle.solvers.nonlinear.newton import Energy, EnergyNewton, NewtonRecord
from shellobstacle.solvers.result import ConvergenceError, MethodResult, Step

__all__ = ["solve_in_contact"]

logger = logging.getLogger(__name__)


def _step(
    kappa: float, record: NewtonRecord, load: float, seconds: float, **details: object
) -> Step:
    """The summary's row of one κ: the relative residual is ``‖R‖ / ‖f‖`` (``load``)."""
    norms = record.norms
    relative = norms[-1] / load if load > 0 else 0.0
    return Step(kappa, record.iterations, True, "residual below rtol", relative, seconds,
                list(norms), {"energy": record.energy, **details})  # fmt: skip


def solve_in_contact(problem: Energy, kappas: Sequence[float], rtol: float = 1e-9) -> MethodResult:
    """Load stepping to 1 at ``kappas[0]``, then Newton at each later κ (``problem``: a
    :class:`~shellobstacle.models.nonlinear_koiter.NonlinearKoiterProblem` with a penalty).

    Returns:
        One step per κ (the first's iterations summed over the load steps) and, in
        ``extra["load_path"]``, the load steps (``steps``: one record per accepted step) and
        their ``cuts``; a failure (a limit point included) ends it, reported as not
        converged with its one-line message.
    """
    out = MethodResult()
    newton = EnergyNewton(problem, rtol=rtol, max_it=25)
    stepping = LoadStepping(problem, newton=newton)
    problem.set_kappa(kappas[0])
    t = time.perf_counter()
    try:
        path = stepping.solve(1.0)
    except ConvergenceError as err:
        path = getattr(err, "path", stepping.path)
        out.converged, out.error = False, str(err)
    out.extra["load_path"] = {
        "steps": [dataclasses.asdict(step) for step in path.steps] if path else [],
        "cuts": path.cuts if path else 0,
    }
    if not out.converged:
        out.steps.append(Step(kappas[0], 0, False, out.error or "", math.nan, 0.0))
        return out
    record = NewtonRecord(
        sum(s.newton_iterations for s in path.steps), energy=path.steps[-1].energy
    )
    record.norms = [newton.residual()]  # at s = 1
    load, seconds = newton.f.norm(), time.perf_counter() - t
    out.steps.append(_step(kappas[0], record, load, seconds, load_steps=len(path.steps) - 1))
    for kappa in kappas[1:]:
        problem.set_kappa(kappa)
        t = time.perf_counter()
        try:
            record = newton.solve()
        except ConvergenceError as err:
            out.converged, out.error = False, f"κ = {kappa:.3g}: {err}"
            out.steps.append(Step(kappa, 0, False, str(err), math.nan, time.perf_counter() - t))
            return out
        logger.info(
            "κ = %.3g: %d Newton steps, energy %.6e", kappa, record.iterations, record.energy
        )
        out.steps.append(_step(kappa, record, load, time.perf_counter() - t))
    return out
