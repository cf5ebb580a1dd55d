"""The Brezis–Sibony iteration for the penalized problem (docs/model.md §6, the paper's (38)).

With ``R(ψ)`` the residual vector of the discrete penalized problem (the ``"residual"`` form of
:class:`~shellobstacle.models.problem.PenalizedProblem`:
``A_h ψ + (ε/κ) P_h β(ψ) − P_h(p√a)`` tested
against the basis of ``V_h``) and ``M`` the mass matrix of ``V_h``, the paper's operator is
``N_h(ψ) = M⁻¹ R(ψ)`` and the iteration (38) reads

.. math:: ψ_{k+1} = ψ_k − τ M^{-1} R(ψ_k), \\qquad τ = Ξ h^4 .

Dirichlet dofs carry identity rows (and columns) in ``M`` and zero rows in ``R``, so ``ψ``
stays 0 on them.

**Residual.** A step does not assemble the residual form: ``R(ψ) = Kψ − L + (1/κ) Mᵀ min(g, 0)``
from the stiffness matrix ``K`` and the penalty's point matrix ``M``
(:class:`~shellobstacle.solvers.quadrature_penalty.QuadraturePenalty`, the operators
:class:`~shellobstacle.solvers.newton.solver.NewtonSolver` uses), which is the form's vector up to
round-off (tested) for a fraction of the cost: a product with ``K``, one with the point
matrix and one with its stored transpose. The mass matrix is factorized once by Cholesky
(PETSc's own serially, MUMPS under MPI). A step costs a fraction of an assembly of the
residual form (docs/perf/brezis-sibony.md).

**Step and contraction.** ``R`` is piecewise linear: at every penalty quadrature point
``min(g, 0)`` is a piecewise-linear function of the affine gap ``g(ψ)``, so
``R(ψ) − R(φ) = J̄ (ψ − φ)`` exactly, with ``J̄ = K + (ε/κ) Σ_x w_x θ_x (c·)(c·)/|c|``,
``K`` the elastic matrix and ``θ_x ∈ [0, 1]``. Hence ``K ≤ J̄ ≤ K + P_all`` (Loewner order),
``P_all`` being the penalty Jacobian with *every* penalty point active. The Jacobian at the
start would not do: the penalty part changes with ``ψ``. In the ``M``-norm (the L² norm of
``V_h``) the error and the increments therefore contract at every step by at most

.. math:: ρ = \\max(|1 − τ λ_{min}|, |1 − τ λ_{max}|),

with ``λ_min`` the smallest eigenvalue of ``K v = λ M v`` and ``λ_max`` the largest of
``(K + P_all) v = λ M v`` (both on the free dofs). The automatic step is
``τ = 2 / (λ_max (1 + s))`` with a safety ``s`` (SLEPc's Ritz value approaches ``λ_max``
from below), so ``ρ = 1 − τ λ_min`` and ``Ξ = τ / h⁴`` is reported. ``ρ`` is a computable
value of Theorem 9.1's factor ``(1 − ρ')^{1/2}``, and ``ρ/(1 − ρ) ‖ψ_{k+1} − ψ_k‖`` bounds the
error left. Since ``λ_max / λ_min`` grows like ``h⁻²`` (or like
``1/κ`` once the penalty dominates), the number of iterations grows like ``h⁻²``: the paper's
"very slow" warning.

**Mass.** ``mass="consistent"`` is the paper's ``M`` (factorized once by MUMPS);
``mass="lumped"`` replaces it by its row sums (a diagonal scaling; a deviation from the paper,
P1 only: the row sums of P2 vanish at the vertices). With the lumped mass every L² norm
above is the lumped one.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from mpi4py import MPI  # noqa: F401  (before PETSc: the MPI runtime it links to)
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np
import ufl

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.base import (
    ConvergenceError,
    UserOptions,
    direct_solver,
    with_user_options,
)
from shellobstacle.solvers.brezis_sibony.options import BrezisSibonyOptions
from shellobstacle.solvers.brezis_sibony.result import BrezisSibonyResult
from shellobstacle.solvers.quadrature_penalty import QuadraturePenalty, penalty_hessian
from shellobstacle.solvers.spectrum import extreme_eigenvalue

__all__ = ["BrezisSibonySolver"]

Progress = Callable[[int, float], Any]


class BrezisSibonySolver:
    """The iteration (38) for one :class:`PenalizedProblem` on a mesh of size ``h``.

    The mass matrix is assembled and factorized once (or lumped once), and the stiffness
    and the penalty's point matrix are assembled once; each step forms the residual from
    them (module docstring), applies ``M⁻¹`` and updates ``problem.zeta``.
    ``κ`` is read from ``problem.kappa`` at every :meth:`solve` (the spectrum is re-estimated
    when it changed). Collective under MPI.

    Args:
        problem: the compiled penalized problem; ``problem.zeta`` is the iterate.
        h: the mesh size in ``τ = Ξ h⁴`` (the caller's ``h``, e.g. the largest cell diameter).
        options: step, mass, start and stopping rules.
    """

    def __init__(
        self,
        problem: PenalizedProblem,
        h: float,
        options: BrezisSibonyOptions | None = None,
    ) -> None:
        if not h > 0:
            raise ValueError(f"the mesh size h must be > 0, got {h}")
        self.problem = problem
        self.h = float(h)
        self.options = opts = options or BrezisSibonyOptions()
        kinds = ("bs_mass", "bs_linearized")
        self.user_options = UserOptions(
            opts.petsc_options, kinds, "brezis-sibony", problem.mesh.comm
        )
        V, mesh = problem.V, problem.mesh
        self.comm = mesh.comm
        degree = problem.disc.degree
        if opts.mass == "lumped" and degree != 1:
            raise ValueError(
                "mass = 'lumped' needs P1 (the row sums of the P2 mass matrix vanish at vertices)"
            )
        u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
        dx_mass = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": 2 * degree})

        # the mass matrix (identity rows/columns at Dirichlet dofs) or its row sums
        bcs = problem.bcs
        self.M = dolfinx.fem.petsc.assemble_matrix(
            dolfinx.fem.form(ufl.inner(u, v) * dx_mass), bcs=bcs, diag=1.0
        )
        self.M.assemble()
        self.free = dolfinx.fem.petsc.create_vector(V)  # 1 at free dofs, 0 at Dirichlet dofs
        self.free.set(1.0)
        dolfinx.fem.petsc.set_bc(self.free, bcs)
        self.D: PETSc.Vec | None = None
        self.ksp: PETSc.KSP | None = None
        if opts.mass == "lumped":
            ones = ufl.as_vector([1.0, 1.0, 1.0])
            D = dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(ufl.inner(ones, v) * dx_mass))
            D.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            D.pointwiseMult(D, self.free)
            D.axpy(1.0, self._one_minus_free())  # 1 at Dirichlet dofs
            if D.min()[1] <= 0.0:
                raise ValueError("the lumped mass has a non-positive entry")
            self.D = D
            self.M.zeroEntries()  # the diagonal matrix of D, for the eigenproblems
            self.M.setDiagonal(D)
            self.M.assemble()
        else:
            # PETSc's own Cholesky serially, nested dissection: on these small meshes it solves
            # faster than in the natural order or by MUMPS (docs/perf/brezis-sibony.md)
            with self.user_options.applied():
                if self.comm.size == 1:
                    self.ksp = direct_solver(self.M, "cholesky", "bs_mass", "petsc", ordering="nd")
                else:
                    self.ksp = direct_solver(self.M, "cholesky", "bs_mass")

        # the residual's operators (as NewtonSolver's): K (Dirichlet rows identity), the
        # penalty at its points, the load vector L (Dirichlet rows 0; assembled per solve)
        self.K = problem.stiffness()
        self.penalty = QuadraturePenalty(problem)
        self.penalty.store_transpose()
        self.L = dolfinx.fem.petsc.create_vector(V)
        self.R = dolfinx.fem.petsc.create_vector(V)
        self.d = dolfinx.fem.petsc.create_vector(V)
        self.Md = dolfinx.fem.petsc.create_vector(V)
        owned = np.flatnonzero(self.free.array_r == 1.0).astype(PETSc.IntType)
        rstart = self.free.getOwnershipRange()[0]
        self._free_is = PETSc.IS().createGeneral(owned + rstart, comm=self.comm)
        self._spectrum_cache: dict[float, tuple[float, float]] = {}
        self.spectrum_seconds = 0.0

    # -- building blocks ----------------------------------------------------------------------
    def _one_minus_free(self) -> PETSc.Vec:
        """``1 − free``: 1 at Dirichlet dofs."""
        w = self.free.copy()
        w.scale(-1.0)
        w.shift(1.0)
        return w

    def _residual(self) -> None:
        """``R ← R(problem.zeta) = Kψ − L + (1/κ) Mᵀ min(g, 0)``, zero at Dirichlet dofs."""
        psi = self.problem.zeta.x.petsc_vec
        self.K.mult(psi, self.R)
        self.R.axpy(-1.0, self.L)
        g = self.penalty.gap(psi)
        self.penalty.add_residual(np.minimum(g, 0.0), float(self.problem.kappa.value), self.R)

    def _form_residual(self) -> PETSc.Vec:
        """The residual form assembled at ``problem.zeta`` (a new vector; what
        :meth:`_residual` computes, up to round-off)."""
        self.problem.update_multiplier()
        b = dolfinx.fem.petsc.assemble_vector(self.problem.forms["residual"])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        dolfinx.fem.petsc.set_bc(b, self.problem.bcs)
        return b

    def _apply_inverse_mass(self) -> None:
        """``d ← M⁻¹ R``."""
        if self.D is not None:
            self.d.pointwiseDivide(self.R, self.D)
        else:
            self.ksp.solve(self.R, self.d)
            if self.ksp.getConvergedReason() < 0:
                raise ConvergenceError(
                    f"mass-matrix solve failed (PETSc reason {self.ksp.getConvergedReason()})"
                )

    def _m_norm(self, x: PETSc.Vec) -> float:
        """``sqrt(xᵀ M x)``: the L² norm of the function with coefficients ``x``."""
        self.M.mult(x, self.Md)
        return math.sqrt(max(x.dot(self.Md), 0.0))

    def spectrum(self) -> tuple[float, float]:
        """``(λ_min, λ_max)``: smallest of ``K v = λ M v``, largest of ``(K + P_all) v = λ M v``.

        Both on the free (non-Dirichlet) dofs, for the current ``κ``; cached per ``κ``.
        """
        kappa = float(self.problem.kappa.value)
        if kappa in self._spectrum_cache:
            return self._spectrum_cache[kappa]
        t0 = time.perf_counter()
        B = self.M.createSubMatrix(self._free_is, self._free_is)
        K_ff = self.K.createSubMatrix(self._free_is, self._free_is)
        opts = self.options
        lam_min = extreme_eigenvalue(K_ff, B, False, opts.eigen_tol, opts.eigen_max_iterations)
        K_ff.destroy()
        # K + P_all: the penalty's Jacobian with every point active
        pen = self.penalty
        P_all = penalty_hessian(pen.M, pen.D, np.arange(pen.D.size), kappa)
        S = self.K.duplicate(copy=True)
        S.axpy(1.0, P_all, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        P_all.destroy()
        S_ff = S.createSubMatrix(self._free_is, self._free_is)
        lam_max = extreme_eigenvalue(S_ff, B, True, opts.eigen_tol, opts.eigen_max_iterations)
        for A in (S, S_ff, B):
            A.destroy()
        self._spectrum_cache[kappa] = (lam_min, lam_max)
        self.spectrum_seconds += time.perf_counter() - t0
        return lam_min, lam_max

    def _start(self) -> None:
        """Set ``problem.zeta`` to ``ψ_0`` (homogeneous Dirichlet values in every case; the
        load vector ``L`` must be current: :meth:`_load`)."""
        zeta = self.problem.zeta
        if self.options.start == "zero":
            zeta.x.array[:] = 0.0
        elif self.options.start == "linearized":
            ksp = direct_solver(self.K, "lu", "bs_linearized")
            ksp.solve(self.L, zeta.x.petsc_vec)
            reason = ksp.getConvergedReason()
            ksp.destroy()
            if reason < 0:
                raise ConvergenceError(
                    f"linearized start: linear solve failed (PETSc reason {reason})"
                )
        dolfinx.fem.petsc.set_bc(zeta.x.petsc_vec, self.problem.bcs)
        zeta.x.scatter_forward()

    def _load(self) -> float:
        """``L ←`` the load vector (its parameters may have changed since the last solve);
        returns ``‖L‖ = ‖R(0)‖`` (the penalty vanishes at ψ = 0 as θ·q > 0)."""
        return self.problem.load_vector(self.L).norm()

    # -- the iteration ------------------------------------------------------------------------
    @with_user_options
    def solve(self, progress: Progress | None = None) -> BrezisSibonyResult:
        """Run (38) from the chosen start until a stopping criterion or the iteration cap.

        Args:
            progress: called as ``progress(k, Δ_k)`` every ``options.progress_every`` steps,
                ``Δ_k = ‖ψ_k − ψ_{k−1}‖_{L²}``.

        Returns:
            The :class:`~shellobstacle.solvers.brezis_sibony.result.BrezisSibonyResult`;
            ``problem.zeta`` holds the last iterate, also when ``converged`` is False
            (iteration cap, divergence, NaN): nothing is raised then.
        """
        opts, problem = self.options, self.problem
        t_start = time.perf_counter()
        h4 = self.h**4
        lam_min = lam_max = math.nan
        if opts.xi is None or opts.estimate_spectrum:
            lam_min, lam_max = self.spectrum()
        tau = opts.xi * h4 if opts.xi is not None else 2.0 / (lam_max * (1.0 + opts.safety))
        bound = max(abs(1.0 - tau * lam_min), abs(1.0 - tau * lam_max))
        ref = self._load()
        self._start()
        scale = ref if ref > 0.0 else 1.0
        setup = time.perf_counter() - t_start

        psi = problem.zeta.x.petsc_vec
        R, d = self.R, self.d
        result = BrezisSibonyResult(
            False, 0, "", tau / h4, tau, lam_max, lam_min, bound,
            increment_stride=opts.history_stride,
        )  # fmt: skip
        recent: deque[float] = deque(maxlen=opts.tail + 1)
        first = last = math.nan
        max_ratio = 0.0
        psi_norm = self._m_norm(psi)
        rel_inc = math.nan
        k = 0
        while True:
            self._residual()  # R(ψ_k)
            rnorm = R.norm()
            if not math.isfinite(rnorm):
                result.reason = "residual is not finite (NaN/Inf)"
                break
            if rnorm <= opts.rtol_residual * scale:
                result.converged = True
                result.reason = "relative residual below rtol_residual"
                break
            if k >= opts.max_iterations:
                result.reason = f"no convergence in {opts.max_iterations} iterations"
                break
            self._apply_inverse_mass()  # d = M⁻¹ R(ψ_k)
            dR, psiR = R.mDot([d, psi])  # dᵀMd, ψ_kᵀMd
            inc = tau * math.sqrt(max(dR, 0.0))
            psi.axpy(-tau, d)  # ψ_{k+1}
            problem.zeta.x.scatter_forward()
            k += 1
            # ‖ψ_{k+1}‖² = ‖ψ_k‖² − 2τ ψ_kᵀMd + τ² dᵀMd (recomputed exactly now and then)
            old_norm = psi_norm
            if k % 1000 == 0:
                psi_norm = self._m_norm(psi)
            else:
                psi_norm = math.sqrt(max(psi_norm**2 - 2 * tau * psiR + tau**2 * dR, 0.0))
            if k == 1:
                first = inc
            else:
                max_ratio = max(max_ratio, inc / last if last > 0 else math.inf)
            last = inc
            recent.append(inc)
            if (k - 1) % opts.history_stride == 0:
                result.increments.append(inc)
            rel_inc = inc / old_norm if old_norm > 0 else math.inf
            if progress is not None and k % opts.progress_every == 0:
                progress(k, inc)
            if not math.isfinite(inc):
                result.reason = "increment is not finite (NaN/Inf)"
                break
            if inc > opts.divergence_factor * first:
                result.reason = f"diverging: increment grew by more than {opts.divergence_factor:g}"
                break
            if inc <= opts.rtol * old_norm:
                result.converged = True
                result.reason = "relative L2 increment below rtol"
                self._residual()
                rnorm = R.norm()
                break

        result.iterations = k
        result.relative_residual = rnorm / scale
        result.relative_increment = rel_inc
        result.max_ratio = max_ratio if k >= 2 else math.nan
        if k >= 2 and first > 0:
            result.contraction_factor = (last / first) ** (1.0 / (k - 1))
        if len(recent) >= 2 and recent[0] > 0:
            result.contraction_factor_tail = (recent[-1] / recent[0]) ** (1.0 / (len(recent) - 1))
        if k >= 1 and bound < 1.0:
            result.error_estimate = bound / (1.0 - bound) * last
        result.setup_seconds = setup
        result.seconds = time.perf_counter() - t_start
        return result
