"""Inexact Newton with conjugate gradients and geometric multigrid on the mesh hierarchy.

The meshes of a uniformly refined mesh (:mod:`~shellobstacle.mesh.hierarchy`) carry nested
Lagrange spaces; PETSc's PCMG runs V-cycles on them with the interpolation between the levels
(the three components each interpolated by itself) and Galerkin coarse operators ``Pᵀ J P`` of
a Jacobian ``J = K + H``: ``Pᵀ K P`` is made once, and only the penalty part ``H`` (the rows of
the active points' cells) is multiplied out; the active points reach the coarse levels through
it. The coarsest level (gmsh's mesh) is factorized by MUMPS.

The smoother is two Chebyshev iterations preconditioned by the Jacobian's diagonal (point
Jacobi; the same on any number of ranks): ζ_α is an elliptic H¹ system, whose high
frequencies Chebyshev damps, and ζ_3 enters without derivatives (its block is a
penalty-augmented mass matrix, well conditioned once scaled by its diagonal). Chebyshev and
the V-cycle are symmetric, so the Krylov method is plain CG. Point-block Jacobi (each node's
3×3 block inverted) needs several times more iterations at small κ (docs/perf/multigrid.md).

The coarser levels' operators follow the Jacobian: at a Newton step where more than
:data:`COARSE_UPDATE_SHARE` of their active points changed activity, the points that turned
active are added to the penalty part's Galerkin products and those that turned inactive taken
out, and the coarse level is factorized again. Operators kept over a κ go stale where the
first κ's active set moves over many steps (the ellipsoid, the paraboloid), and CG then takes
several times the iterations (docs/perf/multigrid.md). Chebyshev's bound of the
largest eigenvalue of ``D⁻¹A`` on each smoothed level, which PETSc would estimate (Lanczos,
ten steps) at every set-up with a new matrix, is estimated once per solve (one κ), at its
first Newton step, the same way (:func:`largest_eigenvalue`), and given to the smoothers with
PETSc's interval, ``[0.1, 1.1]`` times the estimate: estimated at every step, the bounds
change nothing. CG runs with the current Jacobian, the finest level's smoother too. A
direction whose CG fails, or needs more than
:data:`~shellobstacle.solvers.linear.iterative.KEPT_ITERATION_FACTOR` times the most
iterations since the set-up, is solved again with the levels set up anew.

Koiter's model (P2; the hybrid bending form's stiffness condensed onto ζ, with the couplings
of the two cells of each facet) takes the same multigrid on its ghosted meshes, whose
refinements keep the children on their parent's rank
(:func:`~shellobstacle.mesh.refinement.keep_ranks`), in W-cycles: the bending part is of
fourth order: with V-cycles the CG iterations per Newton step grow as h halves on the
cylindrical panel, with W-cycles they level off (docs/perf/multigrid.md). Its answers are the
direct path's, in a third to a half of the memory. Without the levels it is refused (GAMG
needs hundreds of CG iterations per Newton step there).

A mesh without a known hierarchy (a mesh made elsewhere, or one gmsh mesh) falls back to
algebraic multigrid (GAMG) on the whole system, with block size 3 and the constants of each
component as its near-nullspace: set up at every Newton step, it is slower than both the
direct path and the geometric V-cycle on the paper's problem (docs/perf/multigrid.md).
:attr:`MultigridStrategy.fallback` says so, and Newton's method passes
it on (a warning and the summary's ``linear_solver_used``).

The Newton side (forcing terms, the seeded first step, the finished direction) is that of
:class:`~shellobstacle.solvers.linear.iterative.IterativeStrategy`.
"""

from __future__ import annotations

import itertools
import time

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx and PETSc)
from petsc4py import PETSc

import dolfinx
import numpy as np

from shellobstacle.mesh.hierarchy import coarser_meshes, prolongation
from shellobstacle.mesh.memory import multigrid_needs_levels
from shellobstacle.messages import ConfigError
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers import libpetsc
from shellobstacle.solvers.base import set_options, unique_prefix
from shellobstacle.solvers.linear.iterative import (
    KEPT_ITERATION_FACTOR,
    KEPT_MIN_ITERATIONS,
    IterativeStrategy,
)
from shellobstacle.solvers.newton.system import PenalizedSystem
from shellobstacle.solvers.quadrature_penalty import penalty_factor

__all__ = [
    "CHEBYSHEV_INTERVAL",
    "COARSE_UPDATE_SHARE",
    "SMOOTHERS",
    "MultigridStrategy",
    "largest_eigenvalue",
]

#: the level smoothers' preconditioners: point Jacobi or point-block (3×3 per node) Jacobi
SMOOTHERS = ("jacobi", "pbjacobi")

_LEVELS = {
    "mg_levels_ksp_type": "chebyshev",
    "mg_levels_ksp_max_it": 2,
    "mg_coarse_ksp_type": "preonly",
    "mg_coarse_pc_type": "cholesky",
    "mg_coarse_pc_factor_mat_solver_type": "mumps",
}
#: Chebyshev's interval as multiples of the estimated ``λ_max(D⁻¹A)`` (PETSc's default)
CHEBYSHEV_INTERVAL = (0.1, 1.1)
#: the coarser operators are made anew when more than this share of their active points
#: changed activity (0: at any change; a larger share keeps stale operators over a κ whose
#: active set moves, for more CG iterations, docs/perf/multigrid.md)
COARSE_UPDATE_SHARE = 0.0
#: Lanczos steps of an estimate (PETSc's default)
ESTIMATE_STEPS = 10
_GEOMETRIC = {"pc_type": "mg", **_LEVELS}
_ALGEBRAIC = {"pc_type": "gamg", "pc_gamg_threshold": 0.02, **_LEVELS}


class MultigridStrategy(IterativeStrategy):
    """Newton directions by CG with a multigrid V-cycle (module docstring).

    Args:
        rtol: the smallest forcing term (and the tolerance of every solve with ``"fixed"``).
        forcing: ``"eisenstat-walker"`` or ``"fixed"`` (every direction to ``rtol``).
        seed: take a solve's first step from an iterate without contact towards the seeded
            model (:mod:`~shellobstacle.solvers.newton.seeds`).
        smoother: :data:`SMOOTHERS`, the preconditioner of the levels' Chebyshev iteration.
        levels: the most mesh levels to use (None: all the hierarchy has).
        finish: continue a direction that keeps the active set to Newton's threshold
            (:class:`~shellobstacle.solvers.linear.iterative.IterativeStrategy`).
    """

    def __init__(
        self,
        rtol: float = 1e-12,
        forcing: str = "eisenstat-walker",
        seed: bool = True,
        smoother: str = "jacobi",
        levels: int | None = None,
        finish: bool = True,
    ) -> None:
        super().__init__(rtol, forcing, seed, finish)
        if smoother not in SMOOTHERS:
            raise ValueError(f"smoother must be one of {SMOOTHERS}, got {smoother!r}")
        if levels is not None and levels < 1:
            raise ValueError(f"levels must be >= 1, got {levels}")
        self.smoother, self.max_levels = smoother, levels
        self.levels = 1  # of the V-cycle (1: algebraic multigrid)
        self.estimates = 0  # of a level's eigenvalue bound
        self._estimators: list[PETSc.KSP] = []  # per smoothed level (empty: PETSc's own)
        self._levels_current = False  # set up in this solve
        self._levels_most = 0  # the most CG iterations of a direction since the set-up
        self._coarse_active: np.ndarray | None = None  # the active points of the coarse operators
        self.coarse_updates = 0  # of the coarser operators within a solve (active points moved)
        #: why algebraic multigrid runs instead of the geometric one ("" when it does not)
        self.fallback = ""

    def attach(self, system: PenalizedSystem, timings: dict[str, float]) -> None:
        """CG with PCMG on the mesh hierarchy (GAMG without one) under a prefix of its own."""
        t0 = time.perf_counter()
        self.system, self.timings = system, timings
        system.incremental = True
        self.ksp = ksp = PETSc.KSP().create(system.comm)
        prefix = unique_prefix("newton")
        ksp.setOptionsPrefix(prefix)
        ksp.setType("cg")
        transfers = self._transfers(system.problem)
        if not transfers and multigrid_needs_levels(system.problem.model):
            raise ConfigError(
                "solver.linear_solver = 'multigrid' for Koiter's model needs the mesh's coarser "
                "levels (algebraic multigrid took 100-900 CG iterations per Newton step): set "
                "domain.refinements >= 1, or use linear_solver = 'direct'"
            )
        self.levels = len(transfers) + 1
        if not transfers and self.max_levels != 1:
            self.fallback = (
                "solver.linear_solver = 'multigrid': the mesh has no coarser levels (no "
                "domain.refinements), so algebraic multigrid (GAMG) runs instead of the "
                "geometric one; set domain.refinements >= 1 for the geometric one"
            )
        options = dict(_GEOMETRIC if transfers else _ALGEBRAIC)
        options["mg_levels_pc_type"] = self.smoother
        if system.problem.model == "koiter":  # fourth-order bending: W-cycles (docstring)
            options["pc_mg_cycle_type"] = "w"
        database = PETSc.Options()  # (the user's petsc_options, already there, win)
        mine = {k: v for k, v in options.items() if not database.hasName(prefix + k)}
        set_options(self, prefix, mine)
        pc = ksp.getPC()
        self._P = transfers
        if transfers:
            pc.setType("mg")
            pc.setMGLevels(self.levels)
            for level, P in enumerate(transfers, start=1):
                pc.setMGInterpolation(level, P)
            self._K = self._galerkin(system.K)
            self._A = [K.duplicate(copy=True) for K in self._K]
        ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
        ksp.setTolerances(rtol=self.rtol, atol=1e-50, max_it=2000)
        ksp.setFromOptions()
        if transfers:
            # PCMG does not read its levels' options itself: the coarse level would be
            # PETSc's own LU, slower than MUMPS' Cholesky
            for level in range(self.levels):
                pc.getMGSmoother(level).setFromOptions()
            self._estimators = self._make_estimators(prefix)
        system.on_new_jacobian = self._new_jacobian
        timings["multigrid_setup"] = time.perf_counter() - t0
        timings["multigrid_levels"] = 0.0  # the levels' set-ups and updates (within "solve")

    def _transfers(self, problem: PenalizedProblem) -> list[PETSc.Mat]:
        """The interpolations from each level to the next, coarsest first (empty without a
        hierarchy), with the rows of the finer level's Dirichlet dofs zeroed: a correction
        vanishes there, and a boundary node moved onto a curved γ, extrapolated from interior
        coarse nodes, would otherwise bring ``K``'s unit Dirichlet diagonal into ``Pᵀ K P``
        (against ζ_3's diagonal of order ε h², docs/perf/multigrid.md)."""
        V = problem.V
        meshes = [*coarser_meshes(V.mesh), V.mesh]
        if self.max_levels is not None:
            meshes = meshes[-self.max_levels :]
        spaces = [dolfinx.fem.functionspace(m, V.ufl_element()) for m in meshes[:-1]] + [V]
        transfers = []
        for coarse, fine in itertools.pairwise(spaces):
            P = prolongation(coarse, fine)
            start = P.getOwnershipRange()[0]
            rows = (start + problem.dirichlet_rows(fine)).astype(PETSc.IntType)
            P.zeroRows(rows, diag=0.0)
            transfers.append(P)
        return transfers

    def _new_jacobian(self, A: PETSc.Mat) -> None:
        """The Jacobian (symmetric positive definite: the coarse Cholesky) to the KSP."""
        A.setOption(PETSc.Mat.Option.SPD, True)
        self.ksp.setOperators(A)

    def _galerkin(self, A: PETSc.Mat) -> list[PETSc.Mat]:
        """``Pᵀ A P`` on every coarser level, coarsest first (from the finest down)."""
        coarse = []
        for P in reversed(self._P):
            A = A.ptap(P)
            coarse.append(A)
        return coarse[::-1]

    def _coarse_operators(self, update: bool = False) -> bool:
        """The levels' operators ``Pᵀ J P`` for the current Jacobian ``J = K + H``: ``Pᵀ K P``
        made once, plus the penalty part's ``(S P)ᵀ (S P)`` with ``H = Sᵀ S``, ``S`` the rows
        of the active points (a few per cent: far cheaper than ``Pᵀ J P``; carried down the
        levels as ``S P``, no ``n × n`` product on the finer levels). With ``update`` (the
        same κ) only the points that changed activity since the last call are added or taken
        out, as the fine Jacobian is (:attr:`PenalizedSystem.incremental`), and nothing is
        done unless more than :data:`COARSE_UPDATE_SHARE` of the operators' active points
        changed. Returns whether the operators were made or changed (collective)."""
        system = self.system
        active, then = system.held_active, self._coarse_active
        if update and active is not None and then is not None:
            terms = [(active & ~then, 1.0), (then & ~active, -1.0)]
            comm = system.comm
            changed = comm.allreduce(sum(int(np.count_nonzero(p)) for p, _ in terms))
            if changed <= COARSE_UPDATE_SHARE * comm.allreduce(int(np.count_nonzero(then))):
                return False
        elif update and active is None and then is None:
            return False
        else:
            for K, A in zip(self._K, self._A, strict=True):
                K.copy(A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            terms = [] if active is None else [(active, 1.0)]
        self._coarse_active = None if active is None else active.copy()
        for points, sign in terms:
            rows = np.flatnonzero(points)
            if not system.comm.allreduce(rows.size):
                continue
            S = penalty_factor(system.penalty.M, system.penalty.D, rows, system.kappa)
            for level in reversed(range(self.levels - 1)):
                coarse = S.matMult(self._P[level])
                S.destroy()
                H = coarse.transposeMatMult(coarse)
                self._A[level].axpy(sign, H, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
                H.destroy()
                S = coarse
            S.destroy()
        pc = self.ksp.getPC()
        for level, A in enumerate(self._A):
            A.setOption(PETSc.Mat.Option.SPD, True)  # (the coarse level: MUMPS' LDLᵀ)
            pc.getMGSmoother(level).setOperators(A)
        return True

    def begin(self) -> None:
        """A new solve (a new κ): new forcing terms, the levels set up at its first step."""
        super().begin()
        self._levels_current = False

    def refresh(self) -> None:
        """The penalty's operators were made anew: the levels set up anew at the next step."""
        super().refresh()
        self._levels_current = False

    def _make_estimators(self, prefix: str) -> list[PETSc.KSP]:
        """CG with each smoothed level's preconditioner, for :func:`largest_eigenvalue`
        (empty, and PETSc estimates at every set-up, if the levels are not Chebyshev's, if
        the user's options set its bounds, or if PETSc lacks ``KSPChebyshevSetEigenvalues``)."""
        if libpetsc.function("KSPChebyshevSetEigenvalues") is None:
            return []
        database = PETSc.Options()
        if any(
            k.startswith(prefix + "mg_levels") and "chebyshev_e" in k for k in database.getAll()
        ):
            return []
        pc = self.ksp.getPC()
        estimators = []
        for level in range(1, self.levels):
            smoother = pc.getMGSmoother(level)
            if smoother.getType() != PETSc.KSP.Type.CHEBYSHEV:
                return []
            estimator = PETSc.KSP().create(self.system.comm)
            estimator.setType("cg")
            estimator.getPC().setType(smoother.getPC().getType())
            estimator.setComputeEigenvalues(True)
            estimator.setTolerances(rtol=1e-12, atol=1e-300, max_it=ESTIMATE_STEPS)
            estimators.append(estimator)
        return estimators

    def _bounds(self) -> None:
        """Chebyshev's interval on every smoothed level from ``λ_max(D⁻¹A)`` of its current
        operator (collective)."""
        pc = self.ksp.getPC()
        fine = self.system.A
        set_eigenvalues = libpetsc.function("KSPChebyshevSetEigenvalues")
        low, high = CHEBYSHEV_INTERVAL
        for level, estimator in enumerate(self._estimators, start=1):
            A = self._A[level] if level < self.levels - 1 else fine
            emax = largest_eigenvalue(estimator, A)
            error = set_eigenvalues(pc.getMGSmoother(level).handle, high * emax, low * emax)
            if error:
                raise RuntimeError(f"KSPChebyshevSetEigenvalues failed (PETSc error {error})")
            self.estimates += 1

    def _set_up_levels(self) -> None:
        """The coarser levels' operators for the current Jacobian and, unless PETSc makes
        them, the smoothers' bounds (collective)."""
        self._coarse_operators()
        if self._estimators:
            self._bounds()
        self.multigrid_builds += 1
        self._levels_current, self._levels_most = True, 0

    def _solve(self, b: PETSc.Vec) -> None:
        """``δ ← A⁻¹ b`` by CG with the V-cycle; with levels kept from an earlier step of the
        solve, a failed or stagnating CG is repeated with the levels set up anew."""
        if not self._P:  # algebraic multigrid: PETSc sets it up at every step
            self._solve_once(b)
            self.multigrid_builds += 1
            return
        kept = self._levels_current
        t0 = time.perf_counter()
        if not kept:
            self._set_up_levels()
        elif self._coarse_operators(update=True):
            self.coarse_updates += 1
        self.timings["multigrid_levels"] += time.perf_counter() - t0
        max_it = self.ksp.getTolerances()[3]
        if kept:
            cap = max(KEPT_MIN_ITERATIONS, KEPT_ITERATION_FACTOR * self._levels_most)
            self.ksp.setTolerances(max_it=min(max_it, cap))
        self._solve_once(b)
        self.ksp.setTolerances(max_it=max_it)
        if kept and self.ksp.getConvergedReason() < 0:
            self._rejected += self.ksp.getIterationNumber()
            self._set_up_levels()
            self._solve_once(b)
        self._levels_most = max(self._levels_most, self.ksp.getIterationNumber())

    def _solve_once(self, b: PETSc.Vec) -> None:
        """One CG solve into ``system.dz``."""
        self.ksp.solve(b, self.system.dz)


def largest_eigenvalue(estimator: PETSc.KSP, A: PETSc.Mat) -> float:
    """An estimate of ``λ_max(D⁻¹A)``, ``D`` the preconditioner of ``estimator`` (a CG KSP
    that computes eigenvalues): the Ritz values of :data:`ESTIMATE_STEPS` CG steps from a
    fixed noisy right-hand side, PETSc's (a hash of the global index), as Chebyshev's own
    estimate (collective)."""
    estimator.setOperators(A)
    b, x = A.createVecs()
    start, end = b.getOwnershipRange()
    b.array[:] = _noise(np.arange(start, end))
    estimator.solve(b, x)
    values = estimator.computeEigenvalues()
    for v in (b, x):
        v.destroy()
    return float(np.max(values.real))


def _noise(index: np.ndarray) -> np.ndarray:
    """PETSc's noisy vector of Chebyshev's estimates: an integer hash of each global index,
    scaled to about [−1, 1]."""
    x = index.astype(np.uint32)
    x = ((x >> np.uint32(16)) ^ x) * np.uint32(0x45D9F3B)
    x = ((x >> np.uint32(16)) ^ x) * np.uint32(0x45D9F3B)
    x = (x >> np.uint32(16)) ^ x
    return (x.astype(np.int64) - 2147483648) * 5.0e-10
