"""Exact solver of the discrete obstacle problem with nodal constraints (MODEL.md §3, §5).

With the constraint imposed at the Lagrange nodes ``x_i`` of the displacement space (P1: the
vertices; P2: the vertices and edge midpoints), the discrete variational inequality
(``κ = 0``) is the strictly convex quadratic program

:math:`\\min_{η ∈ V_h} J(η) = \\tfrac12 η^T K η - f^T η` subject to
:math:`g_i(η) = θ(x_i)·q + c(x_i)·η(x_i) ≥ 0` at every node :math:`x_i`,

with ``K`` the (linear, ``κ``-independent) stiffness matrix of either model and ``f`` the
load vector, both carrying the problem's homogeneous Dirichlet conditions. For P1 it is the
limit ``κ → 0`` of the penalized problem with ``penalty_quadrature = "vertex"``; for P2 no
quadrature has exactly these points with positive weights, so the penalized problems
approach it only as ``h → 0``.

**Bounds.** The rotations of :mod:`~shellobstacle.solvers.nodal` turn each node's
constraint into a lower bound on one rotated unknown, ``u_b ≥ ψ_b``: with ``K' = QᵀKQ`` and
``f' = Qᵀf`` the problem is a bound-constrained QP.

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

**KKT.** At the solution ``(ζ^h, λ)`` (``B`` the constraint matrix: row ``i`` is
``c(x_i)`` on the unknowns of node ``i``): ``K ζ − f − Bᵀλ = 0``, ``g_i ≥ 0``,
``λ_i ≥ 0``, ``λ_i g_i = 0``. The multiplier ``λ_i = (K'u − f')_{i,k_i} / |c(x_i)|`` is
the nodal contact force (``λ ≥ 0`` pushes the shell away from the plane); divided by
a lumped mass (P1: ``∫ φ_i √a dy``) it is a contact pressure. A penalized solution
approximates it by ``(ε/κ) m^0_i {g_i}^- / |c(x_i)|`` with ``m^0_i = ∫ φ_i dy``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np

from shellobstacle.problem import PenalizedProblem
from shellobstacle.solvers.base import ConvergenceError, direct_solver, factorize
from shellobstacle.solvers.line_search import piecewise_linear_root
from shellobstacle.solvers.nodal import NodalConstraint
from shellobstacle.solvers.options import ActiveSetOptions

__all__ = ["ActiveSetResult", "ActiveSetSolver"]


@dataclass
class ActiveSetResult:
    """What an active-set solve did, and the KKT quality of its answer.

    Attributes:
        converged: whether the active set settled and the KKT measures pass ``kkt_rtol``.
        iterations: linear solves in total (``newton_steps + pdas_steps``).
        active_nodes: global number of nodes in the final active set.
        reason: why the solver stopped.
        kkt: ``primal_feasibility = max_i {g_i}^-``, ``dual_feasibility = max_i {λ_i}^-``,
            ``complementarity = max_i |λ_i g_i|`` (absolute; see ``scales``) and
            ``stationarity = ‖K ζ − f − Bᵀλ‖ / ‖f‖`` (relative; Euclidean norms of the nodal
            vectors, evaluated in the original, unrotated unknowns).
        scales: natural sizes of the KKT quantities: ``gap`` (``max_i θ(x_i)·q``), ``force``
            (``max_i λ_i``, or ``‖f‖_∞`` without contact) and ``load`` (``‖f‖``).
        newton_steps: semismooth Newton steps of the path following (phase 1).
        pdas_steps: primal–dual active-set steps (phase 2).
        gammas: the ``γ`` of each path-following stage.
        active_history: global size of the active set after each primal–dual step.
        timings: seconds in ``setup`` (stiffness, rotation, ``QᵀKQ``: once per solver),
            ``assemble`` (load), ``solve`` (factorizations and solves), ``kkt`` and ``total``.
        multiplier: ``λ`` (nodal contact forces), a scalar Function on the nodes (the
            solver's own, refreshed by each :meth:`ActiveSetSolver.solve`: copy it to keep it).
        contact_pressure: ``λ_i / m_i``, ``m_i`` the lumped masses of
            :class:`~shellobstacle.solvers.nodal.NodalConstraint` (likewise refreshed).
    """

    converged: bool
    iterations: int
    active_nodes: int
    reason: str
    kkt: dict[str, float] = field(default_factory=dict)
    scales: dict[str, float] = field(default_factory=dict)
    newton_steps: int = 0
    pdas_steps: int = 0
    gammas: list[float] = field(default_factory=list)
    active_history: list[int] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    multiplier: dolfinx.fem.Function | None = None
    contact_pressure: dolfinx.fem.Function | None = None

    @property
    def relative_kkt(self) -> dict[str, float]:
        """KKT measures over their natural scales (``gap``, ``force``, ``force·gap``, 1)."""
        gap, force = self.scales.get("gap", 1.0) or 1.0, self.scales.get("force", 1.0) or 1.0
        return {
            "primal_feasibility": self.kkt["primal_feasibility"] / gap,
            "dual_feasibility": self.kkt["dual_feasibility"] / force,
            "complementarity": self.kkt["complementarity"] / (force * gap),
            "stationarity": self.kkt["stationarity"],
        }


class ActiveSetSolver:
    """Exact solver of the discrete obstacle problem (κ = 0) of one :class:`PenalizedProblem`.

    The stiffness matrix, the nodal rotation and ``K' = QᵀKQ`` are built once; each
    :meth:`solve` re-assembles only the load, so load parameters may change between solves.

    Args:
        problem: a P1 problem with ``penalty_quadrature = "vertex"``, or a P2 problem (its
            ``κ`` is not used).
        options: schedule, limits and tolerance.

    Raises:
        ValueError: for other discretizations, or when a node whose displacement is fixed
            lies below the plane (no admissible displacement).
    """

    def __init__(self, problem: PenalizedProblem, options: ActiveSetOptions | None = None) -> None:
        disc = problem.disc
        if not (disc.degree == 2 or (disc.degree == 1 and disc.penalty_quadrature == "vertex")):
            raise ValueError(
                "ActiveSetSolver solves the nodal constraint of P1 (vertices, as "
                "penalty_quadrature='vertex' penalizes) or P2 (vertices and edge midpoints): "
                f"got degree={disc.degree}, penalty_quadrature={disc.penalty_quadrature!r}"
            )
        self.problem = problem
        self.options = options or ActiveSetOptions()
        self.timings: dict[str, float] = {"setup": 0.0, "assemble": 0.0, "solve": 0.0, "kkt": 0.0}
        t0 = time.perf_counter()
        self.comm: MPI.Comm = problem.mesh.comm
        self.bs = problem.V.dofmap.index_map_bs
        self.n = problem.V.dofmap.index_map.size_local
        self.K = problem.stiffness()
        self.nodal = nodal = NodalConstraint(problem)
        self.free, self.nodes, self.iB, self.psi = nodal.free, nodal.nodes, nodal.iB, nodal.psi
        self.gap_scale = self._max(np.abs(nodal.theta_q))
        self.Q = nodal.Q
        self.Kr = self.K.ptap(self.Q)  # K' = Qᵀ K Q
        self.row0 = self.Kr.getOwnershipRange()[0]
        self.diag = self.Kr.getDiagonal()
        self.d = self.diag.array_r[self.iB].copy()  # K'_bb > 0

        # work matrix (K' modified per step, same sparsity) and the direct solver
        self.W = self.Kr.duplicate(copy=True)
        self.W.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
        self.ksp = direct_solver(self.W, "lu", "as")
        self.u, self.fr = self.Kr.createVecs()
        self.f, self.r, self.du, self.tmp = (self.fr.duplicate() for _ in range(4))
        self.timings["setup"] = time.perf_counter() - t0

    # -- global reductions --------------------------------------------------------------------
    def _max(self, x: np.ndarray) -> float:
        return float(self.comm.allreduce(float(np.max(x, initial=0.0)), op=MPI.MAX))

    def _sum(self, x: float) -> float:
        return float(self.comm.allreduce(float(x), op=MPI.SUM))

    def _count(self, mask: np.ndarray) -> int:
        return int(self.comm.allreduce(int(np.count_nonzero(mask)), op=MPI.SUM))

    def _differ(self, a: np.ndarray, b: np.ndarray) -> bool:
        return bool(self.comm.allreduce(bool(np.any(a != b)), op=MPI.LOR))

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
        self.Kr.mult(self.u, self.r)
        self.r.axpy(-1.0, self.fr)
        return self.r.array_r[self.iB] + self.d * (self.psi - self.u.array_r[self.iB]) > 0

    # -- solve --------------------------------------------------------------------------------
    def solve(self) -> ActiveSetResult:
        """Solve the discrete obstacle problem; leave ``ζ^h`` in ``problem.zeta``.

        Returns:
            The :class:`ActiveSetResult` with the multiplier, contact pressure and KKT measures.

        Raises:
            ConvergenceError: if the active set does not settle within the limits, or the KKT
                measures miss ``kkt_rtol``; ``problem.zeta`` then holds the last iterate and
                ``err.result`` the :class:`ActiveSetResult`.
        """
        opts, problem = self.options, self.problem
        t_start = time.perf_counter()
        self.timings = {"setup": self.timings["setup"], "assemble": 0.0, "solve": 0.0, "kkt": 0.0}
        n3 = self.n * self.bs

        ta = time.perf_counter()
        b = problem.load_vector()
        self.f.array[:] = b.array_r[:n3]
        b.destroy()
        self.Q.multTranspose(self.f, self.fr)
        self.timings["assemble"] += time.perf_counter() - ta

        zeta = problem.zeta
        warm = False
        if opts.warm_start:
            dolfinx.fem.petsc.set_bc(zeta.x.petsc_vec, problem.bcs)
            zeta.x.scatter_forward()
            self.Q.multTranspose(zeta.x.petsc_vec, self.u)
            warm = self.u.norm(PETSc.NormType.NORM_INFINITY) > 0
        else:
            self.u.set(0.0)

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

        self.Q.mult(self.u, zeta.x.petsc_vec)  # ζ = Q u
        zeta.x.scatter_forward()
        tk = time.perf_counter()
        result = self._kkt()
        self.timings["kkt"] += time.perf_counter() - tk
        result.iterations = newton_steps + pdas_steps
        result.newton_steps, result.pdas_steps = newton_steps, pdas_steps
        result.gammas, result.active_history = gammas, history
        if converged:
            worst = max(result.relative_kkt.values())
            if not worst <= opts.kkt_rtol:
                converged = False
                reason = f"KKT conditions hold only to {worst:.2e} > kkt_rtol = {opts.kkt_rtol:.1e}"
        result.converged, result.reason = converged, reason or "stopped"
        result.timings = dict(self.timings) | {"total": time.perf_counter() - t_start}
        if not converged:
            raise ConvergenceError(
                f"the active-set solver did not converge: {result.reason} "
                f"({result.iterations} linear solves)",
                result,
            )
        return result

    def _kkt(self) -> ActiveSetResult:
        """Multiplier, active set and KKT measures of the current ``u`` (``ζ = Qu`` in place)."""
        n, nodes = self.n, self.nodes
        uB = self.u.array_r[self.iB]
        self.Kr.mult(self.u, self.r)
        self.r.axpy(-1.0, self.fr)
        on_bound = uB <= self.psi  # PDAS puts the active unknowns exactly on the bound
        lam = np.zeros(n)
        lam[nodes[on_bound]] = self.r.array_r[self.iB[on_bound]] / self.nodal.cn[nodes[on_bound]]

        # gap and stationarity in the original unknowns: g = θ·q + c·ζ, K ζ − f − Bᵀλ
        g = self.nodal.gap(self.problem.zeta.x.array)
        self.K.mult(self.problem.zeta.x.petsc_vec, self.tmp)
        self.tmp.axpy(-1.0, self.f)
        self.tmp.array[:] -= self.nodal.constraint_force(lam)
        load = self.f.norm()
        stationarity = self.tmp.norm() / (load if load > 0 else 1.0)
        force = self._max(np.abs(lam)) or self.f.norm(PETSc.NormType.NORM_INFINITY)
        kkt = {
            "primal_feasibility": self._max(np.maximum(-g, 0.0)),
            "dual_feasibility": self._max(np.maximum(-lam, 0.0)),
            "complementarity": self._max(np.abs(lam * g)),
            "stationarity": stationarity,
        }
        scales = {"gap": self.gap_scale, "force": force, "load": load}
        self.nodal.set_multiplier(lam)
        return ActiveSetResult(
            converged=False,
            iterations=0,
            active_nodes=self._count(on_bound & (lam[nodes] > 0)),
            reason="",
            kkt=kkt,
            scales=scales,
            multiplier=self.nodal.multiplier,
            contact_pressure=self.nodal.contact_pressure,
        )
