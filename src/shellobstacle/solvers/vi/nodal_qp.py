"""The nodal obstacle problem as a bound-constrained quadratic program (docs/model.md §3, §5).

With the constraint ``g ≥ 0`` imposed at the Lagrange nodes ``x_i`` of the displacement
space (P1: the vertices; P2: the vertices and edge midpoints), the discrete variational
inequality (``κ = 0``) is the strictly convex quadratic program

:math:`\\min_{η ∈ V_h} J(η) = \\tfrac12 η^T K η - f^T η` subject to
:math:`g_i(η) = θ(x_i)·q + c(x_i)·η(x_i) ≥ 0` at every node :math:`x_i`,

``K`` the (``κ``-independent) stiffness matrix of either model and ``f`` the load vector,
both with the problem's homogeneous Dirichlet conditions. The rotations of
:mod:`~shellobstacle.solvers.vi.nodal` turn each node's constraint into a lower bound on one
rotated unknown, ``u_b ≥ ψ_b``; with ``K' = QᵀKQ`` and ``f' = Qᵀf`` the problem is
``min ½ uᵀK'u − f'ᵀu`` subject to ``u_B ≥ ψ``. :class:`NodalQP` holds these data once per
problem for every solver of it (:mod:`~shellobstacle.solvers.vi.active_set`,
:mod:`~shellobstacle.solvers.vi.snes_vi`, :mod:`~shellobstacle.solvers.vi.proximal_galerkin`).

**KKT.** At the solution ``(ζ^h, λ)`` (``B`` the constraint matrix: row ``i`` is ``c(x_i)``
on the unknowns of node ``i``): ``K ζ − f − Bᵀλ = 0``, ``g_i ≥ 0``, ``λ_i ≥ 0``,
``λ_i g_i = 0``. The multiplier of a bound, ``λ_i = (K'u − f')_{i,k_i} / |c(x_i)|``, is the
nodal contact force (``λ ≥ 0`` pushes the shell away from the plane); divided by a lumped
mass it is a contact pressure. :meth:`NodalQP.evaluate` measures the four conditions of any
iterate and multiplier in the original, unrotated unknowns.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.base import ConvergenceError
from shellobstacle.solvers.vi.nodal import NodalConstraint

__all__ = ["NodalQP", "NodalResult", "factor_mb", "require_nodal"]


def require_nodal(problem: PenalizedProblem, solver: str) -> None:
    """Refuse discretizations whose constraint is not the nodal one.

    Raises:
        ValueError: P1 with a penalty quadrature other than the vertices.
    """
    disc = problem.disc
    if not (disc.degree == 2 or (disc.degree == 1 and disc.penalty_quadrature == "vertex")):
        raise ValueError(
            f"{solver} solves the nodal constraint of P1 (vertices, as "
            "penalty_quadrature='vertex' penalizes) or P2 (vertices and edge midpoints): "
            f"got degree={disc.degree}, penalty_quadrature={disc.penalty_quadrature!r}"
        )


@dataclass
class NodalResult:
    """What a solve of the nodal problem did, and the KKT quality of its answer.

    Attributes:
        converged: whether the solver's own stopping rule was met (and its KKT acceptance).
        iterations: linear solves in total.
        active_nodes: global number of nodes where ``λ_i > d_i g_i/|c_i|`` (``d_i = K'_bb``:
            the multiplier outweighs the stiffness times the gap; at an exact solution the
            nodes in contact that carry a force).
        reason: why the solver stopped.
        kkt: ``primal_feasibility = max_i {g_i}^-``, ``dual_feasibility = max_i {λ_i}^-``,
            ``complementarity = max_i |λ_i g_i|`` (absolute; see ``scales``) and
            ``stationarity = ‖K ζ − f − Bᵀλ‖ / ‖f‖`` (relative; Euclidean norms of the nodal
            vectors, evaluated in the original, unrotated unknowns).
        scales: natural sizes of the KKT quantities: ``gap`` (``max_i θ(x_i)·q``), ``force``
            (``max_i λ_i``, or ``‖f‖_∞`` without contact) and ``load`` (``‖f‖``).
        timings: seconds in ``setup`` (stiffness, rotation, ``QᵀKQ``: once per solver),
            ``assemble`` (load), ``solve`` (factorizations and solves), ``kkt`` and ``total``.
        factor_mb: MUMPS' memory of the last factorization (INFOG(22), summed over ranks).
        multiplier: ``λ`` (nodal contact forces), a scalar Function on the nodes (the
            solver's own, refreshed by each solve: copy it to keep it).
        contact_pressure: ``λ_i / m_i``, ``m_i`` the lumped masses of
            :class:`~shellobstacle.solvers.vi.nodal.NodalConstraint` (likewise refreshed).
    """

    converged: bool
    iterations: int
    active_nodes: int
    reason: str
    kkt: dict[str, float] = field(default_factory=dict)
    scales: dict[str, float] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    factor_mb: float = 0.0
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

    def conclude(self, kkt_rtol: float, solver: str, unit: str) -> None:
        """Accept the answer only if the relative KKT measures are at most ``kkt_rtol``.

        Raises:
            ConvergenceError: naming ``solver``, the reason and the iterations (in ``unit``),
                with this result, when it did not converge.
        """
        worst = max(self.relative_kkt.values())
        if self.converged and not worst <= kkt_rtol:
            self.converged = False
            self.reason += f"; KKT conditions hold only to {worst:.2e} > kkt_rtol = {kkt_rtol:.1e}"
        if not self.converged:
            raise ConvergenceError(
                f"{solver} did not converge: {self.reason} ({self.iterations} {unit})", self
            )

    def details(self) -> dict[str, Any]:
        """The JSON-friendly record of a result folder's summary (``kkt`` and its scales)."""
        return {
            "active_nodes": self.active_nodes,
            "kkt": self.kkt,
            "kkt_relative": self.relative_kkt,
            "kkt_scales": self.scales,
            "factor_mb": self.factor_mb,
            "timings": self.timings,
        }


class NodalQP:
    """``K``, ``f``, the rotation ``Q``, ``K' = QᵀKQ``, ``f' = Qᵀf`` and the bounds of one problem.

    The stiffness matrix, the rotation and ``K'`` are built once; :meth:`assemble_load`
    re-assembles only the load, so load parameters may change between solves.

    Attributes:
        K, Kr: ``K`` and ``K' = QᵀKQ``; read them, never change them.
        f, fr: the load vector ``f`` and ``f' = Qᵀf`` (owned dofs).
        nodal: the :class:`~shellobstacle.solvers.vi.nodal.NodalConstraint` (``Q``, ``ψ``, …).
        iB, psi: the constrained rotated unknowns (local positions) and their bounds.
        d: ``K'_bb > 0`` of the constrained unknowns.
        gap_scale: ``max_i |θ(x_i)·q|``.

    Raises:
        ValueError: for a discretization without the nodal constraint (:func:`require_nodal`),
            or when a node whose displacement is fixed lies below the plane.
    """

    def __init__(self, problem: PenalizedProblem, solver: str = "the nodal solver") -> None:
        require_nodal(problem, solver)
        self.problem = problem
        self.comm: MPI.Comm = problem.mesh.comm
        self.bs = problem.V.dofmap.index_map_bs
        self.n = problem.V.dofmap.index_map.size_local
        self.K = problem.stiffness()
        self.nodal = nodal = NodalConstraint(problem)
        self.nodes, self.iB, self.psi = nodal.nodes, nodal.iB, nodal.psi
        self.Q = nodal.Q
        self.gap_scale = self.max(np.abs(nodal.g0))
        self.Kr = self.K.ptap(self.Q)  # K' = Qᵀ K Q
        self.diag = self.Kr.getDiagonal()
        self.d = self.diag.array_r[self.iB].copy()  # K'_bb > 0
        self.f, self.fr = self.Kr.createVecs()
        self._r = self.fr.duplicate()

    # -- global reductions --------------------------------------------------------------------
    def max(self, x: np.ndarray) -> float:
        """``max x`` over all ranks (0 for empty arrays)."""
        return float(self.comm.allreduce(float(np.max(x, initial=0.0)), op=MPI.MAX))

    def sum(self, x: float) -> float:
        """``Σ x`` over all ranks."""
        return float(self.comm.allreduce(float(x), op=MPI.SUM))

    def count(self, mask: np.ndarray) -> int:
        """Global number of ``True`` entries."""
        return int(self.comm.allreduce(int(np.count_nonzero(mask)), op=MPI.SUM))

    def differ(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Whether two distributed masks differ anywhere."""
        return bool(self.comm.allreduce(bool(np.any(a != b)), op=MPI.LOR))

    # -- data of one solve --------------------------------------------------------------------
    def assemble_load(self) -> None:
        """``f`` ← the load vector, ``f' ← Qᵀf``."""
        b = self.problem.load_vector()
        self.f.array[:] = b.array_r[: self.n * self.bs]
        b.destroy()
        self.Q.multTranspose(self.f, self.fr)

    def start(self, u: PETSc.Vec, warm: bool) -> bool:
        """``u ← Qᵀζ`` (``problem.zeta`` with its Dirichlet values) if ``warm``, else 0;
        returns whether ``u`` is nonzero."""
        if not warm:
            u.set(0.0)
            return False
        zeta = self.problem.zeta
        dolfinx.fem.petsc.set_bc(zeta.x.petsc_vec, self.problem.bcs)
        zeta.x.scatter_forward()
        self.Q.multTranspose(zeta.x.petsc_vec, u)
        return u.norm(PETSc.NormType.NORM_INFINITY) > 0

    def residual(self, u: PETSc.Vec, out: PETSc.Vec) -> None:
        """``out ← K'u − f'``, the gradient of the rotated energy."""
        self.Kr.mult(u, out)
        out.axpy(-1.0, self.fr)

    def bound_forces(self, u: PETSc.Vec) -> np.ndarray:
        """``(K'u − f')_B``: the multiplier estimate of every bound at ``u``."""
        self.residual(u, self._r)
        return self._r.array_r[self.iB].copy()

    def predicted_active(self, u: PETSc.Vec, lam_B: np.ndarray) -> np.ndarray:
        """Where ``λ_b + d_b (ψ_b − u_b) > 0``: the bounds a semismooth Newton step holds."""
        return lam_B + self.d * (self.psi - u.array_r[self.iB]) > 0

    # -- the answer ---------------------------------------------------------------------------
    def evaluate(self, u: PETSc.Vec, lam_B: np.ndarray, active: np.ndarray) -> dict[str, Any]:
        """Leave ``ζ = Qu`` in ``problem.zeta``; the multiplier and the KKT measures.

        Args:
            u: the rotated iterate.
            lam_B: ``(K'u − f')_b`` of the bounds the solver takes as carrying a force
                (0 for the others).
            active: the bounds counted as active (``active_nodes``).

        Returns:
            The fields ``active_nodes``, ``kkt``, ``scales``, ``multiplier`` and
            ``contact_pressure`` of a :class:`NodalResult` (collective).
        """
        problem, nodal = self.problem, self.nodal
        zeta = problem.zeta
        self.Q.mult(u, zeta.x.petsc_vec)
        zeta.x.scatter_forward()
        lam = np.zeros(self.n)
        lam[self.nodes] = lam_B / nodal.cn[self.nodes]
        # gap and stationarity in the original unknowns: g = θ·q + c·ζ, K ζ − f − Bᵀλ
        g = nodal.gap(zeta.x.array)
        r = self._r
        self.K.mult(zeta.x.petsc_vec, r)
        r.axpy(-1.0, self.f)
        r.array[:] -= nodal.constraint_force(lam)
        load = self.f.norm()
        stationarity = r.norm() / (load if load > 0 else 1.0)
        force = self.max(np.abs(lam)) or self.f.norm(PETSc.NormType.NORM_INFINITY)
        kkt = {
            "primal_feasibility": self.max(np.maximum(-g, 0.0)),
            "dual_feasibility": self.max(np.maximum(-lam, 0.0)),
            "complementarity": self.max(np.abs(lam * g)),
            "stationarity": stationarity,
        }
        nodal.set_multiplier(lam)
        return {
            "active_nodes": self.count(active),
            "kkt": kkt,
            "scales": {"gap": self.gap_scale, "force": force, "load": load},
            "multiplier": nodal.multiplier,
            "contact_pressure": nodal.contact_pressure,
        }


def factor_mb(ksp: PETSc.KSP) -> float:
    """MUMPS' memory of ``ksp``'s factorization in MB, summed over ranks (INFOG(22)); 0
    when it has none."""
    try:
        F = ksp.getPC().getFactorMatrix()
        return float(F.getMumpsInfog(22))
    except PETSc.Error:
        return 0.0
