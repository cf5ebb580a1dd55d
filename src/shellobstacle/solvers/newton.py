"""Semismooth Newton for the penalized problem, globalized by an exact line search (MODEL.md §4).

``J_κ`` is strictly convex, C¹ and piecewise quadratic, so along a Newton
direction ``δ`` the function ``φ(t) = J_κ(ζ + tδ)`` is convex and piecewise
quadratic and ``φ'(t) = R(ζ + tδ)·δ`` is monotone and piecewise linear. The step
length is the root of ``φ'`` (found by safeguarded secant steps, exact once the
active set along the segment is fixed), which makes every step decrease the
energy and the iteration globally convergent from any start.

The membrane part of ``J_κ`` is quadratic: its Hessian ``K`` is assembled once, and the
penalty part lives at its quadrature points (:class:`~shellobstacle.penalty.QuadraturePenalty`).
A residual is then one product with ``K`` and one with the point matrix ``M``, a Jacobian
``K`` plus a product over the active points only, and a line-search evaluation a sum over
the points. The direct solver condenses the steps onto a contact zone around the active
points (:mod:`shellobstacle.solvers.contact_zone`): the stiffness outside it is factorized once
per zone, and the Newton steps are taken on the zone's own problem, with the dofs outside the
zone eliminated. Without the zone (``contact_zone=False``) a solve factorizes its first
Jacobian only: later Newton steps, whose Jacobians differ from it only where the active set
moved, are solved by conjugate gradients preconditioned with that factorization, and a new one
is computed only when that does not converge quickly.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import dolfinx
import dolfinx.fem.petsc
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shellobstacle import compat  # noqa: F401
from shellobstacle.penalty import QuadraturePenalty, penalty_hessian
from shellobstacle.problem import PenalizedProblem
from shellobstacle.solvers.coarse_space import CoarseSpace
from shellobstacle.solvers.contact_zone import ContactZone, zone_available
from shellobstacle.solvers.line_search import piecewise_linear_root
from shellobstacle.solvers.options import set_options, unique_prefix

__all__ = ["ConvergenceError", "NewtonOptions", "NewtonResult", "NewtonSolver"]

# CG's relative tolerance for the iterative solver's Euler predictor (with inexact Newton): the
# Euler step's own error is of the order of Δκ/κ (≥ 0.2 on the continuation paths), so the
# tangent needs no more than two digits. Measured at 111k and 326k dofs: the same Newton steps
# with 1e-2 as with 1e-6 (one fewer at one κ), the predictor 3.3× cheaper.
PREDICTOR_RTOL = 1e-2

# The iterative solver's first forcing term from an iterate with contact (a continuation's next
# κ starts from the previous solution). Measured on the paper's problem (docs/performance.md,
# eighth session): 1e-4 gave 9/4/3 Newton steps at 326k and 11/5/2 at 1.92 M (1e-3: 9/4/4,
# 1e-2: 9/5/6, 0.1 with the Euler predictor: 9/7/5 and 11/8/8).
WARM_FORCING = 1e-4

# How far the Jacobian's ζ_α diagonal may move (relative, at any dof) before the iterative
# solver builds GAMG's hierarchy again (NewtonOptions.keep_multigrid).
MULTIGRID_DRIFT = 0.05

# A solve with a kept hierarchy that has not converged within this factor times the most
# iterations of a solve since the build (at least KEPT_MIN_ITERATIONS) is repeated with a new
# one.
KEPT_ITERATION_FACTOR = 4
KEPT_MIN_ITERATIONS = 50


@dataclass(frozen=True)
class NewtonOptions:
    """Stopping rules and linear solver of :class:`NewtonSolver`.

    Attributes:
        rtol: stop when ``‖R(ζ)‖ ≤ rtol ‖R(0)‖`` (``R(0) = −`` load vector).
        atol: stop when ``‖R(ζ)‖ ≤ atol``.
        stol: stop when the Newton correction is smaller than ``stol ‖ζ‖`` (max norms).
        floor_factor: the residual is at its round-off floor when ``‖R‖ ≤ floor_factor · u ·
            (‖L‖ + ‖S‖)``, ``u`` the machine epsilon, ``L`` the load vector and ``S`` the penalty
            residual built from the magnitudes of the terms of ``g = θ·q + ζ_j c_j``; with
            ``ε/κ`` large this floor is far above ``rtol ‖L‖``, and iterating further only
            stirs round-off.
        max_iterations: give up (and raise) after this many Newton steps.
        linear_solver: ``"direct"`` (MUMPS) or ``"iterative"`` (a Krylov method
            preconditioned by a block Gauss–Seidel split: GAMG on ζ_α, Jacobi on ζ_3).
        split_sweep: of the iterative solver's split. ``"forward"``: one sweep (a V-cycle on
            ζ_α, then Jacobi on ζ_3 with the residual updated), not symmetric, so the Krylov
            method is flexible CG keeping four earlier directions (PETSc's FCG, Notay's
            truncated form). ``"symmetric"``: a forward and a backward sweep (two V-cycles),
            symmetric, with CG. The forward sweep took 1.4–1.5× the iterations for half the
            work each and the same Newton steps on the paper's problem (docs/performance.md,
            fourteenth session).
        keep_multigrid: keep GAMG's hierarchy on ζ_α, its finest level included, across κ
            while the Jacobian's ζ_α diagonal stays within ``MULTIGRID_DRIFT`` (5 %) of its
            values at the build, and build it again when it does not or a solve with the kept
            one failed (that solve is then repeated). A solve with the kept one that needs
            more than ``KEPT_ITERATION_FACTOR`` (4) times the most iterations of a solve since
            the build (at least 50) is given up and repeated with a new one. ``False``: built
            at every κ's first step and kept for its later steps whatever their diagonal.
        factorization: of the direct solver: ``"cholesky"`` (MUMPS' LDLᵀ for symmetric
            positive definite matrices, which K_II and the Jacobian are: half the factors'
            memory; docs/performance.md measured a continuation 7–10 % faster than with LU
            on one machine and 14–19 % slower on others) or ``"lu"``.
        linear_rtol: relative tolerance of the iterative linear solver (its smallest one with
            ``forcing = "eisenstat-walker"``), and of the conjugate gradients that reuse a
            factorization.
        forcing: with the iterative solver, how accurately each Newton direction is solved.
            ``"eisenstat-walker"``: an inexact Newton method, CG stops at
            ``‖J δ + R‖ ≤ η_k ‖R‖`` with Eisenstat and Walker's choice 2 (SIAM J. Sci. Comput.
            17, 1996): ``η_k = 0.9 (‖R_k‖ / ‖R_{k−1}‖)²``, safeguarded, at most 0.1, and never
            below ``linear_rtol`` nor below what Newton's stopping test can still see (half the
            stopping threshold over ``‖R_k‖``); the solution is the same, the CG iterations of
            the early steps far fewer. A solve that starts from an iterate with contact (a
            continuation's next κ) takes its first step with ``η_0 = WARM_FORCING`` (1e-4)
            instead of 0.1: from the previous solution the exact Newton steps converge in 2–4
            steps, as the direct solver's do, while a loose first step sets off a string of
            inexact ones (1.92 M on 2 ranks: 11/8/8 → 11/5/2 Newton steps, 181 → 186 CG
            iterations, 21 % less time). ``"fixed"``: ``linear_rtol`` at every step.
        reuse_factorization: with the direct solver, keep one factorization per κ and solve
            later Newton steps at that κ by conjugate gradients preconditioned with it (with
            ``zone_newton``: the factorization of the zone's Schur complement ``S``).
        reuse_max_iterations: give up reusing (and factorize) after this many CG iterations,
            and factorize at once when more quadrature points than this changed between
            active and inactive since the factorization (each change is a rank-one change of
            the Jacobian, one more outlying eigenvalue for CG to find). The default is about
            the cost of one factorization in back-substitutions on 1e5–1e6 dofs (measured in
            docs/performance.md); it is a fixed number, not a timing, so that the iterates do
            not depend on the machine's speed.
        contact_zone: with the direct solver, solve every Newton step exactly by
            condensation onto a contact zone (:mod:`shellobstacle.solvers.contact_zone`):
            ``K`` outside the zone is factorized once per zone, kept across κ, and a step
            factorizes only the zone's small Schur complement. Replaces
            ``reuse_factorization``.
        zone_max_fraction: a zone with more dofs than this fraction is not condensed (the
            whole Jacobian is factorized at every step).
        zone_newton: with a contact zone, take the Newton steps on the zone's own problem
            (``ζ_I`` eliminated: :meth:`NewtonSolver._zone_newton`), with no back-substitution
            with ``K_II`` per step; ``ζ_I`` is computed once at the end of each solve.
        seed_zone: with ``zone_newton``, build the first zone before the first Newton step,
            where a coarse-grid approximation of that step
            (:class:`~shellobstacle.solvers.coarse_space.CoarseSpace`) penetrates the
            obstacle, instead of factorizing ``K`` for the first step and ``K_II`` for the
            second; the first step then goes to the minimizer of the zone's model whose
            active set is those points (:meth:`NewtonSolver._zone_seed`).
        seed_active: with the iterative solver, the same idea without a zone: from an
            iterate without contact the first Newton step solves with the Jacobian whose
            active points are where the coarse-grid approximation of the step penetrates
            (:meth:`NewtonSolver._active_seed`).
        euler_predictor: whether :meth:`NewtonSolver.predict` moves ζ along dζ/dκ before a
            new κ (the continuation's warm start). ``None``: only with the direct solver
            without ``zone_newton``. Not with steps on the contact zone, whose Newton steps
            from the previous solution are fewer than from the Euler prediction on the paper's
            problem (κ = h^0.5, h, h^1.5: 6/2/2, 5/3/2, 7/3/3, 8/3/2, 9/4/2 instead of 6/3/3,
            5/2/3, 7/4/5, 8/6/4, 9/7/6 from 7k to 1.92 M dofs), nor with the iterative solver
            since its warm first step is solved tightly (``forcing``): 9/4/3 from the previous
            solution at 326k against 9/7/5 from the prediction. On the unit square of the
            tests, κ falling 10× or √10× per step, the zone's predictor saved a step or two
            instead (``True`` to use it).
    """

    rtol: float = 1e-10
    atol: float = 1e-30
    stol: float = 1e-12
    floor_factor: float = 100.0
    max_iterations: int = 100
    linear_solver: str = "direct"
    linear_rtol: float = 1e-12
    forcing: str = "eisenstat-walker"
    factorization: str = "cholesky"
    reuse_factorization: bool = True
    reuse_max_iterations: int = 15
    contact_zone: bool = True
    zone_max_fraction: float = 0.3
    zone_newton: bool = True
    seed_zone: bool = True
    seed_active: bool = True
    euler_predictor: bool | None = None
    split_sweep: str = "forward"
    keep_multigrid: bool = True

    def __post_init__(self) -> None:
        if self.linear_solver not in ("direct", "iterative"):
            raise ValueError(
                f"solver.linear_solver must be 'direct' or 'iterative', got {self.linear_solver!r}"
            )
        if self.forcing not in ("eisenstat-walker", "fixed"):
            raise ValueError(
                f"solver.forcing must be 'eisenstat-walker' or 'fixed', got {self.forcing!r}"
            )
        if self.split_sweep not in ("forward", "symmetric"):
            raise ValueError(
                f"split_sweep must be 'forward' or 'symmetric', got {self.split_sweep!r}"
            )
        if self.factorization not in ("lu", "cholesky"):
            raise ValueError(
                f"solver.factorization must be 'lu' or 'cholesky', got {self.factorization!r}"
            )
        if not 0.0 < self.zone_max_fraction <= 1.0:
            raise ValueError(f"zone_max_fraction must be in (0, 1], got {self.zone_max_fraction}")
        if self.reuse_max_iterations < 1:
            raise ValueError(f"reuse_max_iterations must be >= 1, got {self.reuse_max_iterations}")
        if self.max_iterations < 1:
            raise ValueError(f"solver.max_iterations must be >= 1, got {self.max_iterations}")


@dataclass
class NewtonResult:
    """What a Newton solve did: iterations, residual history, step lengths, times."""

    converged: bool
    iterations: int
    reason: str
    residual_norms: list[float] = field(default_factory=list)
    step_lengths: list[float] = field(default_factory=list)
    linear_iterations: list[int] = field(default_factory=list)
    line_search_evaluations: int = 0
    factorizations: int = 0
    zone_steps: int = 0  # of the iterations: steps on the contact zone's own problem
    timings: dict[str, float] = field(default_factory=dict)
    reference: float = 0.0  # ‖R(0)‖, the scale of the relative residual

    @property
    def round_off_limited(self) -> bool:
        """Stopped because round-off, not the tolerance, bounds what can be resolved.

        For tiny κ the gap ``g = θ·q + ζ_j c_j`` is known only to machine precision and the
        penalty multiplies that error by ``ε/κ``: the residual then cannot reach ``rtol`` and
        the iterate is the solution to working precision only.
        """
        return self.converged and self.reason != "relative residual below rtol"

    @property
    def relative_residual(self) -> float:
        """Final ``‖R(ζ)‖ / ‖R(0)‖`` (``R(0)`` = minus the load vector; 0 for a zero load)."""
        if not self.residual_norms:
            return math.nan
        last = self.residual_norms[-1]
        if self.reference > 0:
            return last / self.reference
        return 0.0 if last == 0 else math.inf


class ConvergenceError(RuntimeError):
    """Newton did not converge; ``result`` holds the history, the iterate is left in place."""

    def __init__(self, message: str, result: NewtonResult) -> None:
        super().__init__(message)
        self.result = result


class NewtonSolver:
    """Newton's method for one :class:`PenalizedProblem`, reusable across ``κ`` values."""

    def __init__(self, problem: PenalizedProblem, options: NewtonOptions | None = None) -> None:
        self.problem = problem
        self.options = opts = options or NewtonOptions()
        comm = problem.mesh.comm
        t0 = time.perf_counter()
        self.penalty = QuadraturePenalty(problem)
        self.K = dolfinx.fem.petsc.assemble_matrix(problem.forms["stiffness"], bcs=problem.bcs)
        self.K.assemble()
        # the Jacobian K + penalty part, made at the first full Newton step (steps on the
        # contact zone's problem never need it: one copy of K less in memory, 1.4 GB at 1.9 M)
        self.A: PETSc.Mat | None = None
        self.R = dolfinx.fem.petsc.create_vector(problem.V)
        self.f = dolfinx.fem.petsc.create_vector(problem.V)  # load vector (Dirichlet rows 0)
        self.dz = dolfinx.fem.petsc.create_vector(problem.V)
        self.Kdz = self.K.createVecLeft()
        self.Kz = self.K.createVecLeft()  # Kζ of the current iterate (with R)
        self._Bd = np.zeros(0)  # Bδ of the last full step's line search
        self.ksp = PETSc.KSP().create(comm)
        prefix = unique_prefix("newton")
        self.ksp.setOptionsPrefix(prefix)
        pc = self.ksp.getPC()
        self.zone: ContactZone | None = None
        self._hint: np.ndarray | None = None  # points the full last Newton step penetrates
        zoned = opts.linear_solver == "direct" and opts.contact_zone and zone_available(comm)
        self.reuse = opts.linear_solver == "direct" and opts.reuse_factorization and not zoned
        self.reduced = zoned and opts.zone_newton  # Newton steps on the zone's own problem
        if zoned:
            self.zone = ContactZone(
                self.K, self.penalty, opts.zone_max_fraction, opts.factorization
            )
            self.ksp.setType("preonly")
            pc.setType("python")
            pc.setPythonContext(self.zone)
        elif opts.linear_solver == "direct":
            pc.setType(opts.factorization)
            pc.setFactorSolverType("mumps")
            if self.reuse:
                # the factorization stays that of an earlier Jacobian until _factorize
                pc.setReusePreconditioner(True)
                self.ksp.setType("cg")
                self.ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
                self.ksp.setTolerances(
                    rtol=opts.linear_rtol, atol=0.0, max_it=opts.reuse_max_iterations
                )
                self.ksp.setInitialGuessNonzero(False)
            else:
                self.ksp.setType("preonly")
        else:
            symmetric = opts.split_sweep == "symmetric"
            self.ksp.setType("cg" if symmetric else "fcg")
            # ζ_3 enters the membrane strain without derivatives: its block is a (penalty-
            # augmented) mass matrix, Jacobi is enough there, and AMG works on ζ_α alone.
            # Measured (docs/performance.md): CG iterations then hardly grow with ε/κ.
            split = {
                "pc_type": "fieldsplit",
                "pc_fieldsplit_type": "symmetric_multiplicative" if symmetric else "multiplicative",
                "pc_fieldsplit_block_size": 3,
                "pc_fieldsplit_0_fields": "0,1",
                "pc_fieldsplit_1_fields": "2",
                "fieldsplit_0_ksp_type": "preonly",
                "fieldsplit_0_pc_type": "gamg",
                "fieldsplit_0_pc_gamg_threshold": 0.02,
                # Chebyshev–Jacobi smoothing (GAMG's own default) rather than SOR: more CG
                # iterations, less time (docs/performance.md, seventh session), and the
                # same smoother on any number of ranks
                "fieldsplit_0_mg_levels_pc_type": "jacobi",
                "fieldsplit_1_ksp_type": "preonly",
                "fieldsplit_1_pc_type": "jacobi",
            }
            if not symmetric:
                # four kept directions: the same iterations as FCG's default 30 (329k dofs)
                # for less orthogonalization; with one, a solve with a kept GAMG stagnated
                # (batch 1 at 329k, κ = h²: residual stuck at 4e-3 of its start)
                split["ksp_fcg_mmax"] = 4
            set_options(self, prefix, split)
            # ‖J δ + R‖ itself, the quantity the forcing term bounds
            self.ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
            self.ksp.setTolerances(rtol=opts.linear_rtol, atol=1e-50, max_it=2000)
        self.ksp.setFromOptions()  # (the options stay: the levels are made at every set-up)
        self.timings: dict[str, float] = {
            "setup": time.perf_counter() - t0,
            "assemble": 0.0,
            "factorize": 0.0,
            "solve": 0.0,
            "line_search": 0.0,
            "zone": 0.0,
            "condense": 0.0,
            "zone_newton": 0.0,
        }
        self._factored_kappa: float | None = None  # κ of the factorization held by the KSP
        self._eta: float | None = None  # the last forcing term of the iterative solver
        self._split: list[PETSc.KSP] | None = None  # the field split's solvers (iterative)
        # GAMG's hierarchy on ζ_α (iterative): the κ it was built at and the Jacobian's ζ_α
        # diagonal then (owned entries)
        self._multigrid_kappa: float | None = None
        self._multigrid_diagonal = np.zeros(0)
        self.multigrid_builds = 0
        self._multigrid_most = 0  # the most iterations of a solve since the build
        self._blocks: tuple[PETSc.IS, PETSc.Mat, PETSc.Mat, PETSc.Vec] | None = None
        self._rejected_iterations = 0  # of a solve repeated with a new hierarchy
        self.factorizations = 0  # in the current solve
        self._reuse_failures = 0
        self._g = np.zeros(0)  # gap at the quadrature points of the current iterate
        self._factored_active = np.zeros(0, dtype=bool)  # active points of the factorization
        # (κ, active points) of the penalty part that A holds (iterative solver: updated)
        self._jacobian_held: tuple[float, np.ndarray] | None = None

    @property
    def kappa(self) -> float:
        """The current penalty parameter."""
        return float(self.problem.kappa.value)

    @property
    def active_points(self) -> np.ndarray:
        """The owned penalty points where the last iterate penetrates, ``g_k < 0`` (the
        active set ``A`` of MODEL.md §5), as a boolean array in the quadrature space's local
        order; empty before the first solve."""
        return self._g < 0

    @property
    def penalty_gaps(self) -> np.ndarray:
        """The gap ``g_k`` of the last iterate at the owned penalty points (read-only view)."""
        view = self._g.view()
        view.flags.writeable = False
        return view

    # -- residual and Jacobian ----------------------------------------------------------------
    def _load(self) -> None:
        """``f ←`` the load vector (load parameters may have changed since the last solve)."""
        self.problem.load_vector(self.f)

    def _residual(self) -> None:
        """``R ← R(ζ) = Kζ − f + (1/κ) Mᵀ min(g, 0)`` and ``g ← g(ζ)`` at the points.

        ``ζ`` satisfies the homogeneous Dirichlet conditions, so the Dirichlet rows are 0.
        """
        zeta = self.problem.zeta.x.petsc_vec
        self.K.mult(zeta, self.Kz)
        self._g = self.penalty.gap(zeta)
        self._finish_residual()

    def _residual_after_step(self, t: float) -> None:
        """:meth:`_residual` after ``ζ ← ζ + tδ`` from ``Kδ`` and ``Bδ`` of the line search:
        ``Kζ ← Kζ + tKδ`` and ``g ← g + tBδ`` (two products with K and B fewer per step;
        the same values up to round-off)."""
        self.Kz.axpy(t, self.Kdz)
        self._g = self._g + t * self._Bd
        self._finish_residual()

    def _finish_residual(self) -> None:
        """``R ← Kζ − f + (1/κ) Mᵀ min(g, 0)`` from ``self.Kz`` and ``self._g``."""
        self.Kz.copy(self.R)
        self.R.axpy(-1.0, self.f)
        self.penalty.add_residual(np.minimum(self._g, 0.0), self.kappa, self.R)

    def _jacobian(self, g: np.ndarray | None = None) -> None:
        """``A ← K + (1/κ) M_Aᵀ diag(1/D_A) M_A`` at the active points ``A`` of ``g`` (default:
        the current gaps).

        With the iterative solver, a Jacobian at the same κ is updated by the points that
        changed activity only, ``A ← A + P_on − P_off`` (a few percent of the active points
        after a κ's first step; the result differs from a new sum in round-off only).
        """
        active = (self._g if g is None else g) < 0
        held = self._jacobian_held
        if held is not None and held[0] == self.kappa and self.A is not None:
            self._update_jacobian(held[1], active)
        else:
            self._new_jacobian(active)
        iterative = self.options.linear_solver == "iterative"
        self._jacobian_held = (self.kappa, active) if iterative else None

    def _update_jacobian(self, held: np.ndarray, active: np.ndarray) -> None:
        """``A ← A + (1/κ)(M_onᵀ W M_on − M_offᵀ W M_off)`` from the active set ``held``."""
        self._add_penalty_hessian(active & ~held, 1.0)
        self._add_penalty_hessian(held & ~active, -1.0)

    def _add_penalty_hessian(self, points: np.ndarray, sign: float) -> None:
        """``A ← A + sign (1/κ) M_Pᵀ diag(1/D_P) M_P`` for the owned points ``P`` where
        ``points`` holds (nothing where ``P`` is empty on every rank)."""
        rows = np.flatnonzero(points)
        if self.problem.mesh.comm.allreduce(rows.size):
            P = penalty_hessian(self.penalty.M, self.penalty.D, rows, self.kappa)
            self.A.axpy(sign, P, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            P.destroy()

    def _new_jacobian(self, active: np.ndarray) -> None:
        """``A ← K + P_A`` for the active points ``active`` (a mask of the owned points)."""
        if self.A is None:
            self.A = self.K.duplicate(copy=True)
            opts = self.options
            if (
                self.zone is None
                and opts.linear_solver == "direct"
                and opts.factorization == "cholesky"
            ):
                self.A.setOption(PETSc.Mat.Option.SPD, True)
            self.ksp.setOperators(self.A)
        else:
            self.K.copy(self.A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        self._add_penalty_hessian(active, 1.0)

    def _factorize(self) -> None:
        """Factorize the current Jacobian (kept for the later steps of this solve)."""
        t0 = time.perf_counter()
        pc = self.ksp.getPC()
        pc.setReusePreconditioner(False)
        pc.setUp()  # the numeric factorization (the symbolic one is kept)
        pc.setReusePreconditioner(self.reuse)
        self._factored_kappa = self.kappa
        self._factored_active = self._g < 0
        self.factorizations += 1
        self.timings["factorize"] += time.perf_counter() - t0

    def _floor(self, load_norm: float) -> float:
        """Estimated round-off floor of ``‖R(ζ)‖`` at the current iterate.

        ``u (‖f‖ + ‖S‖)`` with ``S = (1/κ) Mᵀ (χ_A · (|θ·q| + Σ_j |ζ_j c_j|))``: the rounding
        of the terms of ``g`` amplified by the penalty.
        """
        active = np.flatnonzero(self._g < 0)
        values = np.zeros_like(self._g)
        values[active] = self.penalty.gap_scale(self.problem.zeta.x.petsc_vec, active)
        S = self.R.duplicate()
        S.set(0.0)
        self.penalty.add_residual(values, self.kappa, S)
        norm = S.norm()
        S.destroy()
        return self._floor_of(load_norm, norm)

    def _floor_of(self, load_norm: float, penalty_norm: float) -> float:
        """``floor_factor · u · (‖f‖ + ‖S‖)`` (:meth:`_floor`)."""
        return (
            self.options.floor_factor * np.finfo(PETSc.ScalarType).eps * (load_norm + penalty_norm)
        )

    def _direction(self) -> None:
        """``δ ← A⁻¹ (−R)`` (``self.R`` holds ``−R``).

        With a kept factorization of another Jacobian at this κ, conjugate gradients
        preconditioned by it; if they do not converge in ``reuse_max_iterations``, a new
        factorization.
        """
        if self.zone is not None:
            zone = self.zone
            before = zone.builds, dict(zone.timings)
            zone.prepare(self._g < 0, self._hint)
            self.ksp.getPC().setUp()  # S for the current Jacobian (if it changed)
            zone.newton_step(self.R, self.problem.zeta.x.petsc_vec, self.dz)
            self.factorizations += zone.builds - before[0]
            if zone.whole:
                self.factorizations += 1
            for key, value in zone.timings.items():
                self.timings[key] += value - before[1][key]
            self._factored_kappa = self.kappa
        elif not self.reuse:
            if self.options.linear_solver == "direct":
                self._factorize()
            self._solve_direction(self.R)
            self._factored_kappa = self.kappa  # the preconditioner held is for this κ
        else:
            if self._factored_kappa is None or self._active_set_moved():
                self._factorize()
            self.ksp.solve(self.R, self.dz)
            if self.ksp.getConvergedReason() < 0:
                self._reuse_failures += 1
                self._factorize()
                self.ksp.solve(self.R, self.dz)
        self.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def _forcing(self, norms: list[float], target: float) -> float:
        """CG's relative tolerance ``η_k`` for the next direction (``NewtonOptions.forcing``).

        Eisenstat–Walker choice 2, ``η_k = γ (‖R_k‖/‖R_{k−1}‖)^α`` with ``γ = 0.9``, ``α = 2``,
        kept above ``γ η_{k−1}^α`` when that exceeds 0.1 (no sudden drop), at most
        ``η_max = 0.1`` (also the first ``η`` of a cold start; ``WARM_FORCING`` for the first
        step from an iterate with contact), at least ``target / (2 ‖R_k‖)`` (a linear
        residual below half the stopping threshold is invisible to Newton's test) and at least
        ``linear_rtol``.
        """
        opts = self.options
        if opts.forcing == "fixed":
            return opts.linear_rtol
        gamma, alpha, eta_max = 0.9, 2.0, 0.1
        eta = eta_max
        if len(norms) == 1 and self._contact():
            eta = WARM_FORCING
        if len(norms) >= 2 and self._eta is not None and norms[-2] > 0.0:
            eta = gamma * (norms[-1] / norms[-2]) ** alpha
            previous = gamma * self._eta**alpha
            if previous > 0.1:
                eta = max(eta, previous)
            eta = min(eta, eta_max)
        if norms[-1] > 0.0:
            eta = max(eta, 0.5 * target / norms[-1])
        self._eta = min(max(eta, opts.linear_rtol), eta_max)
        return self._eta

    def _contact(self) -> bool:
        """Whether the current iterate penetrates anywhere (collective)."""
        return self.problem.mesh.comm.allreduce(bool((self._g < 0).any()), op=MPI.LOR)

    def _solve_direction(self, b: PETSc.Vec) -> None:
        """``δ ← A⁻¹ b`` by the KSP; with the iterative solver GAMG's hierarchy on ζ_α is
        kept from an earlier direction (Jacobi on ζ_3 and the coupling block are always
        those of the current Jacobian: :meth:`_solve_split`).

        Between Newton steps at one κ the ζ_α block changes only by the penalty's
        ``(1/κ) c_α c_β`` terms at the points that changed activity; the paper's problem
        took the same CG iterations at every step with the kept hierarchy as with a new one,
        for about a quarter less time (docs/performance.md, seventh session). A new κ scales
        those terms; on the paper's problem, where ``c_α`` is small in the contact region,
        the hierarchy kept across κ gave the same iterations too (fourteenth session). With
        ``keep_multigrid`` it is kept while :meth:`_multigrid_drift` stays small, else built
        at every κ's first direction.
        """
        if self.options.linear_solver != "iterative":
            self.ksp.solve(b, self.dz)
            return
        diagonal = self._diagonal()
        if self._multigrid_kappa is None:
            build = True
        elif self.options.keep_multigrid:
            build = self._multigrid_drift(diagonal[:, :2]) > MULTIGRID_DRIFT
        else:
            build = self._multigrid_kappa != self.kappa
        self._solve_split(b, build, diagonal)
        if not build and self.ksp.getConvergedReason() < 0:
            self._rejected_iterations += self.ksp.getIterationNumber()
            self._solve_split(b, True, diagonal)
        self._multigrid_most = max(self._multigrid_most, self.ksp.getIterationNumber())

    def _solve_split(self, b: PETSc.Vec, build: bool, diagonal: np.ndarray) -> None:
        """One solve with the field split, building GAMG's hierarchy anew if ``build``
        (``diagonal``: the current Jacobian's, :meth:`_diagonal`).

        The split's blocks are not extracted from the Jacobian at every set-up (PETSc's
        default): after the first, the ζ_α block, GAMG's finest level, is refreshed at a
        build only (between builds its diagonal drifts by at most ``MULTIGRID_DRIFT``), and
        the ζ_3 block, where Jacobi reads only the diagonal, gets the current diagonal. The
        coupling block the sweep multiplies by is still the current Jacobian's.
        """
        if self._split is not None:  # (the split exists after its first set-up)
            is_alpha, P_alpha, P_3, d_3 = self._blocks
            if build:
                self.A.createSubMatrix(is_alpha, is_alpha, submat=P_alpha)
            d_3.array[:] = diagonal[:, 2]
            P_3.setDiagonal(d_3)
            self._split[0].getPC().setReusePreconditioner(not build)
        max_it = self.ksp.getTolerances()[3]
        if not build:  # a kept hierarchy that stagnates is given up early
            cap = max(KEPT_MIN_ITERATIONS, KEPT_ITERATION_FACTOR * self._multigrid_most)
            self.ksp.setTolerances(max_it=min(max_it, cap))
        self.ksp.solve(b, self.dz)
        self.ksp.setTolerances(max_it=max_it)
        if self._split is None:
            self._split = self.ksp.getPC().getFieldSplitSubKSP()
            self._blocks = self._hold_blocks()
        if build:
            self._multigrid_kappa = self.kappa
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

    def _diagonal(self) -> np.ndarray:
        """The current Jacobian's diagonal at the owned dofs, one row ``(ζ_1, ζ_2, ζ_3)`` per
        node."""
        d = self.A.getDiagonal()
        values = d.array_r.reshape(-1, 3).copy()
        d.destroy()
        return values

    def _multigrid_drift(self, diagonal: np.ndarray) -> float:
        """``max |d_i − d_i⁰| / |d_i⁰|`` over the ζ_α diagonal ``d`` of the Jacobian against
        ``d⁰`` at the hierarchy's build (collective).

        The kept hierarchy's smoothers are Chebyshev–Jacobi with the diagonal and the
        eigenvalue bounds of the build (the upper one 10 % above the estimate): a Jacobian
        whose diagonal moved by more than a few percent can leave those bounds.
        """
        d0 = self._multigrid_diagonal
        local = float(np.max(np.abs(diagonal - d0) / np.abs(d0), initial=0.0))
        return self.problem.mesh.comm.allreduce(local, op=MPI.MAX)

    def _active_set_moved(self) -> bool:
        """Whether more points changed activity since the factorization than CG may iterate."""
        changed = int(np.count_nonzero(self._factored_active != (self._g < 0)))
        return self.problem.mesh.comm.allreduce(changed) > self.options.reuse_max_iterations

    # -- the contact zone as state (checkpoints) --------------------------------------------
    def zone_indicator(self) -> dolfinx.fem.Function | None:
        """The kept contact zone as a 0/1 function on the displacement space (or None).

        A resumed sweep restores it (:meth:`set_zone_indicator`) so that its iterates are
        those of the uninterrupted run: to the last bit serially; under MPI to round-off, as
        MUMPS' parallel factorization itself does not repeat its last bits from run to run (on
        3 or more ranks, on 2 ranks for large problems, and now and then on 2 ranks for small
        ones: once in about a dozen runs of the tests' 3k-dof problem).
        """
        zone = self.zone
        if zone is None or zone.Z is None:
            return None
        u = dolfinx.fem.Function(self.problem.V)
        u.x.petsc_vec.array[zone.owned_zone()] = 1.0
        u.x.scatter_forward()
        return u

    def set_zone_indicator(self, u: dolfinx.fem.Function) -> None:
        """Make the dofs where ``u`` is 1 the contact zone (collective)."""
        if self.zone is None:
            return
        self.zone.set_owned_zone(np.flatnonzero(u.x.petsc_vec.array_r > 0.5))

    @property
    def predicts(self) -> bool:
        """Whether :meth:`predict` is on (``NewtonOptions.euler_predictor``)."""
        choice = self.options.euler_predictor
        if choice is None:
            return self.options.linear_solver == "direct" and not self.reduced
        return choice

    def predict(self, kappa_new: float) -> bool:
        """Euler predictor along κ: ``ζ ← ζ + (κ_new − κ) dζ/dκ`` with ``J dζ/dκ = −∂R/∂κ``.

        ``∂R/∂κ = −(1/κ²) Mᵀ min(g, 0)`` and ``J`` is approximated by the factorization kept
        from the last solve, so the prediction costs one back-substitution (or a few
        preconditioned CG iterations; with ``zone_newton`` see :meth:`_zone_predict`).
        Returns False (and changes nothing) when no factorization for the current κ exists
        or the predictor is off (``NewtonOptions.euler_predictor``).
        """
        kappa = self.kappa
        if self._factored_kappa != kappa or not self.predicts:
            return False
        if self.reduced:
            return self._zone_predict(kappa_new)
        t0 = time.perf_counter()
        b = self.R.duplicate()
        b.set(0.0)
        self.penalty.add_residual(np.minimum(self._g, 0.0), kappa * kappa, b)  # −∂R/∂κ
        if self.reuse:  # the Jacobian at ζ for the CG that reuses the factorization
            self._jacobian()
        if self.zone is not None:
            self.zone.prepare(self._g < 0, None)
        opts = self.options
        if opts.linear_solver == "iterative" and opts.forcing != "fixed":
            self.ksp.setTolerances(rtol=max(opts.linear_rtol, PREDICTOR_RTOL))
        self.ksp.solve(b, self.dz)
        ok = self.ksp.getConvergedReason() > 0
        b.destroy()
        if ok:
            self._euler_step(kappa_new - kappa)
        self.timings["predict"] = self.timings.get("predict", 0.0) + time.perf_counter() - t0
        return ok

    def _euler_step(self, dkappa: float) -> None:
        """``ζ ← ζ + Δκ δ`` with ``δ = dζ/dκ`` in ``self.dz``."""
        self.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        zeta = self.problem.zeta
        with self.dz.localForm() as dz_loc:
            zeta.x.array[:] += dkappa * dz_loc.array_r
        zeta.x.scatter_forward()

    # -- Newton on the zone's own problem -------------------------------------------------------
    def _zone_ready(self) -> bool:
        """Whether the next steps can be taken on the zone's problem (collective).

        Makes the zone hold the current active points first (builds it once contact appears);
        without contact and without a zone, the step is a full one.
        """
        zone = self.zone
        if not self.reduced or zone is None:
            return False
        comm = self.problem.mesh.comm
        active = self._g < 0
        if not zone.usable:
            if zone.whole:
                return False
            if not comm.allreduce(bool(active.any()), op=MPI.LOR):
                if zone.Z is not None or not self.options.seed_zone:
                    return False  # no contact: a full step
                self._hint = self._coarse_hint()
                if not comm.allreduce(bool(self._hint.any()), op=MPI.LOR):
                    return False  # no contact expected either
        t0, before, builds = time.perf_counter(), dict(zone.timings), zone.builds
        zone.prepare(active, self._hint)
        self.factorizations += zone.builds - builds  # (each build factorizes K_II)
        for key, value in zone.timings.items():
            self.timings[key] += value - before[key]
        spent = time.perf_counter() - t0 - sum(zone.timings[k] - before[k] for k in before)
        self.timings["zone"] += spent
        return zone.usable

    def _coarse_hint(self) -> np.ndarray:
        """The points that ``ζ + δ̃`` penetrates, ``δ̃`` a coarse-grid approximation of the
        Newton step ``K⁻¹(−R(ζ))`` at an iterate without contact."""
        t0 = time.perf_counter()
        problem = self.problem
        coarse = CoarseSpace(problem.V, self.K, problem.bcs)
        r = self.R.copy()
        r.scale(-1.0)
        coarse.solve(r, self.dz)
        hint = self._g + self.penalty.apply_B(self.dz) < 0
        r.destroy()
        coarse.destroy()
        self.timings["coarse"] = self.timings.get("coarse", 0.0) + time.perf_counter() - t0
        return hint

    def _active_seed(self) -> np.ndarray | None:
        """Gaps for the first Jacobian of the iterative solver (``NewtonOptions.seed_active``).

        At an iterate without contact the Jacobian is ``K`` and the Newton step overshoots
        into the obstacle, the line search cuts it short, and the active set then grows over
        many damped steps. Instead the first step goes to the minimizer of the model whose
        active points ``Ã`` are those a coarse-grid approximation of ``K⁻¹(−R)`` penetrates
        (:meth:`_coarse_hint`, :meth:`_seed_direction`), as the direct solver's seeded zone
        does (:meth:`_zone_seed`); the exact line search guards it. Measured on the paper's
        problem at the first κ = h^0.5 of the continuation: 9 Newton steps instead of 11 at
        111k and 326k dofs, 11 instead of 15 at 1.92 M. From a cold start at a small κ the
        seed's pinned points push their neighbours through the obstacle and the line search
        cuts the step short: no gain there, or a loss (κ = h at 111k: 22 steps against 21).
        Only for a solve's first step (a seeded step that stops short of the obstacle would
        be followed by the same step again); None (the usual step) with contact, without a
        coarse penetration, or not asked.
        """
        opts = self.options
        if opts.linear_solver != "iterative" or not opts.seed_active:
            return None
        comm = self.problem.mesh.comm
        if self._contact():
            return None
        hint = self._coarse_hint()
        if not comm.allreduce(bool(hint.any()), op=MPI.LOR):
            return None
        return np.where(hint, -1.0, self._g)

    def _seed_residual(self, seed: np.ndarray) -> PETSc.Vec:
        """``−∇q_Ã(ζ) = −R(ζ) − (1/κ) Mᵀ (χ_Ã g)``: minus the gradient of the model whose
        active points are the seed's ``Ã`` (``self.R`` holds ``−R``, which has no penalty
        part at an iterate without contact)."""
        b = self.R.copy()
        self.penalty.add_residual(-np.where(seed < 0, self._g, 0.0), self.kappa, b)
        return b

    def _seed_direction(self, seed: np.ndarray) -> int:
        """``δ ← −(K + P_Ã)⁻¹ ∇q_Ã``, the step to the seeded model's minimizer (the Jacobian
        holds ``P_Ã`` already); if it is not a descent direction of ``J_κ`` (or CG failed),
        the usual Newton step instead. Returns the CG iterations of a discarded seeded solve.
        """
        b = self._seed_residual(seed)
        self._solve_direction(b)
        b.destroy()
        if self.ksp.getConvergedReason() > 0 and self.R.dot(self.dz) > 0:  # −R·δ > 0
            self.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            self._factored_kappa = self.kappa
            return 0
        discarded = self.ksp.getIterationNumber()
        ta = time.perf_counter()
        self._jacobian()
        self.timings["assemble"] += time.perf_counter() - ta
        self._direction()
        return discarded

    @property
    def _zone_budget(self) -> int:
        """CG iterations (and changed points) allowed when reusing the zone's ``S``."""
        opts = self.options
        return opts.reuse_max_iterations if opts.reuse_factorization else 0

    def _zone_newton(
        self,
        result: NewtonResult,
        scale: float,
        ref: float,
        progress: Callable[[int, float], Any] | None,
    ) -> float:
        """Newton steps on the zone's problem, then ``ζ_I`` by one back-substitution.

        While no point outside the zone is active, ``ζ_I = K_II⁻¹ (f_I − K_IZ ζ_Z)`` minimizes
        ``J_κ`` over ``ζ_I`` and leaves ``j(ζ_Z) = ½ ζ_Zᵀ (K_ZZ − T) ζ_Z − f̃·ζ_Z`` plus the
        penalty at the zone's points (:mod:`shellobstacle.solvers.contact_zone`). From an
        iterate with ``R_I = 0`` a Newton step of ``J_κ`` is ``S δ_Z = −∇j``,
        ``δ_I = −K_II⁻¹ K_IZ δ_Z``, and its exact line search is that of ``j``: these are
        Newton steps of ``J_κ`` that need only the zone's Schur complement ``S`` and no
        back-substitution. Their residual ``∇j(ζ_Z)`` is ``R(ζ)`` on the zone (it vanishes
        on ``I``). At the end ``ζ_I`` is formed and ``R(ζ)`` computed in full: if a point
        outside the zone became active, the caller takes a full step, which grows the zone.

        Returns:
            ``‖R(ζ)‖`` of the completed iterate (also the last entry of the history).
        """
        zone, opts, kappa = self.zone, self.options, self.kappa
        assert zone is not None
        t0 = time.perf_counter()
        c0 = zone.timings["condense"]
        zeta = self.problem.zeta
        z, r, d = zone.zone_vector(), zone.zone_vector(), zone.zone_vector()
        zone.gather(zeta.x.petsc_vec, z)
        g = zone.zone_residual(z, kappa, r)
        rnorm = r.norm()
        seed = self._zone_seed(g)
        while result.iterations < opts.max_iterations:
            if rnorm <= max(opts.atol, opts.rtol * scale):
                break
            floor = self._zone_floor(z, g, ref)
            if rnorm <= floor:
                break
            cg = -1
            if seed is not None:  # towards the minimizer of the model whose active set is seed
                cg = self._zone_seed_step(seed, g, r, d)
                seed = None
                if not r.dot(d) < -floor * d.norm():
                    cg = -1  # no descent: the usual Newton step instead
            if cg < 0:
                r.scale(-1.0)
                cg = zone.zone_newton_solve(g, kappa, r, d, self._zone_budget, opts.linear_rtol)
                r.scale(-1.0)
            self._factored_kappa = kappa
            slope0 = r.dot(d)
            small_step = d.norm(PETSc.NormType.NORM_INFINITY) <= opts.stol * z.norm(
                PETSc.NormType.NORM_INFINITY
            )
            if small_step:
                t = 1.0
            else:
                noise = floor * d.norm()
                if not slope0 < -noise:  # no verifiable descent: the full step decides
                    break
                t, evals = self._zone_line_search(g, d, slope0, noise)
                result.line_search_evaluations += evals
            z.axpy(t, d)
            g = zone.zone_residual(z, kappa, r)
            rnorm = r.norm()
            result.iterations += 1
            result.zone_steps += 1
            result.residual_norms.append(rnorm)
            result.step_lengths.append(t)
            result.linear_iterations.append(max(cg, 1))
            if progress is not None:
                progress(result.iterations, rnorm / scale)
            if small_step:
                break
        ts = time.perf_counter()
        zone.extend(z, zeta.x.petsc_vec, load=True)
        zeta.x.scatter_forward()
        self.timings["solve"] += time.perf_counter() - ts
        ta = time.perf_counter()
        self._residual()
        self._hint = None
        rnorm = self.R.norm()
        result.residual_norms[-1] = rnorm  # the completed iterate's residual
        for vec in (z, r, d):
            vec.destroy()
        te, condense = time.perf_counter(), zone.timings["condense"] - c0
        self.timings["assemble"] += te - ta
        self.timings["condense"] += condense
        self.timings["zone_newton"] += te - t0 - (te - ts) - condense
        return rnorm

    def _zone_seed(self, g: np.ndarray) -> np.ndarray | None:
        """The points that the seed of the zone penetrates, among the zone's (the same on
        every rank), when the iterate touches none of them (a solve from ζ = 0); else None.

        Newton steps from an iterate without contact take the active set from that iterate
        (empty) and then grow it with short damped steps (exact-line-search lengths 0.47,
        0.02, 0.03, 0.16, … on the paper's problem at 326k dofs). Starting from the minimizer
        of the model whose active set is the seed's points (18,746 there, against 17,756 at
        the solution), the steps only released points, all of full length: 8 Newton steps at
        the first κ instead of 10 (9 instead of 13 at 1.92 M dofs). The exact line search
        guards the step; one that does not descend is replaced by the usual Newton step.
        """
        zone, comm = self.zone, self.problem.mesh.comm
        if self._hint is None or comm.allreduce(bool((g < 0).any()), op=MPI.LOR):
            return None
        seed = np.concatenate(comm.allgather(self._hint[np.flatnonzero(zone.points)]))
        return seed if seed.any() else None

    def _zone_seed_step(self, seed: np.ndarray, g: np.ndarray, r: PETSc.Vec, d: PETSc.Vec) -> int:
        """``d ← −S_A⁻¹ ∇q_A``: the step to the minimizer of the zone's energy with the
        penalty ``(1/(2κ)) Σ_{p ∈ A} D_p g_p²`` on the points ``A = seed``, from an iterate
        where no point has ``g < 0`` (so ``r = ∇j`` holds no penalty and
        ``∇q_A = r + (1/κ) M_Pᵀ (g on A)``). Returns the CG iterations (0: factorized).
        """
        zone, kappa, opts = self.zone, self.kappa, self.options
        rA = r.copy()
        zone.add_zone_penalty(np.where(seed, g, 0.0), kappa, rA)
        rA.scale(-1.0)
        active = np.where(seed, -1.0, 1.0)  # S with the seed's points active
        cg = zone.zone_newton_solve(active, kappa, rA, d, self._zone_budget, opts.linear_rtol)
        rA.destroy()
        return cg

    def _zone_floor(self, z: PETSc.Vec, g: np.ndarray, ref: float) -> float:
        """:meth:`_floor` for the zone's problem (the active points are the zone's)."""
        zone = self.zone
        scale = zone.zone_gap_scale(z)
        S = z.duplicate()
        S.set(0.0)
        zone.add_zone_penalty(np.where(g < 0, scale, 0.0), self.kappa, S)
        norm = S.norm()
        S.destroy()
        return self._floor_of(ref, norm)

    def _zone_line_search(
        self, g: np.ndarray, d: PETSc.Vec, slope0: float, noise: float
    ) -> tuple[float, int]:
        """:meth:`_line_search` for the zone's problem (the same step length on every rank)."""
        zone = self.zone
        zone.MP.mult(d, zone.wP)
        Md = zone.wP.array_r.copy()
        Kd = d.duplicate()
        zone.Ks.mult(d, Kd)
        curvature = Kd.dot(d)
        Kd.destroy()
        step = self._exact_step(g, Md, Md / zone.DP, curvature, slope0, noise, lambda x: x)
        return self.problem.mesh.comm.bcast(step, root=0)

    def _exact_step(
        self,
        g: np.ndarray,
        Md: np.ndarray,
        Bd: np.ndarray,
        curvature: float,
        slope0: float,
        noise: float,
        total: Callable[[float], float],
    ) -> tuple[float, int]:
        """The root of ``φ'(t) = φ'_el(0) + t δᵀKδ + (1/κ) (Mδ)·min(g + t Bδ, 0)`` in ``[0, 1]``.

        ``total`` sums a point sum over the ranks (or not, for points held by every rank).
        """
        kappa = self.kappa
        elastic0 = slope0 - total(float(np.dot(Md, np.minimum(g, 0.0)))) / kappa

        def slope(t: float) -> float:
            local = float(np.dot(Md, np.minimum(g + t * Bd, 0.0)))
            return elastic0 + t * curvature + total(local) / kappa

        return piecewise_linear_root(slope, slope0, max(1e-10 * abs(slope0), noise))

    def _zone_predict(self, kappa_new: float) -> bool:
        """:meth:`predict` through the zone: ``∂R/∂κ`` lives on the zone's points, so
        ``dζ_Z/dκ`` is one solve with the zone's Jacobian ``S`` at ``ζ`` (conjugate gradients
        preconditioned by the kept factorization) and ``dζ_I/dκ = −K_II⁻¹ K_IZ dζ_Z/dκ`` one
        back-substitution."""
        zone, kappa = self.zone, self.kappa
        if zone is None or not zone.usable or not zone.factored:
            return False
        t0 = time.perf_counter()
        z, b, d = zone.zone_vector(), zone.zone_vector(), zone.zone_vector()
        zone.gather(self.problem.zeta.x.petsc_vec, z)
        b.set(0.0)
        g = zone.zone_gap(z)
        zone.add_zone_penalty(np.minimum(g, 0.0), kappa * kappa, b)  # −∂∇j/∂κ
        zone.zone_newton_solve(g, kappa, b, d, self._zone_budget, self.options.linear_rtol)
        zone.extend(d, self.dz, load=False)
        for vec in (z, b, d):
            vec.destroy()
        self._euler_step(kappa_new - kappa)
        self.timings["predict"] = self.timings.get("predict", 0.0) + time.perf_counter() - t0
        return True

    # -- line search --------------------------------------------------------------------------
    def _line_search(self, slope0: float, noise: float) -> tuple[float, int]:
        """Exact step along δ: the root of ``φ'(t) = R(ζ + tδ)·δ`` (round-off aware).

        ``φ'(t) = R_el(ζ)·δ + t δᵀKδ + (1/κ) (Mδ)·min(g + t Bδ, 0)``: the membrane part is
        linear in ``t`` and the penalty part a sum over the quadrature points. ``g + t Bδ`` is
        affine in ``t``, so only the points with ``g < 0`` or ``g + Bδ < 0`` can contribute on
        ``[0, 1]``: the sums run over those (a few percent of the 7.7 M points at 1.9 M dofs).
        """
        pen = self.penalty
        self._Bd = Bd = pen.apply_B(self.dz)  # (kept for the residual after the step)
        self.K.mult(self.dz, self.Kdz)
        curvature = self.Kdz.dot(self.dz)
        total = self.problem.mesh.comm.allreduce
        g = self._g
        near = np.flatnonzero((g < 0) | (g + Bd < 0))
        Bd = Bd[near]
        return self._exact_step(g[near], pen.D[near] * Bd, Bd, curvature, slope0, noise, total)

    # -- Newton -------------------------------------------------------------------------------
    def solve(self, progress: Callable[[int, float], Any] | None = None) -> NewtonResult:
        """Solve the penalized problem for the current ``κ``, starting from ``problem.zeta``.

        Returns:
            The :class:`NewtonResult` (``problem.zeta`` holds the solution).

        Raises:
            ConvergenceError: after ``max_iterations``, on a failed linear solve or on NaN; the
                last iterate is left in ``problem.zeta`` and the history in ``err.result``.
        """
        opts, problem = self.options, self.problem
        zeta = problem.zeta
        t_start = time.perf_counter()
        dolfinx.fem.petsc.set_bc(zeta.x.petsc_vec, problem.bcs)  # homogeneous bcs on the start
        zeta.x.scatter_forward()
        result = NewtonResult(False, 0, "")
        self.factorizations, self._reuse_failures = 0, 0
        # every solve starts with a new factorization, so its result depends only on the
        # start ζ and not on earlier solves (resumed runs repeat uninterrupted ones exactly)
        self._factored_kappa = None
        self._eta = None  # the last forcing term (iterative solver)
        self._hint = None  # (the zone itself is kept: it depends on the mesh, not on κ)
        if self.zone is not None:
            self.zone.forget_factorization()
        ta = time.perf_counter()
        self._load()
        if self.zone is not None:
            self.zone.set_load(self.f)
        ref = self.f.norm()
        self._residual()
        self.timings["assemble"] += time.perf_counter() - ta
        rnorm = self.R.norm()
        result.residual_norms.append(rnorm)
        scale = ref if ref > 0.0 else 1.0
        result.reference = ref
        just_reduced = False  # the last iterations were on the zone's problem
        while True:
            if not math.isfinite(rnorm):
                result.reason = "residual is not finite (NaN/Inf)"
                break
            if rnorm <= max(opts.atol, opts.rtol * scale):
                result.converged, result.reason = True, "relative residual below rtol"
                break
            floor = self._floor(ref)
            if rnorm <= floor:
                result.converged, result.reason = True, "residual at its round-off floor"
                break
            if result.iterations >= opts.max_iterations:
                result.reason = f"no convergence in {opts.max_iterations} Newton iterations"
                break
            if not just_reduced and self._zone_ready():
                rnorm = self._zone_newton(result, scale, ref, progress)
                just_reduced = True
                continue
            # a full Newton step (no zone yet, a zone too large, or an active point outside it)
            just_reduced = False
            it = result.iterations + 1
            seed = self._active_seed() if result.iterations == 0 else None
            ta = time.perf_counter()
            self._jacobian(seed)
            self.timings["assemble"] += time.perf_counter() - ta
            if opts.linear_solver == "iterative":
                target = max(opts.atol, opts.rtol * scale, floor)
                self.ksp.setTolerances(rtol=self._forcing(result.residual_norms, target))
            ts = time.perf_counter()
            self.R.scale(-1.0)
            apart = ("factorize", "zone", "condense")
            before = sum(self.timings[k] for k in apart)
            discarded = 0  # CG iterations of a seeded direction that did not descend
            if seed is None:
                self._direction()
            else:
                discarded = self._seed_direction(seed)
            self.timings["solve"] += time.perf_counter() - ts
            self.timings["solve"] -= sum(self.timings[k] for k in apart) - before
            if self.zone is not None:
                self._hint = (self._g + self.penalty.apply_B(self.dz)) < 0
            if self.zone is not None:  # an exact solve, not a Krylov method
                result.linear_iterations.append(1)
            else:
                result.linear_iterations.append(
                    self.ksp.getIterationNumber() + discarded + self._rejected_iterations
                )
            self._rejected_iterations = 0
            if self.zone is None and self.ksp.getConvergedReason() < 0:
                result.reason = (
                    f"linear solver failed (PETSc reason {self.ksp.getConvergedReason()})"
                )
                break
            slope0 = -self.R.dot(self.dz)  # R·δ = −δᵀAδ < 0
            tl = time.perf_counter()
            step = self.dz.norm(PETSc.NormType.NORM_INFINITY)
            unorm = zeta.x.petsc_vec.norm(PETSc.NormType.NORM_INFINITY)
            small_step = step <= opts.stol * unorm
            if small_step:  # take the (tiny) full step, then stop: nothing left to gain
                t, evals = 1.0, 0
            elif slope0 >= 0 or not math.isfinite(slope0):
                result.reason = f"not a descent direction (R·δ = {slope0:.3e})"
                break
            else:
                noise = floor * self.dz.norm()  # |round-off in φ'(t)| ≲ ‖R_floor‖ ‖δ‖
                if -slope0 <= noise:
                    # The Newton decrement δᵀAδ is below the round-off of φ': no step can be
                    # verified to decrease J_κ. ζ is the solution to working precision.
                    result.converged = True
                    result.reason = "Newton decrement below the round-off of the energy slope"
                    break
                t, evals = self._line_search(slope0, noise)
            with self.dz.localForm() as dz_loc:
                zeta.x.array[:] += t * dz_loc.array_r
            zeta.x.scatter_forward()
            if small_step:
                self._residual()
            else:  # Kδ and Bδ are the line search's
                self._residual_after_step(t)
            self.timings["line_search"] += time.perf_counter() - tl
            result.line_search_evaluations += evals
            result.step_lengths.append(t)
            result.iterations = it
            rnorm = self.R.norm()
            result.residual_norms.append(rnorm)
            if progress is not None:
                progress(it, rnorm / scale)
            if small_step:
                result.converged, result.reason = True, "Newton correction below stol"
                break
        result.factorizations = self.factorizations
        result.timings = {"total": time.perf_counter() - t_start}
        if not result.converged:
            if not result.reason:
                result.reason = "stopped"
            raise ConvergenceError(
                f"Newton did not converge for kappa = {float(problem.kappa.value):.3e}: "
                f"{result.reason}; relative residual {rnorm / scale:.3e} after "
                f"{result.iterations} iterations",
                result,
            )
        return result
