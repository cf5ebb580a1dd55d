"""The normal component relaxed with the tangential ones held: a globalization of Newton's
method for the membrane model (docs/model.md §5–6).

In the membrane energy ζ_3 enters without derivatives: its block of ``K`` is a weighted mass
matrix (``a^{αβστ} b_στ b_αβ``), and so is the penalty's. A Newton step from an iterate whose
active set misses part of the contact zone (a start interpolated from a coarser mesh misses
its outer ring) treats the missed points as free: the full step pushes their ζ_3 deep into
the obstacle, the exact line search cuts it to ``t`` of 10⁻³–10⁻¹, and the next steps crawl.
Minimizing ``J_κ`` over ζ_3 alone at the full step puts those points back where the penalty
balances the load. That subproblem is strictly convex and piecewise quadratic like ``J_κ``,
and its Jacobian ``K_33 + (1/κ) M_{A,3}ᵀ diag(1/D_A) M_{A,3}`` is mass-like: conjugate
gradients with its diagonal take a few dozen iterations, and one of its Newton steps costs
about a quarter of a whole Newton step; a relaxation takes a few of them.

:class:`NormalRelaxation` solves it by the same semismooth Newton with the exact line search of
:class:`~shellobstacle.solvers.newton.system.PenalizedSystem`;
:class:`~shellobstacle.solvers.newton.solver.NewtonSolver` keeps the relaxed full step instead
of the cut one when its energy is lower.
From the coarser level's solution the finer level then takes a few Newton steps, where
without it the crawl takes several times as many (docs/perf/multigrid.md).
"""

from __future__ import annotations

from mpi4py import MPI  # noqa: F401  (MPI before PETSc)
from petsc4py import PETSc

import numpy as np

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.system import PenalizedSystem
from shellobstacle.solvers.quadrature_penalty import penalty_factor

__all__ = ["RELAX_BELOW", "NormalRelaxation", "require_membrane"]

#: a Newton step whose exact line search gives ``t`` below this is relaxed
RELAX_BELOW = 0.5


def require_membrane(problem: PenalizedProblem, key: str = "normal_relaxation") -> None:
    """Raise ValueError unless ``problem`` is the membrane model, whose energy has no
    derivatives of ζ_3 (the relaxation's premise); the message names ``key``, the option
    that asked for it (the Newton option, or ``solver.nested_iteration``, which relaxes)."""
    if problem.model != "membrane":
        raise ValueError(
            f"{key} relaxes zeta_3 alone, which needs the membrane model (its energy has no "
            f"derivatives of zeta_3), not {problem.model}: switch {key} off"
        )


class NormalRelaxation:
    """``min J_κ`` over ζ_3 with ζ_1, ζ_2 held, from the system's current iterate.

    Args:
        system: the membrane problem's system (three components per node, interleaved).
        rtol: stop when ``‖R_3‖ ≤ rtol ‖R‖`` (the normal residual against the whole one).
        max_steps: the most Newton steps on ζ_3 per relaxation.
    """

    def __init__(self, system: PenalizedSystem, rtol: float = 1e-2, max_steps: int = 12) -> None:
        self.system, self.rtol, self.max_steps = system, rtol, max_steps
        K = system.K
        comm = K.getComm()
        lo, hi = K.getOwnershipRange()
        rows = np.arange(lo, hi, dtype=PETSc.IntType)
        self._local = np.flatnonzero(rows % 3 == 2)  # ζ_3's owned positions
        self._normal = PETSc.IS().createGeneral(rows[self._local], comm=comm)
        self.K33 = K.createSubMatrix(self._normal, self._normal)
        self.J = self.K33.duplicate(copy=True)
        self.b, self.x = self.J.createVecs()
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setType("cg")
        self.ksp.getPC().setType("jacobi")
        self.ksp.setTolerances(rtol=1e-8, max_it=1000)

    def relax(self) -> int:
        """Newton steps on ζ_3 until ``‖R_3‖ ≤ rtol ‖R‖`` (at most ``max_steps``); the
        system's iterate and residual follow. Returns the steps taken."""
        system, comm = self.system, self.system.comm
        taken = 0
        for _ in range(self.max_steps):
            R3 = system.R.array_r[self._local]  # R holds R(ζ) after a move
            normal = np.sqrt(comm.allreduce(float(R3 @ R3)))
            if normal <= self.rtol * system.residual_norm():
                break
            self._jacobian()
            self.b.array[:] = -R3
            self.ksp.solve(self.b, self.x)
            if self.ksp.getConvergedReason() < 0:
                break
            system.dz.set(0.0)
            system.dz.array[self._local] = self.x.array_r
            system.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            slope0 = system.R.dot(system.dz)  # φ'(0) = R(ζ)·δ < 0
            if not slope0 < 0:
                break
            t, _ = system.line_search(slope0, 0.0)
            system.move(t, False)
            taken += 1
        return taken

    def full_step(self, t: float) -> bool:
        """After a Newton step cut to ``t < 1``: move to the full step ``ζ + (1 − t)δ`` and
        relax ζ_3 there; keep it if ``J_κ`` is lower than at the cut step, else go back.
        Returns whether it was kept."""
        system = self.system
        cut_energy = system.energy()
        cut = system.zeta.copy()
        system.move(1.0 - t, False)  # from the line search's Kδ and Bδ
        self.relax()
        kept = system.energy() < cut_energy
        if not kept:
            cut.copy(system.zeta)
            system.problem.zeta.x.scatter_forward()
            system.residual()
        cut.destroy()
        return kept

    def _jacobian(self) -> None:
        """``J ← K_33 + (1/κ) M_{A,3}ᵀ diag(1/D_A) M_{A,3}`` at the current active points."""
        system = self.system
        self.K33.copy(self.J, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        active = np.flatnonzero(system.g < 0)
        if system.comm.allreduce(active.size):
            # the factor S of the penalty Hessian SᵀS at the active rows, then its ζ_3 columns
            S = penalty_factor(system.penalty.M, system.penalty.D, active, system.kappa)
            lo, hi = S.getOwnershipRange()
            rows = PETSc.IS().createStride(hi - lo, lo, 1, comm=system.comm)
            S3 = S.createSubMatrix(rows, self._normal)
            H = S3.transposeMatMult(S3)
            self.J.axpy(1.0, H, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            for obj in (H, S3, rows, S):
                obj.destroy()
        self.ksp.setOperators(self.J)

    def destroy(self) -> None:
        """Free the PETSc objects."""
        for obj in (self.ksp, self.J, self.b, self.x, self.K33, self._normal):
            obj.destroy()
