"""The penalized energy of one problem at its current iterate, as Newton's method needs it.

``J_κ(ζ) = ½ ζᵀKζ − f·ζ + (1/(2κ)) Σ_k D_k min(g_k, 0)²`` (docs/model.md §5): the membrane part
is quadratic, with the stiffness ``K`` assembled once per mesh, and the penalty lives at its
quadrature points (:class:`~shellobstacle.solvers.quadrature_penalty.QuadraturePenalty`). A
residual is then one product with ``K`` and one with the point matrix ``M``, a Jacobian ``K``
plus a product over the active points only, and a line-search evaluation a sum over the points.

:class:`PenalizedSystem` is the model that
:class:`~shellobstacle.solvers.newton.solver.NewtonSolver`
steps on (the contact zone's condensed problem, :mod:`~shellobstacle.solvers.zone.reduced`,
is the other): its residual, Jacobian, round-off floor and exact line search. The Newton
direction comes from a linear strategy (:mod:`~shellobstacle.solvers.linear`), which solves
into :attr:`PenalizedSystem.dz`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers import libpetsc
from shellobstacle.solvers.newton.line_search import exact_step
from shellobstacle.solvers.quadrature_penalty import (
    QuadraturePenalty,
    add_penalty_hessian,
    penalty_hessian,
)

__all__ = ["PenalizedSystem"]


class PenalizedSystem:
    """``J_κ`` of ``problem`` at ``problem.zeta``: residual, Jacobian, floor, line search.

    Between :meth:`negate_residual` (before a direction is solved) and :meth:`move` the
    vector :attr:`R` holds ``−R(ζ)``, the right-hand side of the Newton equation.

    Args:
        problem: the compiled problem (its stiffness is shared, :meth:`PenalizedProblem.stiffness`).
        floor_factor: of the round-off floor (:meth:`floor`).
        incremental: update a Jacobian at the same κ by the points that changed activity
            (:meth:`jacobian`) instead of summing it anew.
    """

    def __init__(
        self, problem: PenalizedProblem, floor_factor: float = 100.0, incremental: bool = False
    ) -> None:
        self.problem = problem
        self.comm: MPI.Comm = problem.mesh.comm
        self.floor_factor = floor_factor
        self.incremental = incremental
        self.penalty = QuadraturePenalty(problem)
        self.K = problem.stiffness()
        # the Jacobian K + penalty part, made at the first full Newton step (steps on the
        # contact zone's problem never need it: one copy of K less in memory)
        self.A: PETSc.Mat | None = None
        self.R = dolfinx.fem.petsc.create_vector(problem.V)
        self.f = dolfinx.fem.petsc.create_vector(problem.V)  # load vector (Dirichlet rows 0)
        self.dz = dolfinx.fem.petsc.create_vector(problem.V)  # the Newton direction δ
        self.Kdz = self.K.createVecLeft()
        self.Kz = self.K.createVecLeft()  # Kζ of the current iterate (with R)
        # the gap at the owned points of the current iterate, Bδ of the last line search and
        # a work array: one array each, over the penalty's points, reused at every step
        n = self.penalty.D.size
        self.g, self._Bd, self._work = np.zeros(n), np.zeros(n), np.zeros(n)
        self._held: tuple[float, np.ndarray] | None = None  # (κ, active points) of A
        self._row_sums: np.ndarray | None = None  # Σ_j |K_ij| at the owned rows (floor)
        #: called with the Jacobian when it is first made (a linear strategy sets the
        #: matrix's options and gives it to its solver before any entry is added)
        self.on_new_jacobian: Callable[[PETSc.Mat], None] | None = None

    @property
    def kappa(self) -> float:
        """The current penalty parameter."""
        return float(self.problem.kappa.value)

    @property
    def zeta(self) -> PETSc.Vec:
        """The iterate ``ζ`` (the problem's own vector)."""
        return self.problem.zeta.x.petsc_vec

    def refresh(self) -> None:
        """Follow the problem's gap after it was linearized anew: the penalty's point operators
        are assembled again in place (:meth:`QuadraturePenalty.refresh`) and the Jacobian's
        penalty part is summed anew at its next use; ``K`` and the Jacobian's matrix (its
        pattern, hence its solvers' analyses) are kept."""
        self.penalty.refresh()
        self._held = None

    def contact(self) -> bool:
        """Whether the current iterate penetrates anywhere (collective)."""
        return self.comm.allreduce(bool((self.g < 0).any()), op=MPI.LOR)

    # -- residual -----------------------------------------------------------------------------
    def load(self) -> float:
        """``f ←`` the load vector (load parameters may have changed); returns ``‖f‖``."""
        self.problem.load_vector(self.f)
        return self.f.norm()

    def residual(self) -> None:
        """``R ← R(ζ) = Kζ − f + (1/κ) Mᵀ min(g, 0)`` and ``g ← g(ζ)`` at the points.

        ``ζ`` satisfies the homogeneous Dirichlet conditions, so the Dirichlet rows are 0.
        """
        self.K.mult(self.zeta, self.Kz)
        self.penalty.gap(self.zeta, out=self.g)
        self._finish_residual()

    def _residual_after_step(self, t: float) -> None:
        """:meth:`residual` after ``ζ ← ζ + tδ`` from ``Kδ`` and ``Bδ`` of the line search:
        ``Kζ ← Kζ + tKδ`` and ``g ← g + tBδ`` (two products fewer; the same values up to
        round-off)."""
        self.Kz.axpy(t, self.Kdz)
        self.g += np.multiply(t, self._Bd, out=self._work)
        self._finish_residual()

    def _finish_residual(self) -> None:
        """``R ← Kζ − f + (1/κ) Mᵀ min(g, 0)`` from ``Kζ`` and ``g``."""
        self.Kz.copy(self.R)
        self.R.axpy(-1.0, self.f)
        self.penalty.add_residual(np.minimum(self.g, 0.0, out=self._work), self.kappa, self.R)

    def energy(self) -> float:
        """``J_κ(ζ) = ½ ζ·Kζ − f·ζ + (1/(2κ)) Σ D_k min(g_k, 0)²`` from the current ``Kζ``
        and ``g``."""
        zeta = self.zeta
        elastic = 0.5 * zeta.dot(self.Kz) - self.f.dot(zeta)
        return elastic + self.penalty.energy(self.g, self.kappa)

    def residual_norm(self) -> float:
        """``‖R(ζ)‖``."""
        return self.R.norm()

    def negate_residual(self) -> None:
        """``R ← −R``: the right-hand side of the Newton equation ``J δ = −R``."""
        self.R.scale(-1.0)

    # -- Jacobian -----------------------------------------------------------------------------
    def jacobian(self, g: np.ndarray | None = None) -> PETSc.Mat:
        """``A ← K + (1/κ) M_Aᵀ diag(1/D_A) M_A`` at the active points ``A`` of ``g`` (default:
        the current gaps); returns ``A``.

        With ``incremental``, a Jacobian at the same κ is updated by the points that changed
        activity only, ``A ← A + P_on − P_off`` (a few percent of the active points after a
        κ's first step; the result differs from a new sum in round-off only).
        """
        active = (self.g if g is None else g) < 0
        held = self._held
        if held is not None and held[0] == self.kappa and self.A is not None:
            self._add_penalty_hessian(active & ~held[1], 1.0)
            self._add_penalty_hessian(held[1] & ~active, -1.0)
        elif self.A is None:
            self.A = self.K.duplicate(copy=True)
            if self.on_new_jacobian is not None:
                self.on_new_jacobian(self.A)
            self._add_penalty_hessian(active, 1.0)
        else:
            self.K.copy(self.A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            self._add_penalty_hessian(active, 1.0)
        self._held = (self.kappa, active) if self.incremental else None
        return self.A

    @property
    def held_active(self) -> np.ndarray | None:
        """The active points whose penalty part :attr:`A` holds (incremental only)."""
        return None if self._held is None else self._held[1]

    def _add_penalty_hessian(self, points: np.ndarray, sign: float) -> None:
        """``A ← A + sign (1/κ) M_Pᵀ diag(1/D_P) M_P`` for the owned points ``P`` where
        ``points`` holds (nothing where ``P`` is empty on every rank); incrementally on the
        columns of ``P`` only (:func:`add_penalty_hessian`: few points, no ``O(n)`` product)."""
        rows = np.flatnonzero(points)
        if not self.comm.allreduce(rows.size):
            return
        if self.incremental:
            pen = self.penalty
            add_penalty_hessian(self.A, pen.M, pen.D, rows, self.kappa, sign)
        else:
            P = penalty_hessian(self.penalty.M, self.penalty.D, rows, self.kappa)
            self.A.axpy(sign, P, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            P.destroy()

    def diagonal(self) -> np.ndarray:
        """The Jacobian's diagonal at the owned dofs, one row ``(ζ_1, ζ_2, ζ_3)`` per node."""
        d = self.A.getDiagonal()
        values = d.array_r.reshape(-1, 3).copy()
        d.destroy()
        return values

    # -- the round-off floor ------------------------------------------------------------------
    def floor(self, load_norm: float) -> float:
        """Estimated round-off floor of ``‖R(ζ)‖`` at the current iterate.

        ``floor_factor · u (‖f‖ + ‖S‖) + u ‖|K| |ζ|‖`` with ``S = (1/κ) Mᵀ (χ_A · (|θ·q| +
        Σ_j |ζ_j c_j|))``: the rounding of the terms of ``g`` amplified by the penalty, and the
        rounding of the products in ``Kζ``, each about ``u Σ_j |K_ij| |ζ_j|``. The second grows
        like the number of dofs and stays below the default ``rtol ‖f‖`` for the membrane
        (3.4e-12 ‖f‖ at 113k dofs); for Koiter's model on fine graded meshes with a small ε
        the bending terms cancel in ``Kζ`` and it bounds what Newton can resolve (6.6e-9 ‖f‖
        at 639k dofs, where the residual stalls at a fifth of it).
        """
        active = np.flatnonzero(self.g < 0)
        values = self._work
        values.fill(0.0)
        values[active] = self.penalty.gap_scale(self.zeta, active)
        S = self.R.duplicate()
        S.set(0.0)
        self.penalty.add_residual(values, self.kappa, S)
        norm = S.norm()
        S.destroy()
        return floor_of(self.floor_factor, load_norm, norm) + self.elastic_rounding()

    def elastic_rounding(self) -> float:
        """``u ‖|K| |ζ|‖`` at the current iterate, with ``|K| |ζ|`` estimated by
        ``(Σ_j |K_ij|) |ζ_i|``: ``ζ`` varies little between neighbouring dofs (within 0.1 %
        for Koiter on the paper's problem)."""
        if self._row_sums is None:
            self._row_sums = abs_row_sums(self.K)  # the owned rows, once per system
        local = self._row_sums * np.abs(self.zeta.array_r)
        total = self.comm.allreduce(float(local @ local))
        return float(np.finfo(PETSc.ScalarType).eps) * math.sqrt(total)

    # -- the step -----------------------------------------------------------------------------
    def penetrated_by_full_step(self) -> np.ndarray:
        """The owned points where ``ζ + δ`` penetrates, ``g + Bδ < 0`` (a mask)."""
        return np.add(self.g, self.penalty.apply_B(self.dz, out=self._work), out=self._work) < 0

    def slope(self) -> float:
        """``φ'(0) = R(ζ)·δ`` (:attr:`R` holds ``−R``)."""
        return -self.R.dot(self.dz)

    def small_step(self, stol: float) -> bool:
        """Whether ``‖δ‖_∞ ≤ stol ‖ζ‖_∞``."""
        step = self.dz.norm(PETSc.NormType.NORM_INFINITY)
        return step <= stol * self.zeta.norm(PETSc.NormType.NORM_INFINITY)

    def direction_norm(self) -> float:
        """``‖δ‖``."""
        return self.dz.norm()

    def line_search(self, slope0: float, noise: float) -> tuple[float, int]:
        """Exact step along δ: the root of ``φ'(t) = R(ζ + tδ)·δ`` (round-off aware).

        ``φ'(t) = R_el(ζ)·δ + t δᵀKδ + (1/κ) (Mδ)·min(g + t Bδ, 0)``: the membrane part is
        linear in ``t`` and the penalty part a sum over the quadrature points. ``g + t Bδ`` is
        affine in ``t``, so only the points with ``g < 0`` or ``g + Bδ < 0`` can contribute on
        ``[0, 1]``: the sums run over those (a few percent of the points).
        """
        pen = self.penalty
        Bd = pen.apply_B(self.dz, out=self._Bd)  # (kept for the residual after the step)
        self.K.mult(self.dz, self.Kdz)
        curvature = self.Kdz.dot(self.dz)
        g = self.g
        near = np.flatnonzero((g < 0) | (np.add(g, Bd, out=self._work) < 0))
        Bd = Bd[near]
        return exact_step(
            g[near], pen.D[near] * Bd, Bd, curvature, slope0, noise, self.kappa,
            self.comm.allreduce,
        )  # fmt: skip

    def move(self, t: float, small: bool) -> None:
        """``ζ ← ζ + tδ`` and the residual there (from the line search's products unless the
        step was too small to search)."""
        zeta = self.problem.zeta
        with self.dz.localForm() as dz_loc:
            zeta.x.array[:] += t * dz_loc.array_r
        zeta.x.scatter_forward()
        if small:
            self.residual()
        else:
            self._residual_after_step(t)


#: the matrix formats whose absolute row sums PETSc computes itself
ROW_SUM_ABS_TYPES = frozenset({"seqaij", "mpiaij"})


def abs_row_sums(A: PETSc.Mat) -> np.ndarray:
    """``Σ_j |A_ij|`` for the rows of ``A`` this rank owns (for ``u ‖|A| |x|‖`` estimates).

    PETSc's ``MatGetRowSumAbs`` sums the AIJ formats' rows in place; for another format, or
    without it (an older PETSc), the rows are copied out (``getValuesCSR``) and summed here.
    """
    row_sum_abs = libpetsc.function("MatGetRowSumAbs")
    if row_sum_abs is not None and A.getType() in ROW_SUM_ABS_TYPES:
        sums = A.createVecLeft()
        status = row_sum_abs(A.handle, sums.handle)
        values = sums.array_r.copy()
        sums.destroy()
        if status != 0:
            raise RuntimeError(f"PETSc's MatGetRowSumAbs failed (error {status})")
        return values
    rows, _, values = A.getValuesCSR()
    sums = np.zeros(rows.size - 1)
    nonempty = rows[:-1] < rows[1:]
    sums[nonempty] = np.add.reduceat(np.abs(values), rows[:-1][nonempty])
    return sums


def floor_of(factor: float, load_norm: float, penalty_norm: float) -> float:
    """``factor · u · (‖f‖ + ‖S‖)``, ``u`` the machine epsilon (:meth:`PenalizedSystem.floor`)."""
    return factor * np.finfo(PETSc.ScalarType).eps * (load_norm + penalty_norm)
