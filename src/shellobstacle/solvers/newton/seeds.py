"""The first active set of a solve that starts without contact, from a coarse-grid step.

From an iterate without contact the Jacobian is ``K``: the Newton step overshoots into the
obstacle, the line search cuts it short, and the active set then grows over many damped
steps. The direct and the iterative solvers instead take their first step to the minimizer of
the model whose active points are those that a cheap approximation of that step penetrates
(the seed): ``ζ + δ̃``, ``δ̃`` the Galerkin approximation of ``K⁻¹(−R(ζ))`` on a coarse
background grid (:class:`~shellobstacle.solvers.newton.coarse_space.CoarseSpace`; its P1 hat
functions
for the membrane, C¹ quadratic B-splines for Koiter's bending energy). The exact line
search guards the seeded step, and one that does not descend is replaced by the usual Newton
step. It saves the first κ a few Newton steps, more on larger meshes (docs/performance.md).
"""

from __future__ import annotations

import time

import numpy as np

from shellobstacle.solvers.newton.coarse_space import CoarseSpace
from shellobstacle.solvers.newton.system import PenalizedSystem

__all__ = ["coarse_penetration"]


def coarse_penetration(system: PenalizedSystem, timings: dict[str, float]) -> np.ndarray:
    """The owned points that ``ζ + δ̃`` penetrates, ``δ̃`` the coarse-grid approximation of
    the Newton step ``K⁻¹(−R(ζ))`` at an iterate without contact (overwrites ``system.dz``).
    """
    t0 = time.perf_counter()
    problem = system.problem
    coarse = CoarseSpace(problem.V, system.K, problem.bcs, smooth=problem.model == "koiter")
    r = system.R.copy()
    r.scale(-1.0)
    coarse.solve(r, system.dz)
    hint = system.penetrated_by_full_step()
    r.destroy()
    coarse.destroy()
    timings["coarse"] = timings.get("coarse", 0.0) + time.perf_counter() - t0
    return hint
