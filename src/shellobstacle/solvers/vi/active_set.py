"""Exact solver of the discrete obstacle problem with nodal constraints (docs/model.md §5–6).

The problem is the bound-constrained quadratic program ``min ½ uᵀK'u − f'ᵀu``, ``u_B ≥ ψ``
of :mod:`~shellobstacle.solvers.vi.nodal_qp` (the constraint at the Lagrange nodes, rotated
into bounds). For P1 it is the limit ``κ → 0`` of the penalized problem with
``penalty_quadrature = "vertex"``; for P2 no quadrature has exactly these points with
positive weights, so the penalized problems approach it only as ``h → 0``.

**Solver.** Two phases, every step one sparse direct solve (MUMPS) with the
sparsity of ``K'`` (its symbolic factorization is reused):

1. *Moreau–Yosida path following* (globalization). For ``γ = γ_0, γ_0 s, γ_0 s², …``
   minimize the strictly convex, C¹, piecewise-quadratic
   ``J_γ(u) = J(u) + ½ Σ_b γ d_b {ψ_b − u_b}_+²`` (``d_b = K'_bb``) by semismooth Newton
   with an exact line search, warm-started from the previous ``γ``: globally
   convergent for every ``γ``. (Plain primal–dual active-set steps from a cold
   start cycle on the paper's problem: ``K'`` is not an M-matrix.)
2. *Primal–dual active set* (semismooth Newton on ``min(λ_b, d_b(u_b − ψ_b)) = 0``),
   started from the regularized solution: with the active set ``A`` the unknowns
   ``u_A = ψ_A`` are eliminated (``MatZeroRowsColumns``), the rest solved exactly, and
   ``λ_A = (K'u − f')_A``. When the next active set equals ``A`` the KKT conditions
   hold exactly (up to the round-off of the linear solve). If it does not settle
   within a few steps, phase 1 continues with a larger ``γ``.

**Multiplier.** ``λ_i = (K'u − f')_{i,k_i} / |c(x_i)|`` on the active set, 0 elsewhere. A
penalized solution approximates it by ``(ε/κ) m^0_i {g_i}^- / |c(x_i)|`` with
``m^0_i = ∫ φ_i dy``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from mpi4py import MPI  # noqa: F401  (MPI before PETSc)
from petsc4py import PETSc

import numpy as np

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.base import (
    ConvergenceError,
    UserOptions,
    direct_solver,
    factorize,
    with_user_options,
)
from shellobstacle.solvers.newton.line_search import piecewise_linear_root
from shellobstacle.solvers.vi.nodal_qp import NodalQP, NodalResult, factor_mb
from shellobstacle.solvers.vi.options import ActiveSetOptions

__all__ = ["ActiveSetResult", "ActiveSetSolver"]


@dataclass
class ActiveSetResult(NodalResult):
    """What an active-set solve did, and the KKT quality of its answer
    (:class:`~shellobstacle.solvers.vi.nodal_qp.NodalResult`; ``converged`` also requires the
    KKT measures to pass ``kkt_rtol``, ``iterations`` is ``newton_steps + pdas_steps`` and
    ``active_nodes`` the size of the final active set).

    Attributes:
        newton_steps: semismooth Newton steps of the path following (phase 1).
        pdas_steps: primal–dual active-set steps (phase 2).
        gammas: the ``γ`` of each path-following stage.
        active_history: global size of the active set after each primal–dual step.
    """

    newton_steps: int = 0
    pdas_steps: int = 0
    gammas: list[float] = field(default_factory=list)
    active_history: list[int] = field(default_factory=list)

    def details(self) -> dict:
        """The summary's record: KKT measures, phases and the active set's history."""
        return super().details() | {
            "newton_steps": self.newton_steps,
            "pdas_steps": self.pdas_steps,
            "active_history": self.active_history,
        }


class ActiveSetSolver:
    """Exact solver of the discrete obstacle problem (κ = 0) of one :class:`PenalizedProblem`.

    The stiffness matrix, the nodal rotation and ``K' = QᵀKQ`` are built once
    (:class:`~shellobstacle.solvers.vi.nodal_qp.NodalQP`); each :meth:`solve` re-assembles only
    the load, so load parameters may change between solves.

    Args:
        problem: a P1 problem with ``penalty_quadrature = "vertex"``, or a P2 problem (its
            ``κ`` is not used).
        options: schedule, limits and tolerance.

    Raises:
        ValueError: for other discretizations, or when a node whose displacement is fixed
            lies below the plane (no admissible displacement).
    """

    def __init__(self, problem: PenalizedProblem, options: ActiveSetOptions | None = None) -> None:
        self.problem = problem
        self.options = options or ActiveSetOptions()
        self.user_options = UserOptions(
            self.options.petsc_options, ("as",), "active-set", problem.mesh.comm
        )
        self.timings: dict[str, float] = {"setup": 0.0, "assemble": 0.0, "solve": 0.0, "kkt": 0.0}
        t0 = time.perf_counter()
        self.qp = qp = NodalQP(problem, "ActiveSetSolver")
        self.iB, self.psi, self.d = qp.iB, qp.psi, qp.d
        self.Kr, self.fr, self.diag = qp.Kr, qp.fr, qp.diag
        self.row0 = self.Kr.getOwnershipRange()[0]
        self._sum, self._count, self._differ = qp.sum, qp.count, qp.differ

        # work matrix (K' modified per step, same sparsity) and the direct solver
        self.W = self.Kr.duplicate(copy=True)
        self.W.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
        with self.user_options.applied():
            self.ksp = direct_solver(self.W, "lu", "as")
        self.u = self.fr.duplicate()
        self.r, self.du, self.tmp = (self.fr.duplicate() for _ in range(3))
        self.timings["setup"] = time.perf_counter() - t0

    # -- linear algebra -----------------------------------------------------------------------
    def _linear_solve(self, rhs: PETSc.Vec, x: PETSc.Vec, changed: bool = True) -> None:
        """``x ← W⁻¹ rhs``; ``changed``: ``W`` changed since the last solve (it is
        factorized again, with more MUMPS workspace when the analysis under-estimated it:
        INFOG(1) = −9 on adapted meshes of 10⁶ dofs)."""
        t = time.perf_counter()
        if changed:
            self.ksp.setOperators(self.W)  # the next set-up factorizes the new values
            factorize(self.ksp, "the active-set system")
        self.ksp.solve(rhs, x)
        self.timings["solve"] += time.perf_counter() - t
        if self.ksp.getConvergedReason() < 0:
            F = self.ksp.getPC().getFactorMatrix()
            raise ConvergenceError(
                f"linear solve failed (PETSc reason {self.ksp.getConvergedReason()}, MUMPS "
                f"INFOG(1) = {F.getMumpsInfog(1)}, INFOG(2) = {F.getMumpsInfog(2)})"
            )

    def _gradient(self, gamma: float) -> np.ndarray:
        """``r ← ∇J_γ(u) = K'u − f' − γ d {ψ − u_B}_+`` (on B); returns the violation mask."""
        self.Kr.mult(self.u, self.r)
        self.r.axpy(-1.0, self.fr)
        viol = self.psi - self.u.array_r[self.iB]
        active = viol > 0
        if gamma > 0:
            self.r.array[self.iB] -= gamma * self.d * np.maximum(viol, 0.0)
        return active

    # -- phase 1: semismooth Newton on J_γ ----------------------------------------------------
    def _slope(self, t: float, a0: float, b: float, rho: np.ndarray, viol: np.ndarray) -> float:
        """``φ'(t) = ∇J_γ(u + tδ)·δ = a0 + t b − Σ_B ρ δ {ψ − u − tδ}_+`` (global)."""
        dB = self.du.array_r[self.iB]
        return a0 + t * b - self._sum(np.sum(rho * dB * np.maximum(viol - t * dB, 0.0)))

    def _line_search(self, slope0: float, a0: float, b: float, rho, viol) -> float:
        """Minimizer of the convex piecewise-quadratic ``φ(t) = J_γ(u + tδ)`` on ``[0, 1]``."""
        t, _ = piecewise_linear_root(
            lambda t: self._slope(t, a0, b, rho, viol),
            slope0,
            1e-12 * abs(slope0),
            max_evaluations=100,
            interval_rtol=1e-15,
        )
        return t

    def _newton_stage(self, gamma: float, budget: int) -> tuple[int, bool]:
        """Minimize ``J_γ`` from the current ``u``; returns (steps, converged)."""
        rho = gamma * self.d
        eps = np.finfo(PETSc.ScalarType).eps
        for step in range(1, min(budget, self.options.max_stage_iterations) + 1):
            active = self._gradient(gamma)
            self.Kr.copy(self.W, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            self.tmp.array[:] = self.diag.array_r
            self.tmp.array[self.iB[active]] += rho[active]
            self.W.setDiagonal(self.tmp, PETSc.InsertMode.INSERT_VALUES)
            self.r.scale(-1.0)
            self._linear_solve(self.r, self.du)
            slope0 = -self.r.dot(self.du)  # ∇J_γ·δ = −δᵀWδ
            self.Kr.mult(self.u, self.tmp)
            energy = abs(self.fr.dot(self.u)) + abs(self.u.dot(self.tmp))  # size of J_γ's terms
            self.Kr.mult(self.du, self.tmp)
            b = self.tmp.dot(self.du)
            viol = self.psi - self.u.array_r[self.iB]
            # (K'u − f')·δ = ∇J_γ·δ + Σ ρ δ {ψ − u}_+
            dB = self.du.array_r[self.iB]
            a0 = slope0 + self._sum(np.sum(rho * dB * np.maximum(viol, 0.0)))
            if not math.isfinite(slope0):
                return step, False
            if -slope0 <= 1e3 * eps * energy:  # Newton decrement below the energy's round-off
                return step, True
            t = self._line_search(slope0, a0, b, rho, viol)
            self.u.axpy(t, self.du)
            new_active = self.psi - self.u.array_r[self.iB] > 0
            if t == 1.0 and not self._differ(active, new_active):
                return step, True  # full step, same active set: the exact minimizer of J_γ
        return step, False

    # -- phase 2: primal–dual active set ------------------------------------------------------
    def _pdas(self, active: np.ndarray, budget: int, history: list[int]) -> tuple[int, bool]:
        """Primal–dual active-set steps from the set ``active`` (over B); (steps, converged)."""
        for step in range(1, budget + 1):
            self.Kr.copy(self.W, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            rows = (self.row0 + self.iB[active]).astype(PETSc.IntType)
            self.tmp.set(0.0)
            self.tmp.array[self.iB[active]] = self.psi[active]
            self.fr.copy(self.r)
            self.W.zeroRowsColumns(rows, 1.0, self.tmp, self.r)
            rhs = self.r.copy()
            self._linear_solve(self.r, self.u)
            self.u.array[self.iB[active]] = self.psi[active]  # exactly on the bound
            self.Kr.mult(self.u, self.r)
            self.r.axpy(-1.0, self.fr)
            lam = np.where(active, self.r.array_r[self.iB], 0.0)
            new = lam + self.d * (self.psi - self.u.array_r[self.iB]) > 0
            history.append(self._count(new))
            if not self._differ(new, active):
                self._refine(rhs, active)
                rhs.destroy()
                return step, True
            rhs.destroy()
            active = new
        return step, False

    def _refine(self, rhs: PETSc.Vec, active: np.ndarray) -> None:
        """One step of iterative refinement of the last solve ``W u = rhs`` (the settled
        active set's system, still factorized): ``u ← u + W⁻¹(rhs − W u)``. On meshes graded by
        10³–10⁴ (adaptive refinement) the factorization's backward error alone leaves the
        relative stationarity at 1e-10–1e-9; one step brings it back to round-off."""
        residual = rhs.duplicate()
        self.W.mult(self.u, residual)
        residual.aypx(-1.0, rhs)
        correction = rhs.duplicate()
        self._linear_solve(residual, correction, changed=False)
        self.u.axpy(1.0, correction)
        self.u.array[self.iB[active]] = self.psi[active]
        for v in (residual, correction):
            v.destroy()

    def _prediction(self) -> np.ndarray:
        """Active set predicted at the current ``u``: ``λ_b + d_b (ψ_b − u_b) > 0``."""
        return self.qp.predicted_active(self.u, self.qp.bound_forces(self.u))

    # -- solve --------------------------------------------------------------------------------
    @with_user_options
    def solve(self) -> ActiveSetResult:
        """Solve the discrete obstacle problem; leave ``ζ^h`` in ``problem.zeta``.

        Returns:
            The :class:`ActiveSetResult` with the multiplier, contact pressure and KKT measures.

        Raises:
            ConvergenceError: if the active set does not settle within the limits, or the KKT
                measures miss ``kkt_rtol``; ``problem.zeta`` then holds the last iterate and
                ``err.result`` the :class:`ActiveSetResult`.
        """
        opts = self.options
        t_start = time.perf_counter()
        self.timings = {"setup": self.timings["setup"], "assemble": 0.0, "solve": 0.0, "kkt": 0.0}
        ta = time.perf_counter()
        self.qp.assemble_load()
        self.timings["assemble"] += time.perf_counter() - ta
        warm = self.qp.start(self.u, opts.warm_start)

        newton_steps = pdas_steps = 0
        gammas: list[float] = []
        history: list[int] = []
        converged, reason = False, ""
        u_reg = self.u.duplicate()
        self.u.copy(u_reg)
        try:
            if warm:  # a good start (e.g. a penalized solution) often needs no path following
                steps, converged = self._pdas(
                    self._prediction(), min(opts.max_pdas_iterations, opts.max_iterations), history
                )
                pdas_steps += steps
                reason = "active set settled from the warm start" if converged else ""
            gamma, previous = opts.gamma_initial, None
            while not converged:
                budget = opts.max_iterations - newton_steps - pdas_steps
                if budget <= 0:
                    reason = f"no convergence in {opts.max_iterations} linear solves"
                    break
                if gamma > opts.gamma_max:
                    reason = f"active set did not settle up to gamma_max = {opts.gamma_max:.1e}"
                    break
                u_reg.copy(self.u)
                steps, ok = self._newton_stage(gamma, budget)
                newton_steps += steps
                gammas.append(gamma)
                self.u.copy(u_reg)
                if not ok:
                    if newton_steps + pdas_steps >= opts.max_iterations:
                        reason = f"no convergence in {opts.max_iterations} linear solves"
                    else:
                        reason = f"semismooth Newton did not converge at gamma = {gamma:.1e}"
                    break
                predicted = self._prediction()
                settled = previous is not None and not self._differ(predicted, previous)
                if settled or gamma * opts.gamma_factor > opts.gamma_max:
                    budget = opts.max_iterations - newton_steps - pdas_steps
                    steps, converged = self._pdas(
                        predicted, min(opts.max_pdas_iterations, budget), history
                    )
                    pdas_steps += steps
                    reason = f"active set settled after path following to gamma = {gamma:.1e}"
                previous = predicted
                gamma *= opts.gamma_factor
        except ConvergenceError as err:  # failed linear solve
            converged, reason = False, str(err)
        u_reg.destroy()

        tk = time.perf_counter()
        result = self._kkt()
        self.timings["kkt"] += time.perf_counter() - tk
        result.iterations = newton_steps + pdas_steps
        result.newton_steps, result.pdas_steps = newton_steps, pdas_steps
        result.gammas, result.active_history = gammas, history
        result.converged, result.reason = converged, reason or "stopped"
        result.timings = dict(self.timings) | {"total": time.perf_counter() - t_start}
        result.conclude(opts.kkt_rtol, "the active-set solver", "linear solves")
        return result

    def _kkt(self) -> ActiveSetResult:
        """Multiplier, active set and KKT measures of the current ``u`` (``ζ = Qu`` in place)."""
        on_bound = self.u.array_r[self.iB] <= self.psi  # PDAS puts the active unknowns on it
        lam_B = np.where(on_bound, self.qp.bound_forces(self.u), 0.0)
        fields = self.qp.evaluate(self.u, lam_B, on_bound & (lam_B > 0))
        return ActiveSetResult(
            converged=False, iterations=0, reason="", factor_mb=factor_mb(self.ksp), **fields
        )
