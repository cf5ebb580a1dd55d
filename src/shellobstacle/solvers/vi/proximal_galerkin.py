"""The latent-variable proximal point method on the nodal obstacle problem (a peer of the
active-set solver).

Keith & Surowiec's proximal Galerkin method (Found. Comput. Math., 2024) for a lower bound
``u ≥ ψ``: each step of the proximal point iteration with the entropy (Bregman) distance,

:math:`u_k = \\arg\\min_u J(u) + α_k^{-1} D(u, u_{k-1})`,

is written with a latent variable ``φ = log(u − ψ)``, so that ``u = ψ + e^φ`` lies above
the bound for every ``φ``, and solved by Newton's method in the mixed unknowns ``(u, φ)``.
Here the bound is the nodal one of :mod:`~shellobstacle.solvers.vi.nodal_qp` (``u_B ≥ ψ``
after the nodal change of variables, docs/model.md §5), the latent variable lives at the
constrained nodes and the distance is weighted by the lumped masses ``m_b``:

:math:`α_k (K'u − f') + E M (φ − φ_{k−1}) = 0,\\qquad M (E^T u − ψ − e^φ) = 0`,

``E`` the injection of the bounds. Newton's matrix
``[[α_k K', E M], [M Eᵀ, −M diag(e^φ)]]`` is symmetric indefinite; its latent block is
diagonal (the latent variable is nodal), so by default it is condensed out (a symmetric
positive definite matrix with ``K'``'s sparsity, one Cholesky factorization per Newton step),
or the mixed matrix is factorized as the authors' DOLFINx examples do
(``linear_system = "mixed"``): the same iterates. Full Newton steps, as in those examples;
``α_k`` follows their double-exponential rule, made dimensionless by the largest nodal load
pressure (:class:`~shellobstacle.solvers.vi.options.ProximalGalerkinOptions`). At the limit
``λ_b = (K'u − f')_b = m_b (φ_{k−1} − φ_k)/α_k ≥ 0`` is the multiplier. The answer is
measured by the same KKT check as the active-set solver's, with ``λ_b = (K'u − f')_b`` at
every bound.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.base import (
    ConvergenceError,
    UserOptions,
    direct_solver,
    factorization_pc,
    unique_prefix,
    with_user_options,
)
from shellobstacle.solvers.vi.nodal_qp import NodalQP, NodalResult, factor_mb
from shellobstacle.solvers.vi.options import ProximalGalerkinOptions

__all__ = ["ProximalGalerkinResult", "ProximalGalerkinSolver"]


@dataclass
class ProximalGalerkinResult(NodalResult):
    """What a proximal Galerkin solve did (:class:`~shellobstacle.solvers.vi.nodal_qp.NodalResult`;
    ``iterations`` counts Newton steps over all proximal steps, one linear solve each).

    Attributes:
        proximal_steps: proximal point steps taken (accepted).
        rejected_steps: steps whose Newton iteration failed and that were taken again with
            a smaller ``α̂``.
        newton_per_step: Newton steps of each attempt (rejected ones included).
        alphas: the dimensionless ``α̂`` of each attempt.
        increments: ``‖u_k − u_{k−1}‖ / ‖u_k‖`` of each accepted step.
    """

    proximal_steps: int = 0
    rejected_steps: int = 0
    newton_per_step: list[int] = field(default_factory=list)
    alphas: list[float] = field(default_factory=list)
    increments: list[float] = field(default_factory=list)

    def details(self) -> dict:
        """The summary's record: KKT measures and the proximal history."""
        return super().details() | {
            "proximal_steps": self.proximal_steps,
            "rejected_steps": self.rejected_steps,
            "newton_per_step": self.newton_per_step,
            "alphas": self.alphas,
            "increments": self.increments,
        }


class ProximalGalerkinSolver:
    """The latent-variable proximal point method on the nodal problem of one
    :class:`PenalizedProblem`.

    ``K'``, the bounds and the Newton matrix's pattern are built once; each :meth:`solve`
    re-assembles only the load. A warm start's gaps below ``10⁻¹² max|ψ|`` start their latent
    variable at that floor (``log 0`` has no value).

    Args:
        problem: a P1 problem with ``penalty_quadrature = "vertex"``, or a P2 problem (either
            model).
        options: the proximal parameters, tolerances and factorization.

    Raises:
        ValueError: for other discretizations, or when a node whose displacement is fixed
            lies below the plane.
    """

    def __init__(
        self, problem: PenalizedProblem, options: ProximalGalerkinOptions | None = None
    ) -> None:
        self.problem = problem
        self.options = opts = options or ProximalGalerkinOptions()
        self.user_options = UserOptions(
            opts.petsc_options, ("pg",), "proximal-galerkin", problem.mesh.comm
        )
        t0 = time.perf_counter()
        self.qp = qp = NodalQP(problem, "ProximalGalerkinSolver")
        self.m = qp.nodal.node_masses()[qp.nodes]  # the latent variable's weights
        with self.user_options.applied():
            self.step = (_Condensed if opts.linear_system == "condensed" else _Mixed)(
                qp, self.m, opts.factorization
            )
        self.u, self.r, self.Fu = (qp.fr.duplicate() for _ in range(3))
        self.timings: dict[str, float] = {"setup": time.perf_counter() - t0}

    # -- one Newton iteration of one proximal step --------------------------------------------
    def _residual(
        self, alpha: float, phi: np.ndarray, phi_prev: np.ndarray
    ) -> tuple[np.ndarray, float, float]:
        """``F_u`` (into ``self.Fu``), ``F_φ`` and the norms of both."""
        qp, iB = self.qp, self.qp.iB
        qp.residual(self.u, self.r)
        Fu = self.Fu.array
        Fu[:] = alpha * self.r.array_r
        Fu[iB] += self.m * (phi - phi_prev)
        with np.errstate(over="ignore"):  # an overflow is a failed step (non-finite norm)
            Fphi = self.m * (self.u.array_r[iB] - qp.psi - np.exp(phi))
        sq = qp.comm.allreduce(np.array([np.dot(Fu, Fu), np.dot(Fphi, Fphi)]), op=MPI.SUM)
        return Fphi, math.sqrt(sq[0]), math.sqrt(sq[1])

    def _proximal_step(
        self, alpha: float, phi: np.ndarray, phi_prev: np.ndarray, scales: tuple[float, float]
    ) -> tuple[int, bool]:
        """Newton on one step's equations from ``(u, φ)``; returns (steps, converged)."""
        opts = self.options
        for step in range(opts.max_newton_iterations + 1):
            Fphi, ru, rphi = self._residual(alpha, phi, phi_prev)
            if not (math.isfinite(ru) and math.isfinite(rphi)):
                return step, False
            if ru <= opts.newton_rtol * alpha * scales[0] and rphi <= opts.newton_rtol * scales[1]:
                return step, True
            if step == opts.max_newton_iterations:
                break
            t = time.perf_counter()
            du, dphi = self.step.solve(alpha, phi, self.Fu, Fphi)
            self.timings["solve"] += time.perf_counter() - t
            self.u.array[:] += du
            phi += dphi
        return opts.max_newton_iterations, False

    # -- solve --------------------------------------------------------------------------------
    @with_user_options
    def solve(self) -> ProximalGalerkinResult:
        """Solve the nodal problem; leave ``ζ^h`` in ``problem.zeta``.

        Returns:
            The :class:`ProximalGalerkinResult` with the multiplier, contact pressure and
            KKT measures.

        Raises:
            ConvergenceError: a Newton iteration failed, the increments did not fall below
                ``tol`` within ``max_iterations`` steps, or the KKT measures miss
                ``kkt_rtol``; ``problem.zeta`` then holds the last iterate and ``err.result``
                the :class:`ProximalGalerkinResult`.
        """
        opts, qp = self.options, self.qp
        t_start = time.perf_counter()
        self.timings = {"setup": self.timings["setup"], "assemble": 0.0, "solve": 0.0}
        t = time.perf_counter()
        qp.assemble_load()
        self.timings["assemble"] = time.perf_counter() - t
        qp.start(self.u, opts.warm_start)
        # α = α̂ / P with P the largest nodal load pressure |f_i| / m_i
        f_nodes = np.linalg.norm(qp.f.array_r.reshape(qp.n, qp.bs), axis=1)
        node_mass = qp.nodal.node_masses()
        pressure = qp.max(np.divide(f_nodes, node_mass, out=np.zeros(qp.n), where=node_mass > 0))
        pressure = pressure or 1.0
        gap0 = self.u.array_r[qp.iB] - qp.psi
        floor = 1e-12 * (qp.max(np.abs(qp.psi)) or 1.0)
        phi = np.log(np.maximum(gap0, floor))
        scales = (qp.fr.norm() or 1.0, math.sqrt(qp.sum(np.sum((self.m * qp.psi) ** 2))) or 1.0)

        newton_per_step: list[int] = []
        alphas: list[float] = []
        increments: list[float] = []
        converged, reason = False, f"no convergence in {opts.max_iterations} proximal steps"
        rejected, cap = 0, opts.alpha_max
        u_prev = self.u.duplicate()
        try:
            for scheduled in opts.alphas():
                alpha_hat = min(scheduled, cap)
                self.u.copy(u_prev)
                phi_prev = phi.copy()
                while True:
                    steps, ok = self._proximal_step(alpha_hat / pressure, phi, phi_prev, scales)
                    newton_per_step.append(steps)
                    alphas.append(alpha_hat)
                    if ok:
                        break
                    # back to the step's start with a 10 times smaller α̂
                    rejected += 1
                    u_prev.copy(self.u)
                    phi[:] = phi_prev
                    alpha_hat /= 10
                    if rejected > opts.max_rejections:
                        raise ConvergenceError(
                            f"Newton did not converge in proximal step {len(increments) + 1} "
                            f"after {rejected} reductions of alpha (last {10 * alpha_hat:.3g})"
                        )
                if rejected:  # after a failure α̂ grows by at most `regrowth` per step
                    cap = min(opts.regrowth * alpha_hat, opts.alpha_max)
                u_prev.axpy(-1.0, self.u)
                norm = self.u.norm()
                increments.append(u_prev.norm() / (norm if norm > 0 else 1.0))
                if increments[-1] <= opts.tol:
                    converged = True
                    reason = f"increment {increments[-1]:.2e} <= tol = {opts.tol:.1e}"
                    break
        except ConvergenceError as err:  # Newton or a linear solve failed
            reason = str(err)
        u_prev.destroy()

        t = time.perf_counter()
        lam_B = qp.bound_forces(self.u)
        fields = qp.evaluate(self.u, lam_B, qp.predicted_active(self.u, lam_B))
        self.timings["kkt"] = time.perf_counter() - t
        result = ProximalGalerkinResult(
            converged=converged,
            iterations=sum(newton_per_step),
            reason=reason,
            factor_mb=factor_mb(self.step.ksp),
            proximal_steps=len(increments),
            rejected_steps=rejected,
            newton_per_step=newton_per_step,
            alphas=alphas,
            increments=increments,
            **fields,
        )
        result.timings = dict(self.timings) | {"total": time.perf_counter() - t_start}
        result.conclude(opts.kkt_rtol, "the proximal Galerkin iteration", "Newton steps")
        return result


def _checked_solve(ksp: PETSc.KSP, rhs: PETSc.Vec, x: PETSc.Vec) -> None:
    ksp.solve(rhs, x)
    if ksp.getConvergedReason() < 0:
        raise ConvergenceError(f"linear solve failed (PETSc reason {ksp.getConvergedReason()})")


class _Condensed:
    """Newton's step with the latent variable condensed out (it is nodal: its block is
    diagonal): ``(α K' + E W Eᵀ) δu = −F_u − E (W/M) F_φ`` with ``W = M e^{−φ}``, then
    ``M δφ = −(F_u + α K' δu)_B`` from the first block row. ``W`` is capped at ``10¹⁶ α K'_bb``
    (a bound held to round-off), where ``e^{−φ}`` would overflow. Symmetric positive
    definite, the sparsity of ``K'``: one Cholesky factorization per step, symbolic reused."""

    def __init__(self, qp: NodalQP, m: np.ndarray, factorization: str) -> None:
        self.qp, self.m = qp, m
        self.W = qp.Kr.duplicate(copy=True)
        self.W.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
        self.ksp = direct_solver(self.W, factorization, "pg")
        self.rhs, self.du, self.diag = (qp.fr.duplicate() for _ in range(3))

    def solve(
        self, alpha: float, phi: np.ndarray, Fu: PETSc.Vec, Fphi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        qp, iB = self.qp, self.qp.iB
        qp.Kr.copy(self.W, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        self.W.scale(alpha)
        self.diag.array[:] = alpha * qp.diag.array_r
        w_over_m = np.exp(np.minimum(-phi, np.log(1e16 * alpha * qp.d / self.m)))
        self.diag.array[iB] += self.m * w_over_m
        self.W.setDiagonal(self.diag, PETSc.InsertMode.INSERT_VALUES)
        self.rhs.array[:] = -Fu.array_r
        self.rhs.array[iB] -= w_over_m * Fphi
        _checked_solve(self.ksp, self.rhs, self.du)
        qp.Kr.mult(self.du, self.rhs)
        dphi = -(Fu.array_r[iB] + alpha * self.rhs.array_r[iB]) / self.m
        return self.du.array_r.copy(), dphi


class _Mixed:
    """Newton's step as the authors' examples take it: the mixed matrix
    ``[[α K', E M], [M Eᵀ, −M diag(e^φ)]]`` (symmetric indefinite; a MatNest converted to
    AIJ, each rank's ``u`` rows then its ``φ`` rows) factorized by MUMPS."""

    def __init__(self, qp: NodalQP, m: np.ndarray, factorization: str) -> None:
        comm, iB = qp.comm, qp.iB
        self.qp, self.m = qp, m
        self.n3 = n3 = qp.fr.getLocalSize()
        nB = iB.size
        self.A00 = qp.Kr.duplicate(copy=True)
        c0 = comm.exscan(nB) or 0  # the first φ of this rank
        latent = (c0 + np.arange(nB)).astype(PETSc.IntType)
        indptr = np.zeros(n3 + 1, dtype=PETSc.IntType)
        indptr[iB + 1] = 1  # iB is increasing: row iB[b] holds m_b in column b
        A01 = PETSc.Mat().createAIJ(
            ((n3, PETSc.DETERMINE), (nB, PETSc.DETERMINE)),
            csr=(np.cumsum(indptr).astype(PETSc.IntType), latent, m),
            comm=comm,
        )
        A01.assemble()
        self.A11 = PETSc.Mat().createAIJ(
            ((nB, PETSc.DETERMINE), (nB, PETSc.DETERMINE)),
            csr=(np.arange(nB + 1, dtype=PETSc.IntType), latent, np.zeros(nB)),
            comm=comm,
        )
        self.A11.assemble()
        blocks = [[self.A00, A01], [A01.transpose(PETSc.Mat()), self.A11]]
        self.nest = PETSc.Mat().createNest(blocks, comm=comm)
        self.M = self.nest.convert("aij", PETSc.Mat())
        rows, _ = self.nest.getNestISs()
        start = self.M.getOwnershipRange()[0]
        for is_, want in zip(
            rows, (np.arange(n3) + start, np.arange(nB) + start + n3), strict=True
        ):
            if not np.array_equal(is_.getIndices(), want):
                raise RuntimeError("unexpected layout of the converted MatNest")
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOptionsPrefix(unique_prefix("pg"))
        self.ksp.setOperators(self.M)
        self.ksp.setType("preonly")
        if factorization == "cholesky":  # symmetric indefinite: MUMPS' LDLᵀ with pivots
            self.M.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        factorization_pc(self.ksp.getPC(), factorization)
        self.ksp.setFromOptions()
        self.F, self.dX = self.M.createVecs()

    def solve(
        self, alpha: float, phi: np.ndarray, Fu: PETSc.Vec, Fphi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        self.qp.Kr.copy(self.A00, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        self.A00.scale(alpha)
        d = self.A11.getDiagonal()
        d.array[:] = -self.m * np.exp(phi)
        self.A11.setDiagonal(d)
        d.destroy()
        self.nest.convert("aij", out=self.M)
        n3 = self.n3
        self.F.array[:n3] = -Fu.array_r
        self.F.array[n3:] = -Fphi
        _checked_solve(self.ksp, self.F, self.dX)
        return self.dX.array_r[:n3].copy(), self.dX.array_r[n3:].copy()
