"""Inexact Newton with conjugate gradients and geometric multigrid on the mesh hierarchy.

The meshes of a uniformly refined mesh (:mod:`~shellobstacle.mesh.hierarchy`) carry nested
Lagrange spaces; PETSc's PCMG runs V-cycles on them with the interpolation between the levels
(the three components each interpolated by itself) and Galerkin coarse operators ``Pᵀ J P`` of
every Jacobian ``J = K + H``: ``Pᵀ K P`` is made once, and only the penalty part ``H`` (the
rows of the active points' cells) is multiplied out at each step; the active points reach the
coarse levels through it.
The coarsest level (gmsh's mesh) is factorized by MUMPS.

The smoother is two Chebyshev iterations preconditioned by the Jacobian's diagonal (point
Jacobi; the same on any number of ranks): ζ_α is an elliptic H¹ system, whose high
frequencies Chebyshev damps, and ζ_3 enters without derivatives (its block is a
penalty-augmented mass matrix, well conditioned once scaled by its diagonal). Chebyshev and
the V-cycle are symmetric, so the Krylov method is plain CG. Point-block Jacobi (each node's
3×3 block inverted) needs several times more iterations at small κ (docs/perf/multigrid.md).

A mesh without a known hierarchy (a mesh made elsewhere, or one gmsh mesh) falls back to
algebraic multigrid (GAMG) on the whole system, with block size 3 and the constants of each
component as its near-nullspace.

The Newton side (forcing terms, the seeded first step) is that of
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
from shellobstacle.penalty.quadrature import penalty_hessian
from shellobstacle.solvers.base import set_options, unique_prefix
from shellobstacle.solvers.linear.iterative import IterativeStrategy
from shellobstacle.solvers.system import PenalizedSystem

__all__ = ["SMOOTHERS", "MultigridStrategy"]

#: the level smoothers' preconditioners: point Jacobi or point-block (3×3 per node) Jacobi
SMOOTHERS = ("jacobi", "pbjacobi")

_LEVELS = {
    "mg_levels_ksp_type": "chebyshev",
    "mg_levels_ksp_max_it": 2,
    "mg_coarse_ksp_type": "preonly",
    "mg_coarse_pc_type": "cholesky",
    "mg_coarse_pc_factor_mat_solver_type": "mumps",
}
_GEOMETRIC = {"pc_type": "mg", **_LEVELS}
_ALGEBRAIC = {"pc_type": "gamg", "pc_gamg_threshold": 0.02, **_LEVELS}


class MultigridStrategy(IterativeStrategy):
    """Newton directions by CG with a multigrid V-cycle (module docstring).

    Args:
        rtol: the smallest forcing term (and the tolerance of every solve with ``"fixed"``).
        forcing: ``"eisenstat-walker"`` or ``"fixed"`` (every direction to ``rtol``).
        seed: take a solve's first step from an iterate without contact towards the seeded
            model (:mod:`~shellobstacle.solvers.seeds`).
        smoother: :data:`SMOOTHERS`, the preconditioner of the levels' Chebyshev iteration.
        levels: the most mesh levels to use (None: all the hierarchy has).
    """

    def __init__(
        self,
        rtol: float = 1e-12,
        forcing: str = "eisenstat-walker",
        seed: bool = True,
        smoother: str = "jacobi",
        levels: int | None = None,
    ) -> None:
        super().__init__(rtol, forcing, seed)
        if smoother not in SMOOTHERS:
            raise ValueError(f"smoother must be one of {SMOOTHERS}, got {smoother!r}")
        if levels is not None and levels < 1:
            raise ValueError(f"levels must be >= 1, got {levels}")
        self.smoother, self.max_levels = smoother, levels
        self.levels = 1  # of the V-cycle (1: algebraic multigrid)

    def attach(self, system: PenalizedSystem, timings: dict[str, float]) -> None:
        """CG with PCMG on the mesh hierarchy (GAMG without one) under a prefix of its own."""
        t0 = time.perf_counter()
        self.system, self.timings = system, timings
        system.incremental = True
        self.ksp = ksp = PETSc.KSP().create(system.comm)
        prefix = unique_prefix("newton")
        ksp.setOptionsPrefix(prefix)
        ksp.setType("cg")
        transfers = self._transfers(system.problem.V)
        self.levels = len(transfers) + 1
        options = dict(_GEOMETRIC if transfers else _ALGEBRAIC)
        options["mg_levels_pc_type"] = self.smoother
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
        system.on_new_jacobian = self._new_jacobian
        timings["multigrid_setup"] = time.perf_counter() - t0

    def _transfers(self, V: dolfinx.fem.FunctionSpace) -> list[PETSc.Mat]:
        """The interpolations from each level to the next, coarsest first (empty without a
        hierarchy)."""
        meshes = [*coarser_meshes(V.mesh), V.mesh]
        if self.max_levels is not None:
            meshes = meshes[-self.max_levels :]
        spaces = [dolfinx.fem.functionspace(m, V.ufl_element()) for m in meshes[:-1]] + [V]
        return [prolongation(c, f) for c, f in itertools.pairwise(spaces)]

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

    def _coarse_operators(self) -> None:
        """The levels' operators ``Pᵀ J P`` for the current Jacobian ``J = K + H``: ``Pᵀ K P``
        made once, plus the Galerkin product of the penalty part ``H``, whose rows are those
        of the active points' cells (a few per cent: far cheaper than ``Pᵀ J P``)."""
        system = self.system
        active = system.held_active
        rows = np.flatnonzero(active) if active is not None else np.zeros(0, dtype=np.int64)
        H = None
        if system.comm.allreduce(rows.size):
            H = penalty_hessian(system.penalty.M, system.penalty.D, rows, system.kappa)
        smoothers = [self.ksp.getPC().getMGSmoother(level) for level in range(self.levels - 1)]
        for level in reversed(range(self.levels - 1)):
            A = self._A[level]
            self._K[level].copy(A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            if H is not None:
                coarse = H.ptap(self._P[level])
                H.destroy()
                A.axpy(1.0, coarse, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
                H = coarse
            smoothers[level].setOperators(A)
        if H is not None:
            H.destroy()

    def _solve(self, b: PETSc.Vec) -> None:
        """``δ ← A⁻¹ b`` by CG with a V-cycle set up for the current Jacobian."""
        if self._P:
            self._coarse_operators()
        self.ksp.solve(b, self.system.dz)
        self.multigrid_builds += 1
