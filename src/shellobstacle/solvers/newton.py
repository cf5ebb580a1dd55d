"""Semismooth Newton for the penalized problem, globalized by an exact line search (MODEL.md §4).

``J_κ`` is strictly convex, C¹ and piecewise quadratic, so along a Newton
direction ``δ`` the function ``φ(t) = J_κ(ζ + tδ)`` is convex and piecewise
quadratic and ``φ'(t) = R(ζ + tδ)·δ`` is monotone and piecewise linear. The step
length is the root of ``φ'`` (found by safeguarded secant steps, exact once the
active set along the segment is fixed), which makes every step decrease the
energy and the iteration globally convergent from any start.
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
from petsc4py import PETSc

from shellobstacle import compat  # noqa: F401
from shellobstacle.problem import PenalizedProblem
from shellobstacle.solvers.line_search import piecewise_linear_root

__all__ = ["ConvergenceError", "NewtonOptions", "NewtonResult", "NewtonSolver"]


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
        linear_solver: ``"direct"`` (MUMPS LU) or ``"iterative"`` (CG + GAMG).
        linear_rtol: relative tolerance of the iterative linear solver.
    """

    rtol: float = 1e-10
    atol: float = 1e-30
    stol: float = 1e-12
    floor_factor: float = 100.0
    max_iterations: int = 100
    linear_solver: str = "direct"
    linear_rtol: float = 1e-12

    def __post_init__(self) -> None:
        if self.linear_solver not in ("direct", "iterative"):
            raise ValueError(
                f"solver.linear_solver must be 'direct' or 'iterative', got {self.linear_solver!r}"
            )
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
        self.A = dolfinx.fem.petsc.create_matrix(problem.forms["jacobian"])
        self.R = dolfinx.fem.petsc.create_vector(problem.V)
        self.dz = dolfinx.fem.petsc.create_vector(problem.V)
        self.trial = dolfinx.fem.Function(problem.V)  # ζ + tδ for line-search evaluations
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOperators(self.A)
        prefix = f"shellobstacle_{id(self)}_"
        self.ksp.setOptionsPrefix(prefix)
        pc = self.ksp.getPC()
        if opts.linear_solver == "direct":
            self.ksp.setType("preonly")
            pc.setType("lu")
            pc.setFactorSolverType("mumps")
        else:
            self.ksp.setType("cg")
            pc.setType("gamg")
            self.ksp.setTolerances(rtol=opts.linear_rtol, atol=1e-50, max_it=2000)
        self.ksp.setFromOptions()
        self.timings: dict[str, float] = {"assemble": 0.0, "solve": 0.0, "line_search": 0.0}
        self._factored_kappa: float | None = None  # κ of the Jacobian held by the KSP

    # -- assembly ---------------------------------------------------------------------------
    def _residual(self, u: dolfinx.fem.Function, b: PETSc.Vec) -> None:
        """``b ← R(u)`` with zero rows at Dirichlet dofs (``u`` satisfies the homogeneous bcs)."""
        with b.localForm() as loc:
            loc.set(0.0)
        if u is not self.problem.zeta:
            raise RuntimeError("residual forms are tied to problem.zeta")
        dolfinx.fem.petsc.assemble_vector(b, self.problem.forms["residual"])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        dolfinx.fem.petsc.set_bc(b, self.problem.bcs)

    def _jacobian(self) -> None:
        self._factored_kappa = float(self.problem.kappa.value)
        self.A.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(
            self.A, self.problem.forms["jacobian"], bcs=self.problem.bcs
        )
        self.A.assemble()

    def _norm_of(self, name: str) -> float:
        """Norm of an assembled linear form of the problem (Dirichlet rows zeroed)."""
        b = dolfinx.fem.petsc.assemble_vector(self.problem.forms[name])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        dolfinx.fem.petsc.set_bc(b, self.problem.bcs)
        norm = b.norm()
        b.destroy()
        return norm

    def _floor(self, load_norm: float) -> float:
        """Estimated round-off floor of ``‖R(ζ)‖`` at the current iterate."""
        u = np.finfo(PETSc.ScalarType).eps
        return self.options.floor_factor * u * (load_norm + self._norm_of("penalty_scale"))

    def _direction(self) -> None:
        """``δ ← A⁻¹ (−R)`` (``self.R`` holds ``−R``)."""
        self.ksp.solve(self.R, self.dz)
        self.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def predict(self, kappa_new: float) -> bool:
        """Euler predictor along κ: ``ζ ← ζ + (κ_new − κ) dζ/dκ`` with ``J dζ/dκ = −∂R/∂κ``.

        ``∂R/∂κ = −(1/κ) (ε/κ)∫β(ζ)·v dy`` and ``J`` is the Jacobian already factored at the
        end of the last solve, so the prediction costs one assembly and one back-substitution.
        Returns False (and changes nothing) when no factorization for the current κ exists.
        """
        kappa = float(self.problem.kappa.value)
        if self._factored_kappa != kappa:
            return False
        t0 = time.perf_counter()
        b = dolfinx.fem.petsc.assemble_vector(self.problem.forms["penalty_residual"])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        dolfinx.fem.petsc.set_bc(b, self.problem.bcs)
        b.scale(1.0 / kappa)  # −∂R/∂κ
        self.ksp.solve(b, self.dz)
        self.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        b.destroy()
        zeta = self.problem.zeta
        with self.dz.localForm() as dz_loc:
            zeta.x.array[:] += (kappa_new - kappa) * dz_loc.array_r
        zeta.x.scatter_forward()
        self.timings["predict"] = self.timings.get("predict", 0.0) + time.perf_counter() - t0
        return True

    # -- line search --------------------------------------------------------------------------
    def _slope(self, t: float, z0: np.ndarray) -> float:
        """``φ'(t) = R(ζ_0 + tδ)·δ`` (sets ``problem.zeta`` to ``ζ_0 + tδ``)."""
        zeta = self.problem.zeta
        zeta.x.array[:] = z0 + t * self._dz_local
        zeta.x.scatter_forward()
        self._residual(zeta, self.R)
        self._last_t = t  # self.R now holds R(ζ_0 + tδ)
        return self.R.dot(self.dz)

    def _line_search(self, z0: np.ndarray, slope0: float, noise: float) -> tuple[float, int]:
        """Exact step along δ: the root of ``φ'(t) = R(ζ_0 + tδ)·δ`` (round-off aware)."""
        tol = max(1e-10 * abs(slope0), noise)
        return piecewise_linear_root(lambda t: self._slope(t, z0), slope0, tol)

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
        ref = self._norm_of("load")
        result = NewtonResult(False, 0, "")
        ta = time.perf_counter()
        self._residual(zeta, self.R)
        self.timings["assemble"] += time.perf_counter() - ta
        rnorm = self.R.norm()
        result.residual_norms.append(rnorm)
        scale = ref if ref > 0.0 else 1.0
        result.reference = ref
        for it in range(1, opts.max_iterations + 1):
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
            ta = time.perf_counter()
            self._jacobian()
            self.timings["assemble"] += time.perf_counter() - ta
            ts = time.perf_counter()
            self.R.scale(-1.0)
            self._direction()
            self.timings["solve"] += time.perf_counter() - ts
            result.linear_iterations.append(self.ksp.getIterationNumber())
            if self.ksp.getConvergedReason() < 0:
                result.reason = (
                    f"linear solver failed (PETSc reason {self.ksp.getConvergedReason()})"
                )
                break
            slope0 = -self.R.dot(self.dz)  # R·δ = −δᵀAδ < 0
            tl = time.perf_counter()
            with self.dz.localForm() as dz_loc:
                self._dz_local = np.array(dz_loc.array_r)
            z0 = zeta.x.array.copy()
            step = self.dz.norm(PETSc.NormType.NORM_INFINITY)
            unorm = zeta.x.petsc_vec.norm(PETSc.NormType.NORM_INFINITY)
            small_step = step <= opts.stol * unorm
            self._last_t = None
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
                t, evals = self._line_search(z0, slope0, noise)
            # leave ζ = ζ_0 + tδ and R(ζ) in place; the last slope evaluation usually was at
            # this t already (always for a full step), which saves an assembly
            if self._last_t != t:
                zeta.x.array[:] = z0 + t * self._dz_local
                zeta.x.scatter_forward()
                self._residual(zeta, self.R)
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
        else:
            result.reason = f"no convergence in {opts.max_iterations} Newton iterations"
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
