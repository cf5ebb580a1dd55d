"""One MUMPS factorization per κ, reused by conjugate gradients at the κ's later steps.

The Jacobians of one κ differ only where the active set moved, each moved point a rank-one
change: conjugate gradients preconditioned with the factorization of the κ's first Jacobian
converge in a few iterations, and a new factorization is made only when more points moved
than CG may iterate, or CG does not converge in that many iterations (a fixed budget, not a
timing, so that the iterates do not depend on the machine's speed).
"""

from __future__ import annotations

import time

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx and PETSc)
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers.base import factorization_pc, unique_prefix
from shellobstacle.solvers.linear import LinearSolveError, active_changes
from shellobstacle.solvers.newton.system import PenalizedSystem

__all__ = ["REUSE_MAX_ITERATIONS", "DirectStrategy"]

#: CG iterations (and points that changed activity) allowed with a kept factorization: about
#: the cost of one factorization in back-substitutions on 1e5–1e6 dofs
REUSE_MAX_ITERATIONS = 15


class DirectStrategy:
    """Newton directions by MUMPS (``factorization``: ``"cholesky"`` or ``"lu"``).

    Args:
        factorization: of the Jacobian.
        rtol: relative tolerance of the CG that reuses a factorization.
        reuse: ``False`` factorizes every Jacobian (plain Newton: a reference in tests).
        reuse_max_iterations: CG's budget with a kept factorization.
    """

    predicts = True

    def __init__(
        self,
        factorization: str = "cholesky",
        rtol: float = 1e-12,
        reuse: bool = True,
        reuse_max_iterations: int = REUSE_MAX_ITERATIONS,
    ) -> None:
        if reuse_max_iterations < 1:
            raise ValueError(f"reuse_max_iterations must be >= 1, got {reuse_max_iterations}")
        self.factorization = factorization
        self.rtol = rtol
        self.reuse = reuse
        self.budget = reuse_max_iterations
        self.factorizations = 0
        self.reuse_failures = 0
        self._factored_kappa: float | None = None  # κ of the factorization held
        self._factored_active = np.zeros(0, dtype=bool)  # its active points

    def attach(self, system: PenalizedSystem, timings: dict[str, float]) -> None:
        """The KSP (preonly, or CG when reusing) with a MUMPS factorization as its PC."""
        self.system, self.timings = system, timings
        self.ksp = ksp = PETSc.KSP().create(system.comm)
        ksp.setOptionsPrefix(unique_prefix("newton"))
        pc = ksp.getPC()
        factorization_pc(pc, self.factorization)
        if self.reuse:
            # the factorization stays that of an earlier Jacobian until _factorize
            pc.setReusePreconditioner(True)
            ksp.setType("cg")
            ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
            ksp.setTolerances(rtol=self.rtol, atol=0.0, max_it=self.budget)
            ksp.setInitialGuessNonzero(False)
        else:
            ksp.setType("preonly")
        ksp.setFromOptions()
        system.on_new_jacobian = self._new_jacobian

    def _new_jacobian(self, A: PETSc.Mat) -> None:
        if self.factorization == "cholesky":
            A.setOption(PETSc.Mat.Option.SPD, True)
        self.ksp.setOperators(A)

    def begin(self) -> None:
        """Every solve starts with a new factorization: its result depends only on its start."""
        self._factored_kappa = None
        self.factorizations = 0
        self.reuse_failures = 0

    def refresh(self) -> None:
        """Nothing built from the penalty's values is kept past :meth:`begin` (the Jacobian's
        analysis, its pattern's, is kept)."""

    def reduced(self, floor_factor: float) -> None:
        """No smaller model: every step is a full one."""
        return None

    def _factorize(self) -> None:
        """Factorize the current Jacobian (kept for the later steps of this κ)."""
        t0 = time.perf_counter()
        pc = self.ksp.getPC()
        pc.setReusePreconditioner(False)
        pc.setUp()  # the numeric factorization (the symbolic one is kept)
        pc.setReusePreconditioner(self.reuse)
        self._factored_kappa = self.system.kappa
        self._factored_active = self.system.g < 0
        self.factorizations += 1
        self.timings["factorize"] += time.perf_counter() - t0

    def direction(self, history: list[float], target: float) -> int:
        """``δ ← J⁻¹(−R)``: CG preconditioned by the kept factorization of this κ, or a new
        factorization (when none is kept, too many points moved, or CG ran out)."""
        system = self.system
        ta = time.perf_counter()
        system.jacobian()
        self.timings["assemble"] += time.perf_counter() - ta
        system.negate_residual()
        ts, factorize0 = time.perf_counter(), self.timings["factorize"]
        if not self.reuse:
            self._factorize()
            self.ksp.solve(system.R, system.dz)
            self._factored_kappa = system.kappa
        else:
            if self._factored_kappa is None or self._moved() > self.budget:
                self._factorize()
            self.ksp.solve(system.R, system.dz)
            if self.ksp.getConvergedReason() < 0:
                self.reuse_failures += 1
                self._factorize()
                self.ksp.solve(system.R, system.dz)
        system.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        self.timings["solve"] += time.perf_counter() - ts - (self.timings["factorize"] - factorize0)
        iterations = self.ksp.getIterationNumber()
        if self.ksp.getConvergedReason() < 0:
            raise LinearSolveError(
                f"linear solver failed (PETSc reason {self.ksp.getConvergedReason()})", iterations
            )
        return iterations

    def _moved(self) -> int:
        """Points that changed activity since the factorization (collective)."""
        return active_changes(self.system.comm, self._factored_active, self.system.g < 0)

    def tangent(self, b: PETSc.Vec) -> bool:
        """``δ ← J⁻¹ b`` at the current iterate with the kept factorization of this κ (CG
        preconditioned by it when reusing); False when none is kept for this κ."""
        system = self.system
        if self._factored_kappa != system.kappa:
            return False
        if self.reuse:  # the Jacobian at ζ for the CG that reuses the factorization
            system.jacobian()
        self.ksp.solve(b, system.dz)
        return self.ksp.getConvergedReason() > 0
