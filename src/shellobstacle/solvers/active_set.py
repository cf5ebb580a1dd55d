"""Exact solver of the discrete obstacle problem P_M^{ε,h} with nodal constraints (MODEL.md §3, §5).

For P1 elements with the constraint imposed at the vertices, the discrete
variational inequality (``κ = 0``) is the strictly convex quadratic program

:math:`\\min_{η ∈ V_h} J(η) = \\tfrac12 η^T K η - f^T η` subject to
:math:`g_i(η) = θ(x_i)·q + c(x_i)·η(x_i) ≥ 0` at every vertex :math:`x_i`,

with ``K`` the (linear, ``κ``-independent) membrane stiffness matrix and ``f`` the
load vector, both carrying the problem's homogeneous Dirichlet conditions. It is
the limit ``κ → 0`` of the penalized problem with ``penalty_quadrature = "vertex"``.

**Nodal rotation.** Each constraint involves only the three unknowns of its
vertex. An orthogonal change of variables ``η_i = Q_i u_i`` per vertex (a
Householder reflection whose column ``k_i`` is ``c(x_i)/|c(x_i)|``; it leaves fixed
Dirichlet components alone) turns it into a lower bound on one rotated unknown,
``u_{i,k_i} ≥ ψ_i = −θ(x_i)·q / |c(x_i)|``. With the block-diagonal ``Q`` (a PETSc
matrix, block size 3), ``K' = QᵀKQ`` and ``f' = Qᵀf`` the problem is a
bound-constrained QP.

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
``c(x_i)`` on the unknowns of vertex ``i``): ``K ζ − f − Bᵀλ = 0``, ``g_i ≥ 0``,
``λ_i ≥ 0``, ``λ_i g_i = 0``. The multiplier ``λ_i = (K'u − f')_{i,k_i} / |c(x_i)|`` is
the nodal contact force (``λ ≥ 0`` pushes the shell away from the plane); divided by
the lumped mass ``∫ φ_i √a dy`` it is a contact pressure. A penalized solution
approximates it by ``(ε/κ) m^0_i {g_i}^- / |c(x_i)|`` with ``m^0_i = ∫ φ_i dy``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from shellobstacle import compat  # noqa: F401  (must precede dolfinx / petsc4py)

# isort: split
import dolfinx
import dolfinx.fem.petsc
import dolfinx.la
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shellobstacle.membrane import elastic_product
from shellobstacle.problem import PenalizedProblem
from shellobstacle.solvers.line_search import piecewise_linear_root
from shellobstacle.solvers.newton import ConvergenceError
from shellobstacle.solvers.options import unique_prefix

__all__ = ["ActiveSetOptions", "ActiveSetResult", "ActiveSetSolver", "nodal_rotations"]


@dataclass(frozen=True)
class ActiveSetOptions:
    """Path-following schedule, limits and acceptance tolerance of :class:`ActiveSetSolver`.

    Attributes:
        max_iterations: give up (and raise) after this many linear solves in total.
        gamma_initial: first Moreau–Yosida parameter ``γ`` (penalty ``γ K'_bb`` per constraint).
        gamma_factor: ``γ`` is multiplied by this between path-following stages.
        gamma_max: largest ``γ``; beyond it the solver gives up.
        max_stage_iterations: semismooth Newton steps allowed for one ``γ``.
        max_pdas_iterations: primal–dual active-set steps per attempt before ``γ`` grows.
        kkt_rtol: the answer is accepted only if the relative KKT measures
            (:attr:`ActiveSetResult.relative_kkt`) are all at most this.
        warm_start: start from the current ``problem.zeta`` (first trying active-set steps
            from it) instead of from zero.
    """

    max_iterations: int = 200
    gamma_initial: float = 1e-4
    gamma_factor: float = 100.0
    gamma_max: float = 1e16
    max_stage_iterations: int = 50
    max_pdas_iterations: int = 6
    kkt_rtol: float = 1e-10
    warm_start: bool = True

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if self.max_stage_iterations < 1 or self.max_pdas_iterations < 1:
            raise ValueError("max_stage_iterations and max_pdas_iterations must be >= 1")
        if not 0 < self.gamma_initial <= self.gamma_max:
            raise ValueError(
                f"need 0 < gamma_initial <= gamma_max, got {self.gamma_initial}, {self.gamma_max}"
            )
        if not self.gamma_factor > 1:
            raise ValueError(f"gamma_factor must be > 1, got {self.gamma_factor}")
        if not self.kkt_rtol > 0:
            raise ValueError(f"kkt_rtol must be > 0, got {self.kkt_rtol}")


@dataclass
class ActiveSetResult:
    """What an active-set solve did, and the KKT quality of its answer.

    Attributes:
        converged: whether the active set settled and the KKT measures pass ``kkt_rtol``.
        iterations: linear solves in total (``newton_steps + pdas_steps``).
        active_nodes: global number of vertices in the final active set.
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
        multiplier: ``λ`` (nodal contact forces), a P1 Function (the solver's own, refreshed
            by each :meth:`ActiveSetSolver.solve`: copy it to keep it).
        contact_pressure: ``λ_i / ∫ φ_i √a dy``, a P1 Function (likewise refreshed).
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


def nodal_rotations(
    c: np.ndarray, free: np.ndarray, rel_tol: float = 1e-12
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthogonal 3×3 matrices ``Q_i`` whose column ``k_i`` is the free part of ``c_i``, normalized.

    ``Q_i`` is a Householder reflection (with column ``k_i`` negated where needed) acting only
    on the free (non-Dirichlet) components of vertex ``i``: ``Q_i e_j = e_j`` for every fixed
    component ``j``, so fixed unknowns stay fixed in the rotated basis, and
    ``c_i · (Q_i u) = |c_i^F| u_{k_i}`` (``c_i^F`` the free part of ``c_i``).

    Args:
        c: ``c_j(x_i) = a^j(x_i)·q``, shape ``(n, 3)``.
        free: which components of each vertex are free, shape ``(n, 3)``, bool.
        rel_tol: a vertex carries no constraint when ``|c_i^F| ≤ rel_tol · max_i |c_i|``.

    Returns:
        ``(Q, k, cn)``: ``Q`` of shape ``(n, 3, 3)``, ``k`` the index of the constrained rotated
        component (``-1`` where the vertex carries no constraint), and ``cn = |c_i^F|``.
    """
    n = c.shape[0]
    cf = np.where(free, c, 0.0)
    cn = np.linalg.norm(cf, axis=1)
    cmax = float(np.max(np.linalg.norm(c, axis=1), initial=0.0))
    constrained = cn > rel_tol * cmax if cmax > 0 else np.zeros(n, dtype=bool)
    Q = np.tile(np.eye(3), (n, 1, 1))
    k = np.full(n, -1, dtype=np.int64)
    idx = np.flatnonzero(constrained)
    if idx.size:
        m = np.arange(idx.size)
        nv = cf[idx] / cn[idx, None]
        kk = np.argmax(np.abs(nv) * free[idx], axis=1)
        s = np.where(nv[m, kk] >= 0, 1.0, -1.0)
        v = s[:, None] * nv  # n' = s n has n'_k = |n_k| > 0 ...
        v[m, kk] += 1.0  # ... so v = e_k + n' has |v|² = 2 + 2|n_k| ≥ 2 (no cancellation)
        H = np.eye(3)[None] - 2.0 * v[:, :, None] * v[:, None, :] / np.sum(v * v, 1)[:, None, None]
        H[m, :, kk] *= -s[:, None]  # H e_k = −n' = −s n, so the flipped column is n
        Q[idx] = H
        k[idx] = kk
    return Q, k, cn


class ActiveSetSolver:
    """Exact solver of the discrete obstacle problem (κ = 0) of one P1 :class:`PenalizedProblem`.

    The stiffness matrix, the nodal rotation and ``K' = QᵀKQ`` are built once; each
    :meth:`solve` re-assembles only the load, so load parameters may change between solves.

    Args:
        problem: a P1 problem with ``penalty_quadrature = "vertex"`` (its ``κ`` is not used).
        options: schedule, limits and tolerance.

    Raises:
        ValueError: for other discretizations, or when a vertex whose displacement is fixed
            lies below the plane (no admissible displacement).
    """

    def __init__(self, problem: PenalizedProblem, options: ActiveSetOptions | None = None) -> None:
        disc = problem.disc
        if disc.degree != 1 or disc.penalty_quadrature != "vertex":
            raise ValueError(
                "ActiveSetSolver solves the nodal (vertex) constraint of P1 elements: it needs "
                "Discretization(degree=1, penalty_quadrature='vertex'), got "
                f"degree={disc.degree}, penalty_quadrature={disc.penalty_quadrature!r}"
            )
        self.problem = problem
        self.options = options or ActiveSetOptions()
        self.timings: dict[str, float] = {"setup": 0.0, "assemble": 0.0, "solve": 0.0, "kkt": 0.0}
        t0 = time.perf_counter()
        V = problem.V
        self.comm: MPI.Comm = problem.mesh.comm
        im = V.dofmap.index_map
        self.bs = bs = V.dofmap.index_map_bs
        self.n = n = im.size_local

        # elastic stiffness K (Dirichlet rows and columns → identity)
        mat, G = problem.shell.material, problem.G
        du, v = ufl.TrialFunction(V), ufl.TestFunction(V)
        gam_u, gam_v = problem.strain_of(du), problem.strain_of(v)
        a = mat.epsilon * elastic_product(G, mat.lam, mat.mu, gam_u, gam_v) * G.sqrt_a * problem.dx
        self.a_form = dolfinx.fem.form(a)
        self.K = dolfinx.fem.petsc.assemble_matrix(self.a_form, bcs=problem.bcs)
        self.K.assemble()

        # vertex data: θ·q, c_j = a^j·q, free components
        points = V.tabulate_dof_coordinates()[:n]
        geo = problem.shell.surface.geometry_numpy(points)
        q = problem.q
        theta_q = sum(np.asarray(geo.theta[j], float) * q[j] for j in range(3))
        self.theta_q = np.broadcast_to(theta_q, (n,)).copy()
        self.c = np.column_stack([np.broadcast_to(np.asarray(cj, float), (n,)) for cj in geo.c(q)])
        free = np.ones(n * bs, dtype=bool)
        for bc in problem.bcs:
            dofs, first_ghost = bc.dof_indices()
            free[dofs[:first_ghost]] = False
        self.free = free.reshape(n, bs)
        self.Qn, self.k, self.cn = nodal_rotations(self.c, self.free)
        self.nodes = np.flatnonzero(self.k >= 0)  # constrained vertices (local)
        bad = np.flatnonzero((self.k < 0) & (self.theta_q < 0))
        if self.comm.allreduce(int(bad.size), op=MPI.SUM):
            raise ValueError(
                "a vertex whose displacement is fixed lies below the plane (θ·q < 0): "
                "the obstacle problem has no admissible displacement"
            )
        self.gap_scale = self._max(np.abs(self.theta_q))
        self.iB = bs * self.nodes + self.k[self.nodes]  # constrained rotated unknowns (local)
        self.psi = -self.theta_q[self.nodes] / self.cn[self.nodes]  # u_b ≥ ψ_b

        # block-diagonal Q (global block rows r0 … r0 + n − 1) and K' = Qᵀ K Q
        r0 = im.local_range[0]
        cols = (bs * (r0 + np.arange(n)))[:, None, None] + np.arange(bs)[None, None, :]
        indices = np.broadcast_to(cols, (n, bs, bs)).reshape(-1).astype(PETSc.IntType)
        indptr = np.arange(0, n * bs * bs + 1, bs, dtype=PETSc.IntType)
        self.Q = PETSc.Mat().createAIJ(
            ((n * bs, PETSc.DETERMINE), (n * bs, PETSc.DETERMINE)),
            bsize=bs,
            csr=(indptr, indices, self.Qn.reshape(-1).astype(PETSc.ScalarType)),
            comm=self.comm,
        )
        self.Q.assemble()
        self.Kr = self.K.ptap(self.Q)
        self.row0 = self.Kr.getOwnershipRange()[0]
        self.diag = self.Kr.getDiagonal()
        self.d = self.diag.array_r[self.iB].copy()  # K'_bb > 0

        # work matrix (K' modified per step, same sparsity) and the direct solver
        self.W = self.Kr.duplicate(copy=True)
        self.W.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
        self.ksp = PETSc.KSP().create(self.comm)
        self.ksp.setOptionsPrefix(unique_prefix("as"))
        self.ksp.setOperators(self.W)
        self.ksp.setType("preonly")
        pc = self.ksp.getPC()
        pc.setType("lu")
        pc.setFactorSolverType("mumps")
        self.ksp.setFromOptions()
        self.u, self.fr = self.Kr.createVecs()
        self.f, self.r, self.du, self.tmp = (self.fr.duplicate() for _ in range(4))

        # the multiplier lives on P1 (collapsed first component: dof j ↔ vertex parent[j] // 3)
        P1, parent = V.sub(0).collapse()
        self.P1 = P1
        self._node_of = np.asarray(parent).reshape(-1) // bs
        self._n1 = P1.dofmap.index_map.size_local
        self.multiplier = dolfinx.fem.Function(P1, name="multiplier")
        self.contact_pressure = dolfinx.fem.Function(P1, name="contact_pressure")
        phi = ufl.TestFunction(P1)
        mass = dolfinx.fem.assemble_vector(dolfinx.fem.form(phi * G.sqrt_a * problem.dx_penalty))
        mass.scatter_reverse(dolfinx.la.InsertMode.add)
        mass.scatter_forward()
        self.mass = mass.array.copy()  # lumped ∫ φ_j √a dy of the local P1 dofs
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
    def _linear_solve(self, rhs: PETSc.Vec, x: PETSc.Vec) -> None:
        t = time.perf_counter()
        self.ksp.solve(rhs, x)
        self.timings["solve"] += time.perf_counter() - t
        if self.ksp.getConvergedReason() < 0:
            raise RuntimeError(
                f"linear solve failed (PETSc reason {self.ksp.getConvergedReason()})"
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
            self._linear_solve(self.r, self.u)
            self.u.array[self.iB[active]] = self.psi[active]  # exactly on the bound
            self.Kr.mult(self.u, self.r)
            self.r.axpy(-1.0, self.fr)
            lam = np.where(active, self.r.array_r[self.iB], 0.0)
            new = lam + self.d * (self.psi - self.u.array_r[self.iB]) > 0
            history.append(self._count(new))
            if not self._differ(new, active):
                return step, True
            active = new
        return step, False

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
        except RuntimeError as err:  # failed linear solve
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
        n, bs, nodes = self.n, self.bs, self.nodes
        uB = self.u.array_r[self.iB]
        self.Kr.mult(self.u, self.r)
        self.r.axpy(-1.0, self.fr)
        on_bound = uB <= self.psi  # PDAS puts the active unknowns exactly on the bound
        lam = np.zeros(n)
        lam[nodes[on_bound]] = self.r.array_r[self.iB[on_bound]] / self.cn[nodes[on_bound]]

        # gap and stationarity in the original unknowns: g = θ·q + c·ζ, K ζ − f − Bᵀλ
        eta = self.problem.zeta.x.array[: n * bs].reshape(n, bs)
        g = self.theta_q + np.sum(self.c * eta, axis=1)
        self.K.mult(self.problem.zeta.x.petsc_vec, self.tmp)
        self.tmp.axpy(-1.0, self.f)
        self.tmp.array[:] -= (np.where(self.free, self.c, 0.0) * lam[:, None]).reshape(-1)
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

        # λ and λ / ∫ φ √a as P1 Functions
        lam_local = np.zeros(int(self._node_of.max(initial=-1)) + 1)
        lam_local[:n] = lam
        self.multiplier.x.array[: self._n1] = lam_local[self._node_of[: self._n1]]
        self.multiplier.x.scatter_forward()
        m = self.mass
        self.contact_pressure.x.array[:] = np.divide(
            self.multiplier.x.array, m, out=np.zeros_like(m), where=m > 0
        )
        return ActiveSetResult(
            converged=False,
            iterations=0,
            active_nodes=self._count(on_bound & (lam[nodes] > 0)),
            reason="",
            kkt=kkt,
            scales=scales,
            multiplier=self.multiplier,
            contact_pressure=self.contact_pressure,
        )
