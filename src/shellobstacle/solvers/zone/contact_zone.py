"""Which dofs form the contact zone, and when it is rebuilt.

The zone holds every active point. When an active point leaves it, the zone is rebuilt
around the active points, the penetration of the last full Newton step and the old zone,
then dilated by rings of the stiffness graph until its dofs have doubled (room for the
contact region to move). A zone above ``max_fraction`` of the dofs is not worth condensing:
the whole Jacobian is then factorized instead, until the active points and the last full
step's penetration have shrunk enough for a zone built from them alone to fit (the first
steps of a weak penalty press a wide region that the later κ give back). The zone depends on
the mesh, not on κ: it is kept across the continuation, and saved with a sweep's records so
that a resumed run repeats the uninterrupted one.
"""

from __future__ import annotations

import time

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers.base import direct_solver, factorize
from shellobstacle.solvers.quadrature_penalty import QuadraturePenalty
from shellobstacle.solvers.zone.condensation import Condensation
from shellobstacle.solvers.zone.graph import csr, dilate, dofs_of, inside, union
from shellobstacle.solvers.zone.multipliers import HybridBlocks
from shellobstacle.solvers.zone.mumps import in_blocks
from shellobstacle.solvers.zone.reduced import ZoneProblem

__all__ = ["DILATION", "ContactZone"]

#: a zone's dofs are those of its points, dilated by rings of ``K``'s graph to this multiple
DILATION = 2


class ContactZone:
    """The zone of one problem: its dofs ``Z``, its condensation and its own problem.

    Args:
        K: the membrane stiffness.
        penalty: the problem's penalty (its point matrix decides which dofs a point couples).
        max_fraction: a zone with more dofs than this fraction is not condensed.
        factorization: MUMPS ``"lu"`` or ``"cholesky"`` of ``K_II`` and ``S``.
        timings: phase seconds (``"zone"``, ``"factorize"``, ``"condense"``) are added here.
    """

    def __init__(
        self,
        K: PETSc.Mat,
        penalty: QuadraturePenalty,
        max_fraction: float,
        factorization: str,
        timings: dict[str, float],
    ) -> None:
        if not 0.0 < max_fraction <= 1.0:
            raise ValueError(f"zone_max_fraction must be in (0, 1], got {max_fraction}")
        self.K, self.penalty, self.max_fraction = K, penalty, max_fraction
        self.factorization, self.timings = factorization, timings
        self.comm: MPI.Comm = K.getComm().tompi4py()
        self.n = K.getSize()[0]
        self.r0, self.r1 = K.getOwnershipRange()
        self.points: np.ndarray | None = None  # owned points inside the zone (None: no zone)
        self.Z: np.ndarray | None = None  # the zone's dofs (global, sorted, on all ranks)
        self.whole = False  # the zone is too large: factorize the whole Jacobian
        self.held = 0  # points inside a zone too large (all ranks')
        self.builds = 0  # zones built (each a factorization of K_II)
        self.cond: Condensation | None = None
        self.problem: ZoneProblem | None = None
        self.whole_ksp: PETSc.KSP | None = None
        self.whole_H: PETSc.Mat | None = None  # a hybrid stiffness' H + P (whole)
        self.f: PETSc.Vec | None = None  # the load of the coming Newton steps
        self.blocks: HybridBlocks | None = None  # a hybrid stiffness' block matrix

    @property
    def sizes(self) -> dict[str, int]:
        """Dofs of the zone, of its interface Γ and of the coupled dofs I'."""
        if self.cond is not None:
            return self.cond.sizes
        return {} if self.Z is None else {"zone_dofs": int(self.Z.size)}

    @property
    def usable(self) -> bool:
        """A nonempty zone that is condensed (not "factorize the whole Jacobian")."""
        return not self.whole and self.Z is not None and self.Z.size > 0

    def covers(self, active: np.ndarray) -> bool:
        """Whether the current zone holds all active points (collective)."""
        ok = self.whole or (self.points is not None and not np.any(active & ~self.points))
        return bool(self.comm.allreduce(ok, op=MPI.LAND))

    def prepare(self, active: np.ndarray, hint: np.ndarray | None) -> bool:
        """Make the zone hold the active points; returns True if a zone was built.

        ``hint``: more points the zone should hold (the penetration of the last full step).
        A zone too large is built again from the active points and ``hint`` alone once the
        zone they predict fits (a zone's dofs taken as proportional to the points it holds;
        a zone that fits is kept while it holds the active points: building one costs more
        than the smaller zone saves, docs/perf/koiter.md).
        """
        base = active if hint is None else active | hint
        if self.whole:
            count = self._held(base)
            predicted = DILATION * count * self.Z.size / max(self.held, 1)
            if count == 0 or predicted > self.max_fraction * self.n:
                return False
        elif self.covers(active):
            return False
        t0, factorize0 = time.perf_counter(), self.timings["factorize"]
        if self.points is not None:
            base = base | self.points
        pattern = csr(self.penalty.M)
        Z = dofs_of(self.comm, base, pattern)
        if Z.size:
            Z = dilate(self.K, Z, DILATION * Z.size)
        built = not (self.whole and self._too_large(Z))
        if built:
            self.set_zone(Z, pattern)
        else:  # still too large: the whole Jacobian's factorization (its analysis) is kept
            self._set_whole(Z, pattern)
        self.timings["zone"] += time.perf_counter() - t0 - (self.timings["factorize"] - factorize0)
        return built

    def _too_large(self, Z: np.ndarray) -> bool:
        return Z.size > self.max_fraction * self.n

    def _held(self, points: np.ndarray) -> int:
        """How many points (a mask of owned points) on all ranks."""
        return self.comm.allreduce(int(np.count_nonzero(points)), op=MPI.SUM)

    def _set_whole(self, Z: np.ndarray, pattern: tuple[np.ndarray, np.ndarray]) -> None:
        """``Z`` is too large: factorize the whole Jacobian (``Z`` kept to be tried again)."""
        self.whole, self.Z, self.points = True, Z, None
        self.held = self._held(inside(self.n, Z, pattern))

    def set_zone(self, Z: np.ndarray, pattern: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Make ``Z`` (sorted global dofs, the same on all ranks) the zone (collective).

        Factorizes ``K_II`` and computes ``T``; a zone above ``max_fraction`` of the dofs
        means "factorize the whole Jacobian" instead. ``pattern``: the point matrix's, if the
        caller has it.
        """
        self.destroy()
        pattern = pattern or csr(self.penalty.M)
        if self._too_large(Z):
            self._set_whole(Z, pattern)
            return
        self.whole, self.Z = False, Z
        self.points = inside(self.n, Z, pattern)
        self.cond = Condensation(self.K, Z, self.factorization, self.timings, self._blocks())
        if Z.size:
            self.problem = ZoneProblem(self.cond, self.penalty, self.points, self.timings)
        self.builds += 1

    def refresh(self) -> None:
        """The zone's problem made again from the penalty's point operators, after they were
        assembled anew (their pattern, hence the zone's points and condensation, unchanged)."""
        if self.problem is not None:
            self.problem.destroy()
            self.problem = ZoneProblem(self.cond, self.penalty, self.points, self.timings)

    def _blocks(self) -> HybridBlocks | None:
        """The block matrix in ``(ζ, t)`` of a hybrid stiffness ``K`` (made once), or None."""
        problem = self.penalty.problem
        hybrid = problem.condensed
        if hybrid is None or hybrid.K is not self.K:  # no blocks, or another stiffness'
            return None
        if self.blocks is None or self.blocks.hybrid is not hybrid:
            self.blocks = HybridBlocks(hybrid, problem.V, problem.t.function_space)
        return self.blocks

    def owned_zone(self) -> np.ndarray:
        """Local positions of the zone's owned dofs (empty without a zone)."""
        if self.Z is None:
            return np.zeros(0, dtype=np.int64)
        lo, hi = np.searchsorted(self.Z, [self.r0, self.r1])
        return self.Z[lo:hi] - self.r0

    def set_owned_zone(self, owned: np.ndarray) -> None:
        """Make the union over the ranks of these owned dofs (local positions) the zone."""
        self.set_zone(union(self.comm, owned + self.r0))

    def destroy(self) -> None:
        """Free the zone's matrices and factorizations."""
        if self.problem is not None:
            self.problem.destroy()
            self.problem = None
        if self.cond is not None:
            self.cond.destroy()
            self.cond = None
        for obj in (self.whole_ksp, self.whole_H):
            if obj is not None:
                obj.destroy()
        self.whole_ksp = self.whole_H = None

    # -- the load and exact solves ------------------------------------------------------------
    def set_load(self, f: PETSc.Vec) -> None:
        """The load vector of the coming Newton steps (``K_II⁻¹ f_I`` is kept if unchanged)."""
        if self.f is not None:
            same = np.array_equal(self.f.array_r, f.array_r)
            if self.comm.allreduce(same, op=MPI.LAND):
                return
            self.f.destroy()
        self.f = f.copy()
        if self.cond is not None:
            self.cond.uf_valid = False

    def forget_factorization(self) -> None:
        """Do not reuse the kept factorization of ``S`` for later Jacobians (a new solve)."""
        if self.cond is not None:
            self.cond.factor_state = None

    def set_up(self, J: PETSc.Mat) -> None:
        """Factorize for the Jacobian ``J``: ``S`` of the zone, or ``J`` itself (whole; for a
        hybrid stiffness the block matrix ``H`` plus the penalty, whose Schur complement is
        ``J``: Cholesky of a cell-local matrix instead of LU of ``J``)."""
        t0 = time.perf_counter()
        if self.whole:
            blocks = self._blocks()
            if blocks is not None:
                self.whole_H = blocks.with_penalty(J, self.K, self.whole_H)
                J = self.whole_H
            prepare = None  # MUMPS orders H's mesh nodes (in_blocks), at its analysis
            if self.whole_ksp is None:
                self.whole_ksp = direct_solver(J, "lu" if blocks is None else "cholesky", "zone")
                if blocks is not None:
                    prepare = in_blocks(blocks.variable_blocks(np.arange(J.getSize()[0])))
            self.whole_ksp.setOperators(J)
            factorize(self.whole_ksp, "the Jacobian", prepare=prepare)
            self.timings["factorize"] += time.perf_counter() - t0
            return
        self.cond.set_up(J)
        self.timings["condense"] += time.perf_counter() - t0

    def newton_step(self, x: PETSc.Vec, zeta: PETSc.Vec, y: PETSc.Vec) -> None:
        """``y ← J⁻¹ x`` for a Newton right-hand side ``x = −R(ζ)`` (after :meth:`set_up`)."""
        if not self.whole:
            self.cond.newton_step(x, zeta, self.f, y)
        elif self.whole_H is None:
            self.whole_ksp.solve(x, y)
        else:  # (y, s) = H_J⁻¹ (x, 0)
            blocks = self.blocks
            blocks.pad(x, blocks.x)
            self.whole_ksp.solve(blocks.x, blocks.y)
            blocks.restrict(blocks.y, y)
