"""Inexact Newton with flexible CG and a block Gauss–Seidel field split, GAMG on ζ_α.

ζ_3 enters the membrane strain without derivatives: its block of the Jacobian is a
penalty-augmented mass matrix, for which Jacobi is enough, and algebraic multigrid works on
the ζ_α block alone; the CG iterations then hardly grow with ``ε/κ``. One forward sweep per
iteration (a V-cycle on ζ_α, then Jacobi on ζ_3 with the residual updated) is not symmetric,
so the Krylov method is flexible CG keeping four earlier directions (PETSc's FCG).

GAMG's hierarchy is kept across Newton steps and across κ while the Jacobian's ζ_α diagonal
stays within :data:`MULTIGRID_DRIFT` of its values at the build: its smoothers keep that
diagonal and their Chebyshev bounds. A solve with the kept hierarchy that fails, or needs
more than :data:`KEPT_ITERATION_FACTOR` times the most iterations of a solve since the build,
is repeated with a new one. The split keeps its diagonal blocks instead of extracting them at
every set-up: the ζ_α block is refreshed at a build only, the ζ_3 block gets the current
diagonal (what Jacobi reads).

CG stops at ``‖J δ + R‖ ≤ η ‖R‖``. A direction whose full step keeps the active set
(``g + Bδ < 0`` where ``g < 0``, nowhere else) is *finished*: CG goes on from ``δ`` to
Newton's stopping threshold. Along it ``J_κ`` is then Newton's quadratic model, so the step
ends the solve, as the direct path's exact step does. Until then, while the active set still
moves, every direction is solved to ``η = 0.1``: a tighter solve of a model whose active set
is about to change buys nothing. A solve that starts from an iterate with contact (a
continuation's next κ) takes its first step with :data:`WARM_FORCING`: from the previous
solution exact steps converge in 2–4 steps, while a loose first step sets off a string of
inexact ones. Without finishing, the forcing terms are Eisenstat and Walker's choice 2 (SIAM
J. Sci. Comput. 17, 1996), ``η_k = 0.9 (‖R_k‖ / ‖R_{k−1}‖)²``, safeguarded, at most 0.1.
Either way ``η`` is never below the tolerance nor below what Newton's stopping test can
still see.
"""

from __future__ import annotations

import time

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers.base import set_options, unique_prefix
from shellobstacle.solvers.linear import LinearSolveError
from shellobstacle.solvers.newton.seeds import coarse_penetration
from shellobstacle.solvers.newton.system import PenalizedSystem

__all__ = [
    "KEPT_ITERATION_FACTOR",
    "KEPT_MIN_ITERATIONS",
    "MULTIGRID_DRIFT",
    "WARM_FORCING",
    "IterativeStrategy",
]

#: the first forcing term of a solve from an iterate with contact
WARM_FORCING = 1e-4
#: how far the Jacobian's ζ_α diagonal may move (relative, at any dof) before GAMG is rebuilt
MULTIGRID_DRIFT = 0.05
#: a solve with a kept hierarchy is given up after this factor times the most iterations of a
#: solve since the build (at least KEPT_MIN_ITERATIONS) and repeated with a new hierarchy
KEPT_ITERATION_FACTOR = 4
KEPT_MIN_ITERATIONS = 50
FORCINGS = ("eisenstat-walker", "fixed")

_SPLIT = {
    "pc_type": "fieldsplit",
    "pc_fieldsplit_type": "multiplicative",
    "pc_fieldsplit_block_size": 3,
    "pc_fieldsplit_0_fields": "0,1",
    "pc_fieldsplit_1_fields": "2",
    "fieldsplit_0_ksp_type": "preonly",
    "fieldsplit_0_pc_type": "gamg",
    "fieldsplit_0_pc_gamg_threshold": 0.02,
    # Chebyshev–Jacobi smoothing, the same on any number of ranks
    "fieldsplit_0_mg_levels_pc_type": "jacobi",
    "fieldsplit_1_ksp_type": "preonly",
    "fieldsplit_1_pc_type": "jacobi",
    # four kept directions: as few iterations as thirty, less orthogonalization
    "ksp_fcg_mmax": 4,
}


class IterativeStrategy:
    """Newton directions by flexible CG with the field split (module docstring).

    Args:
        rtol: the smallest forcing term (and the tolerance of every solve with ``"fixed"``).
        forcing: ``"eisenstat-walker"`` (inexact Newton) or ``"fixed"`` (every direction to
            ``rtol``: the iterations per step then measure the preconditioner alone).
        seed: take a solve's first step from an iterate without contact towards the seeded
            model (:mod:`~shellobstacle.solvers.newton.seeds`).
        finish: continue a direction whose full step keeps the active set to Newton's
            stopping threshold, the others solved to ``η_max = 0.1`` (False: Eisenstat–Walker's
            terms; ``"eisenstat-walker"`` forcing only).
    """

    predicts = False

    def __init__(
        self,
        rtol: float = 1e-12,
        forcing: str = "eisenstat-walker",
        seed: bool = True,
        finish: bool = True,
    ) -> None:
        if forcing not in FORCINGS:
            raise ValueError(f"forcing must be one of {FORCINGS}, got {forcing!r}")
        self.rtol, self.forcing, self.seed = rtol, forcing, seed
        self.finish = finish and forcing == "eisenstat-walker"
        self.factorizations = 0
        self.multigrid_builds = 0
        self.finished = 0  # directions continued to Newton's threshold
        self._eta: float | None = None  # the last forcing term
        self._split: list[PETSc.KSP] | None = None  # the split's solvers, after a set-up
        self._blocks: tuple[PETSc.IS, PETSc.Mat, PETSc.Mat, PETSc.Vec] | None = None
        self._multigrid_diagonal: np.ndarray | None = None  # ζ_α diagonal at the build
        self._multigrid_most = 0  # the most iterations of a solve since the build
        self._rejected = 0  # iterations of a solve repeated with a new hierarchy

    def attach(self, system: PenalizedSystem, timings: dict[str, float]) -> None:
        """Flexible CG with the split's options under a prefix of its own."""
        self.system, self.timings = system, timings
        system.incremental = True
        self.ksp = ksp = PETSc.KSP().create(system.comm)
        prefix = unique_prefix("newton")
        ksp.setOptionsPrefix(prefix)
        ksp.setType("fcg")
        set_options(self, prefix, _SPLIT)
        # ‖J δ + R‖ itself, the quantity the forcing term bounds
        ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
        ksp.setTolerances(rtol=self.rtol, atol=1e-50, max_it=2000)
        ksp.setFromOptions()  # (the options stay: the levels are made at every set-up)
        system.on_new_jacobian = ksp.setOperators

    def begin(self) -> None:
        """A new solve: its first forcing term is chosen afresh."""
        self._eta = None

    def refresh(self) -> None:
        """The kept GAMG hierarchy was built from Jacobians of the old penalty: the next
        direction builds it again, as a new solver's first would."""
        self._multigrid_diagonal = None

    def reduced(self, floor_factor: float) -> None:
        """No smaller model: every step is a full one."""
        return None

    def tangent(self, b: PETSc.Vec) -> bool:
        """No prediction (the warm first step is solved tightly instead)."""
        return False

    # -- a direction --------------------------------------------------------------------------
    def direction(self, history: list[float], target: float) -> int:
        """``δ ← J⁻¹(−R)`` to the forcing term's accuracy; a solve's first step from an
        iterate without contact goes towards the seeded model instead, if that descends."""
        system = self.system
        seed = self._seed() if len(history) == 1 else None
        ta = time.perf_counter()
        system.jacobian(seed)
        self.timings["assemble"] += time.perf_counter() - ta
        self.ksp.setTolerances(rtol=self._forcing(history, target))
        ts = time.perf_counter()
        system.negate_residual()
        earlier = 0  # CG iterations of a solve discarded or continued
        if seed is None:
            self._solve(system.R)
            if self.finish:
                earlier = self._finish(history[-1], target)
        else:
            earlier = self._seeded(seed)
        system.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        self.timings["solve"] += time.perf_counter() - ts
        iterations = self.ksp.getIterationNumber() + earlier + self._rejected
        self._rejected = 0
        if self.ksp.getConvergedReason() < 0:
            raise LinearSolveError(
                f"linear solver failed (PETSc reason {self.ksp.getConvergedReason()})", iterations
            )
        return iterations

    def _forcing(self, norms: list[float], target: float) -> float:
        """The relative tolerance ``η_k`` of the next direction.

        ``η_max = 0.1`` with finishing (:meth:`_finish` tightens it), else Eisenstat–Walker
        choice 2, ``η_k = γ (‖R_k‖/‖R_{k−1}‖)^α`` with ``γ = 0.9``, ``α = 2``, kept above
        ``γ η_{k−1}^α`` when that exceeds 0.1 (no sudden drop), at most ``η_max``; the first
        ``η`` of a cold start is ``η_max``, of a start with contact :data:`WARM_FORCING`; at
        least ``target / (2 ‖R_k‖)`` (a linear residual below half the stopping threshold is
        invisible to Newton's test) and at least ``rtol``.
        """
        if self.forcing == "fixed":
            return self.rtol
        gamma, alpha, eta_max = 0.9, 2.0, 0.1
        eta = eta_max
        if len(norms) == 1 and self.system.contact():
            eta = WARM_FORCING
        if len(norms) >= 2 and self._eta is not None and norms[-2] > 0.0 and not self.finish:
            eta = gamma * (norms[-1] / norms[-2]) ** alpha
            previous = gamma * self._eta**alpha
            if previous > 0.1:
                eta = max(eta, previous)
            eta = min(eta, eta_max)
        if norms[-1] > 0.0:
            eta = max(eta, 0.5 * target / norms[-1])
        self._eta = min(max(eta, self.rtol), eta_max)
        return self._eta

    def _finish(self, rnorm: float, target: float) -> int:
        """If the full step along the inexact ``δ`` keeps the active set (along it ``J_κ`` is
        then Newton's quadratic model), CG goes on from ``δ`` to Newton's stopping threshold
        (``rnorm``: ``‖R‖``), so that the step ends the solve. Returns the CG iterations of
        the first solve (0: not continued). Collective."""
        system = self.system
        if self.ksp.getConvergedReason() <= 0 or rnorm == 0.0:
            return 0
        eta = max(self.rtol, 0.5 * target / rnorm)
        if eta >= self._eta:
            return 0
        active = system.g < 0
        after = system.penetrated_by_full_step()
        if not system.comm.allreduce(bool(np.array_equal(active, after)), op=MPI.LAND):
            return 0
        iterations = self.ksp.getIterationNumber()
        self.ksp.setTolerances(rtol=eta)
        self.ksp.setInitialGuessNonzero(True)
        try:
            self._solve(system.R)
        finally:
            self.ksp.setInitialGuessNonzero(False)
        self._eta = eta
        self.finished += 1
        return iterations

    # -- the seeded first step ----------------------------------------------------------------
    def _seed(self) -> np.ndarray | None:
        """Gaps for the first Jacobian: ``−1`` where the coarse step penetrates (None: the
        usual step; with contact, without a coarse penetration, or not asked)."""
        system = self.system
        if not self.seed or system.contact():
            return None
        hint = coarse_penetration(system, self.timings)
        if not system.comm.allreduce(bool(hint.any()), op=MPI.LOR):
            return None
        return np.where(hint, -1.0, system.g)

    def seeded_gradient(self, seed: np.ndarray) -> PETSc.Vec:
        """``−∇q_Ã(ζ) = −R(ζ) − (1/κ) Mᵀ (χ_Ã g)``: minus the gradient of the model whose
        active points are the seed's ``Ã`` (``R`` holds ``−R``, which has no penalty part at
        an iterate without contact)."""
        system = self.system
        b = system.R.copy()
        system.penalty.add_residual(-np.where(seed < 0, system.g, 0.0), system.kappa, b)
        return b

    def _seeded(self, seed: np.ndarray) -> int:
        """``δ ← −(K + P_Ã)⁻¹ ∇q_Ã``, the step to the seeded model's minimizer (the Jacobian
        holds ``P_Ã``); if it is not a descent direction of ``J_κ`` (or CG failed), the usual
        Newton step instead. Returns the CG iterations of a discarded seeded solve."""
        system = self.system
        b = self.seeded_gradient(seed)
        self._solve(b)
        b.destroy()
        if self.ksp.getConvergedReason() > 0 and system.R.dot(system.dz) > 0:  # −R·δ > 0
            return 0
        discarded = self.ksp.getIterationNumber()
        ta = time.perf_counter()
        system.jacobian()
        self.timings["assemble"] += time.perf_counter() - ta
        self._solve(system.R)
        return discarded

    # -- the split and its kept hierarchy ------------------------------------------------------
    def _solve(self, b: PETSc.Vec) -> None:
        """``δ ← A⁻¹ b`` by the KSP, GAMG's hierarchy on ζ_α kept while the diagonal holds."""
        diagonal = self.system.diagonal()
        if self._multigrid_diagonal is None:
            build = True
        else:
            build = self._multigrid_drift(diagonal[:, :2]) > MULTIGRID_DRIFT
        self._solve_split(b, build, diagonal)
        if not build and self.ksp.getConvergedReason() < 0:
            self._rejected += self.ksp.getIterationNumber()
            self._solve_split(b, True, diagonal)
        self._multigrid_most = max(self._multigrid_most, self.ksp.getIterationNumber())

    def _solve_split(self, b: PETSc.Vec, build: bool, diagonal: np.ndarray) -> None:
        """One solve with the field split, building GAMG's hierarchy anew if ``build``
        (``diagonal``: the current Jacobian's). The coupling block the sweep multiplies by
        is always the current Jacobian's."""
        if self._split is not None:  # (the split exists after its first set-up)
            is_alpha, P_alpha, P_3, d_3 = self._blocks
            if build:
                self.system.A.createSubMatrix(is_alpha, is_alpha, submat=P_alpha)
            d_3.array[:] = diagonal[:, 2]
            P_3.setDiagonal(d_3)
            self._split[0].getPC().setReusePreconditioner(not build)
        max_it = self.ksp.getTolerances()[3]
        if not build:  # a kept hierarchy that stagnates is given up early
            cap = max(KEPT_MIN_ITERATIONS, KEPT_ITERATION_FACTOR * self._multigrid_most)
            self.ksp.setTolerances(max_it=min(max_it, cap))
        self.ksp.solve(b, self.system.dz)
        self.ksp.setTolerances(max_it=max_it)
        if self._split is None:
            self._split = self.ksp.getPC().getFieldSplitSubKSP()
            self._blocks = self._hold_blocks()
        if build:
            self._multigrid_diagonal = diagonal[:, :2].copy()
            self._multigrid_most = 0
            self.multigrid_builds += 1

    def _hold_blocks(self) -> tuple[PETSc.IS, PETSc.Mat, PETSc.Mat, PETSc.Vec]:
        """The split's ζ_α index set and block, its ζ_3 block and a vector of that block's
        rows, after the first set-up; each block is composed with its index set as
        ``"pmat"``, which makes PETSc's field split keep it instead of extracting it again."""
        pc = self.ksp.getPC()
        sets = [pc.getFieldSplitSubIS(name) for name in ("0", "1")]
        blocks = [ksp.getOperators()[1] for ksp in self._split]
        for index_set, block in zip(sets, blocks, strict=True):
            index_set.compose("pmat", block)
        return sets[0], blocks[0], blocks[1], blocks[1].createVecLeft()

    def _multigrid_drift(self, diagonal: np.ndarray) -> float:
        """``max |d_i − d_i⁰| / |d_i⁰|`` over the ζ_α diagonal ``d`` of the Jacobian against
        ``d⁰`` at the hierarchy's build (collective)."""
        d0 = self._multigrid_diagonal
        local = float(np.max(np.abs(diagonal - d0) / np.abs(d0), initial=0.0))
        return self.system.comm.allreduce(local, op=MPI.MAX)
