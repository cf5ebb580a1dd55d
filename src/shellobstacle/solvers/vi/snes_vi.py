"""PETSc's VI Newton methods on the nodal obstacle problem (a peer of the active-set solver).

The problem is the bound-constrained quadratic program of
:mod:`~shellobstacle.solvers.vi.nodal_qp`: ``min ½ uᵀK'u − f'ᵀu`` subject to ``u_B ≥ ψ``
(the constraint ``g ≥ 0`` at the Lagrange nodes after the nodal change of variables,
docs/model.md §3, §5). Its KKT conditions are the mixed complementarity problem
``F(u) = K'u − f' ⊥ u_B ≥ ψ``, ``F(u)_b = 0`` for the unbounded unknowns, which PETSc's
``SNESVINEWTONRSLS`` and ``SNESVINEWTONSSLS`` solve with the bounds
(``SNESVISetVariableBounds``), the Jacobian ``K'`` and PETSc's own line searches:

- ``rsls`` (reduced space): at every step the unknowns on their bound whose ``F`` pushes
  outward are held, Newton's equation is solved on the others (a principal submatrix of
  ``K'``, a new factorization per step), and the step is projected onto the bounds;
- ``ssls`` (semismooth): Newton on the Fischer–Burmeister reformulation
  ``φ(u_b − ψ_b, F_b) = 0`` of every bound, with the full (modified, nonsymmetric) Jacobian.

Each linear solve is a MUMPS factorization. The answer is measured by the same KKT check
as the active-set solver's, with the multiplier ``λ_b = (K'u − f')_b`` of every bound.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from mpi4py import MPI  # noqa: F401  (MPI before PETSc)
from petsc4py import PETSc

import numpy as np

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.base import (
    UserOptions,
    factorization_pc,
    unique_prefix,
    with_user_options,
)
from shellobstacle.solvers.vi.nodal_qp import NodalQP, NodalResult, factor_mb
from shellobstacle.solvers.vi.options import SnesVIOptions

__all__ = ["SnesVIResult", "SnesVISolver"]

_REASONS = {
    value: name
    for name, value in vars(PETSc.SNES.ConvergedReason).items()
    if not name.startswith("_") and isinstance(value, int)
}


@dataclass
class SnesVIResult(NodalResult):
    """What a PETSc VI solve did (:class:`~shellobstacle.solvers.vi.nodal_qp.NodalResult`;
    ``iterations`` counts PETSc's Newton steps, one linear solve each).

    Attributes:
        vi_type: ``"rsls"`` or ``"ssls"``.
        line_search: PETSc's line search.
        snes_reason: PETSc's ``SNESConvergedReason`` by name.
        function_evaluations: evaluations of ``F`` (line searches included).
        residual_norms: PETSc's VI residual norm after each step.
    """

    vi_type: str = "rsls"
    line_search: str = "l2"
    snes_reason: str = ""
    function_evaluations: int = 0
    residual_norms: list[float] = field(default_factory=list)

    def details(self) -> dict:
        """The summary's record: KKT measures, PETSc's reason and counts."""
        return super().details() | {
            "vi_type": self.vi_type,
            "line_search": self.line_search,
            "snes_reason": self.snes_reason,
            "function_evaluations": self.function_evaluations,
        }


class SnesVISolver:
    """PETSc's ``vinewtonrsls`` / ``vinewtonssls`` on the nodal problem of one
    :class:`PenalizedProblem`.

    ``K' = QᵀKQ`` and the bounds are built once
    (:class:`~shellobstacle.solvers.vi.nodal_qp.NodalQP`);
    each :meth:`solve` re-assembles only the load.

    Args:
        problem: a P1 problem with ``penalty_quadrature = "vertex"``, or a P2 problem (either
            model).
        options: the VI type, line search, tolerances and factorization.

    Raises:
        ValueError: for other discretizations, or when a node whose displacement is fixed
            lies below the plane.
    """

    def __init__(self, problem: PenalizedProblem, options: SnesVIOptions | None = None) -> None:
        self.problem = problem
        self.options = opts = options or SnesVIOptions()
        self.user_options = UserOptions(opts.petsc_options, ("vi",), "snes-vi", problem.mesh.comm)
        t0 = time.perf_counter()
        self.qp = qp = NodalQP(problem, "SnesVISolver")
        self.timings: dict[str, float] = {"setup": 0.0}
        # scaled unknowns u = s v and residual F = r (K'u − f'), s = σ_v D^{-1/2} and
        # r = D^{-1/2} / σ_F (D = diag K', σ_v and σ_F the largest bound and load in the
        # Jacobi-scaled units): the distances to the bounds and F are O(1), as ssls' generalized
        # derivative (switched at 1e-6, absolute) and both line searches' norms need
        self.t = qp.diag.duplicate()
        self.t.set(1.0)
        self.sigma_v = 1.0
        if opts.scaling:
            self.t.array[:] = 1.0 / np.sqrt(qp.diag.array_r)
            self.sigma_v = qp.max(np.abs(qp.psi / self.t.array_r[qp.iB])) or 1.0
        self.s = self.t.copy()
        self.s.scale(self.sigma_v)
        self.A = qp.Kr.duplicate(copy=True)
        self.A.diagonalScale(self.s, self.s)  # S K' S, scaled by 1/(σ_v σ_F) at each solve
        self._a = 1.0
        self.b = qp.fr.duplicate()
        # ssls adds to the Jacobian's diagonal and scales its rows in place: it gets a copy,
        # restored at every evaluation; rsls only extracts submatrices
        self.J = self.A.duplicate(copy=True) if opts.vi_type == "ssls" else self.A
        self.v, self.u, self.F = (qp.fr.duplicate() for _ in range(3))
        lower, upper = qp.fr.duplicate(), qp.fr.duplicate()
        lower.set(PETSc.NINFINITY)
        lower.array[qp.iB] = qp.psi / self.s.array_r[qp.iB]
        upper.set(PETSc.INFINITY)

        snes = self.snes = PETSc.SNES().create(qp.comm)
        with self.user_options.applied():  # (the options stay: read at setFromOptions)
            snes.setOptionsPrefix(unique_prefix("vi"))
        snes.setType(f"vinewton{opts.vi_type}")
        snes.setFunction(self._function, self.F)
        snes.setJacobian(self._jacobian, self.J, self.J)
        snes.setVariableBounds(lower, upper)
        snes.setTolerances(
            rtol=opts.rtol, atol=opts.atol, stol=opts.stol, max_it=opts.max_iterations
        )
        snes.setConvergenceHistory(length=opts.max_iterations + 1, reset=True)
        snes.getLineSearch().setType(opts.line_search)
        ksp = snes.getKSP()
        ksp.setType("preonly")
        factorization = "lu" if opts.vi_type == "ssls" else opts.factorization
        factorization_pc(ksp.getPC(), factorization)
        with self.user_options.applied():
            snes.setFromOptions()
        self.timings["setup"] = time.perf_counter() - t0

    def _function(self, _snes: PETSc.SNES, x: PETSc.Vec, F: PETSc.Vec) -> None:
        """``F(v) = A v − b``."""
        self.A.mult(x, F)
        F.axpy(-1.0, self.b)

    def _jacobian(self, _snes: PETSc.SNES, _x: PETSc.Vec, J: PETSc.Mat, _P: PETSc.Mat) -> None:
        """``A`` (restored into ``ssls``'s copy, which PETSc modifies)."""
        if J is not self.A:
            self.A.copy(J, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)

    @with_user_options
    def solve(self) -> SnesVIResult:
        """Solve the nodal problem; leave ``ζ^h`` in ``problem.zeta``.

        Returns:
            The :class:`SnesVIResult` with the multiplier, contact pressure and KKT measures.

        Raises:
            ConvergenceError: PETSc stopped without converging, or the KKT measures miss
                ``kkt_rtol``; ``problem.zeta`` then holds the last iterate and ``err.result``
                the :class:`SnesVIResult`.
        """
        opts, qp = self.options, self.qp
        t_start = time.perf_counter()
        timings = {"setup": self.timings["setup"]}
        t = time.perf_counter()
        qp.assemble_load()
        timings["assemble"] = time.perf_counter() - t
        self.b.pointwiseMult(self.t, qp.fr)
        sigma_f = 1.0
        if opts.scaling:
            sigma_f = self.b.norm(PETSc.NormType.NORM_INFINITY) or 1.0
            self.b.scale(1.0 / sigma_f)
        a = 1.0 / (self.sigma_v * sigma_f)
        self.A.scale(a / self._a)
        self._a = a
        qp.start(self.u, opts.warm_start)
        self.v.pointwiseDivide(self.u, self.s)
        t = time.perf_counter()
        self.snes.solve(None, self.v)
        timings["solve"] = time.perf_counter() - t
        self.u.pointwiseMult(self.s, self.v)
        code = self.snes.getConvergedReason()
        norms, _ = self.snes.getConvergenceHistory()

        t = time.perf_counter()
        lam_B = qp.bound_forces(self.u)
        fields = qp.evaluate(self.u, lam_B, qp.predicted_active(self.u, lam_B))
        timings["kkt"] = time.perf_counter() - t
        result = SnesVIResult(
            converged=code > 0,
            iterations=self.snes.getIterationNumber(),
            reason=f"PETSc: {_REASONS.get(code, code)}",
            factor_mb=factor_mb(self.snes.getKSP()),
            vi_type=opts.vi_type,
            line_search=opts.line_search,
            snes_reason=_REASONS.get(code, str(code)),
            function_evaluations=self.snes.getFunctionEvaluations(),
            residual_norms=[float(v) for v in np.asarray(norms)[1:]],
            **fields,
        )
        result.timings = timings | {"total": time.perf_counter() - t_start}
        result.conclude(opts.kkt_rtol, f"PETSc's vinewton{opts.vi_type}", "steps")
        return result
