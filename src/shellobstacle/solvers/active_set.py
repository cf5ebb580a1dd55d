"""Exact solver of the discrete obstacle problem P_M^{ε,h} with nodal constraints (MODEL.md §3, §5).

For P1 elements with the constraint imposed at the vertices, the discrete
variational inequality is the quadratic program

:math:`\\min_{η ∈ V_h} J(η) = \\tfrac12 η^T K η - f^T η` subject to
:math:`g_i(η) = θ(x_i)·q + c(x_i)·η(x_i) ≥ 0` at every vertex :math:`x_i`,

with ``K`` the (linear, ``κ``-independent) membrane stiffness matrix and ``f`` the
load vector, both with the problem's homogeneous Dirichlet conditions. It is the
limit ``κ → 0`` of the penalized problem with ``penalty_quadrature = "vertex"``.

Each constraint involves only the three degrees of freedom of its vertex. A
nodal rotation ``η_i = Q_i u_i`` (``Q_i`` orthogonal, first free axis along
``c(x_i)``) makes it a simple lower bound ``u_{i,k} ≥ −θ(x_i)·q / |c(x_i)|`` on one
rotated degree of freedom, so the rotated problem ``K' = Qᵀ K Q``, ``f' = Qᵀ f`` is
a bound-constrained QP, solved by PETSc's reduced-space semismooth Newton for
variational inequalities (``SNESVINEWTONRSLS``), in parallel.

KKT conditions at the solution ``(ζ^h, λ)`` (``B`` the constraint matrix, row ``i``
is ``c(x_i)`` on the dofs of vertex ``i``):
``K ζ − f − Bᵀλ = 0``, ``g_i ≥ 0``, ``λ_i ≥ 0``, ``λ_i g_i = 0``. The multiplier ``λ_i``
is the nodal contact force (``λ ≥ 0`` pushes the shell away from the plane); divided
by the lumped mass ``∫ φ_i √a dy`` it is a contact pressure. The penalized
solutions approximate it by ``λ_κ,i = (ε/κ) m^0_i {g_i}^- / |c_i|`` with
``m^0_i = ∫ φ_i dy``.
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
from shellobstacle.solvers.newton import ConvergenceError

__all__ = ["ActiveSetOptions", "ActiveSetResult", "ActiveSetSolver", "nodal_rotations"]

LINE_SEARCHES = ("bt", "basic", "l2", "cp")


@dataclass(frozen=True)
class ActiveSetOptions:
    """Stopping rules of :class:`ActiveSetSolver`.

    Attributes:
        rtol: stop when the residual on the inactive set is below ``rtol`` times the norm of the
            load vector (the residual at ``ζ = 0``).
        atol: absolute floor of the same test.
        floor_factor: the residual is also accepted once it is below ``floor_factor · u ·
            ‖K'‖_∞ ‖u‖_∞ √n`` (``u`` the machine epsilon): the round-off of ``K'u − f'``.
        max_iterations: give up (and raise) after this many semismooth Newton steps.
        line_search: PETSc line search of the VI Newton (``"bt"``, ``"basic"``, ``"l2"``, ``"cp"``).
        active_tol: a vertex counts as active when its rotated gap ``g_i`` is at most
            ``active_tol · max θ·q`` (PETSc puts active unknowns exactly on their bound).
        warm_start: start from the current ``problem.zeta`` (projected onto the constraints)
            instead of from zero.
    """

    rtol: float = 1e-13
    atol: float = 1e-50
    floor_factor: float = 100.0
    max_iterations: int = 100
    line_search: str = "bt"
    active_tol: float = 1e-12
    warm_start: bool = True

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if self.line_search not in LINE_SEARCHES:
            raise ValueError(f"line_search must be one of {LINE_SEARCHES}, got {self.line_search!r}")
        if not (self.rtol >= 0 and self.atol >= 0 and self.active_tol >= 0):
            raise ValueError("rtol, atol and active_tol must be >= 0")


@dataclass
class ActiveSetResult:
    """What an active-set solve did, and the KKT quality of its answer.

    Attributes:
        converged: whether the VI Newton met its stopping rule.
        iterations: semismooth Newton steps taken.
        active_nodes: global number of vertices where the constraint is active.
        reason: PETSc's converged/diverged reason, spelled out.
        kkt: ``primal_feasibility = max_i {g_i}^-``, ``dual_feasibility = max_i {λ_i}^-``,
            ``complementarity = max_i |λ_i g_i|`` (absolute values; see ``scales``) and
            ``stationarity = ‖K ζ − f − Bᵀλ‖ / ‖f‖`` (relative, Euclidean norms of nodal
            vectors, computed in the original unrotated unknowns).
        scales: natural sizes to read the KKT numbers against: ``gap`` (``max θ·q``),
            ``force`` (``max_i |λ_i|``, or ``‖f‖_∞`` if there is no contact) and ``load``
            (``‖f‖``).
        residual_norms: PETSc's residual norm (on the inactive set) after each iteration.
        timings: seconds spent in ``setup`` (stiffness, rotation, ``QᵀKQ``, once per solver),
            ``assemble`` (load), ``solve`` (SNES) and ``kkt`` (post-processing), and ``total``.
        multiplier: ``λ`` (nodal contact forces) as a P1 Function.
        contact_pressure: ``λ_i / ∫ φ_i √a dy`` as a P1 Function.
    """

    converged: bool
    iterations: int
    active_nodes: int
    reason: str
    kkt: dict[str, float] = field(default_factory=dict)
    scales: dict[str, float] = field(default_factory=dict)
    residual_norms: list[float] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    multiplier: dolfinx.fem.Function | None = None
    contact_pressure: dolfinx.fem.Function | None = None


def nodal_rotations(
    c: np.ndarray, free: np.ndarray, rel_tol: float = 1e-12
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthogonal 3×3 matrices ``Q_i`` whose column ``k_i`` is the free part of ``c_i``, normalized.

    ``Q_i`` is a Householder reflection (with one column's sign flipped) that acts only on the
    free (non-Dirichlet) components of vertex ``i``: ``Q_i e_j = e_j`` for every fixed component
    ``j``, so fixed unknowns stay fixed in the rotated basis, and
    ``c_i · (Q_i u) = |c_i^F| u_k``.

    Args:
        c: ``c_j(x_i) = a^j(x_i)·q``, shape ``(n, 3)``.
        free: which components of each vertex are free, shape ``(n, 3)``, bool.
        rel_tol: a vertex is unconstrained when ``|c_i^F| ≤ rel_tol · max_i |c_i|``.

    Returns:
        ``(Q, k, cn)``: ``Q`` of shape ``(n, 3, 3)``, ``k`` the index of the constrained rotated
        component (``-1`` where the vertex carries no constraint), ``cn = |c_i^F|``.
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
        nv = cf[idx] / cn[idx, None]
        kk = np.argmax(np.abs(nv) * free[idx], axis=1)
        s = np.where(nv[np.arange(idx.size), kk] >= 0, 1.0, -1.0)
        v = s[:, None] * nv  # n' = s n, with n'_k = |n_k| > 0
        v[np.arange(idx.size), kk] += 1.0  # v = e_k + n', |v|² = 2 + 2|n_k| ≥ 2
        H = np.eye(3)[None] - 2.0 * v[:, :, None] * v[:, None, :] / np.sum(v * v, axis=1)[:, None, None]
        H[np.arange(idx.size), :, kk] *= -s[:, None]  # H e_k = −n' → Q e_k = n
        Q[idx] = H
        k[idx] = kk
    return Q, k, cn


def _reason_name(reason: int) -> str:
    names = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items() if isinstance(v, int)}
    return f"{names.get(reason, 'UNKNOWN')} ({reason})"


class ActiveSetSolver:
    """Exact solver of the discrete obstacle problem (κ = 0) of one P1 :class:`PenalizedProblem`.

    The stiffness matrix, the nodal rotation and ``K' = QᵀKQ`` are built once; each
    :meth:`solve` re-assembles only the load (so load parameters may change between solves).

    Args:
        problem: a P1 problem with ``penalty_quadrature = "vertex"`` (its ``κ`` is ignored).
        options: stopping rules.

    Raises:
        ValueError: for other discretizations, or when a vertex where every component is fixed
            lies outside the half-space (no admissible displacement).
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
        self.options = opts = options or ActiveSetOptions()
        self.timings: dict[str, float] = {"setup": 0.0, "assemble": 0.0, "solve": 0.0, "kkt": 0.0}
        t0 = time.perf_counter()
        V = problem.V
        self.comm: MPI.Comm = problem.mesh.comm
        im = V.dofmap.index_map
        self.bs = bs = V.dofmap.index_map_bs
        if bs != 3:  # pragma: no cover (PenalizedProblem always builds a 3-vector space)
            raise ValueError(f"expected a 3-vector space, got block size {bs}")
        self.n = n = im.size_local

        # elastic stiffness K (Dirichlet rows/columns → identity) and the load form
        mat = problem.shell.material
        du, v = ufl.TrialFunction(V), ufl.TestFunction(V)
        G = problem.G
        a = (
            mat.epsilon
            * elastic_product(G, mat.lam, mat.mu, problem.strain_of(du), problem.strain_of(v))
            * G.sqrt_a
            * problem.dx
        )
        self.a_form = dolfinx.fem.form(a)
        self.K = dolfinx.fem.petsc.assemble_matrix(self.a_form, bcs=problem.bcs)
        self.K.assemble()

        # vertex data: θ·q, c = (a^j·q)_j, which components are free
        points = V.tabulate_dof_coordinates()[:n]
        geo = problem.shell.surface.geometry_numpy(points)
        q = problem.q
        self.theta_q = np.broadcast_to(
            sum(np.asarray(geo.theta[j], float) * q[j] for j in range(3)), (n,)
        ).copy()
        self.c = np.column_stack([np.broadcast_to(np.asarray(cj, float), (n,)) for cj in geo.c(q)])
        free = np.ones(n * bs, dtype=bool)
        for bc in problem.bcs:
            dofs, first_ghost = bc.dof_indices()
            free[dofs[:first_ghost]] = False
        self.free = free.reshape(n, bs)
        self.Qn, self.k, self.cn = nodal_rotations(self.c, self.free)
        self.constrained = self.k >= 0
        bad = (~self.constrained) & (self.theta_q < 0)
        if self.comm.allreduce(int(bad.sum()), op=MPI.SUM):
            raise ValueError(
                "a vertex whose displacement is fixed lies below the plane (θ·q < 0): "
                "the obstacle problem has no admissible displacement"
            )
        self.gap_scale = float(
            self.comm.allreduce(float(np.max(np.abs(self.theta_q), initial=0.0)), op=MPI.MAX)
        )
        rows = np.arange(n)[self.constrained]
        self.psi = np.zeros(n)
        self.psi[rows] = -self.theta_q[rows] / self.cn[rows]  # bound of u_{i,k}

        # block-diagonal Q (global block rows r0 … r0+n−1) and K' = Qᵀ K Q
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

        # bounds, work vectors and the SNES
        self.u, self.fr = self.Kr.createVecs()
        self.F = self.fr.duplicate()
        self.f = self.fr.duplicate()
        self.lower, self.upper = self.u.duplicate(), self.u.duplicate()
        lo = np.full((n, bs), PETSc.NINFINITY)
        lo[rows, self.k[rows]] = self.psi[rows]
        self.lower.array[:] = lo.reshape(-1)
        self.upper.set(PETSc.INFINITY)
        self.snes = PETSc.SNES().create(self.comm)
        self.snes.setOptionsPrefix(f"shellobstacle_as_{id(self)}_")
        self.snes.setType("vinewtonrsls")
        self.snes.setFunction(self._function, self.F)
        self.snes.setJacobian(self._jacobian, self.Kr, self.Kr)
        self.snes.setVariableBounds(self.lower, self.upper)
        self.snes.getLineSearch().setType(opts.line_search)
        ksp = self.snes.getKSP()
        ksp.setType("preonly")
        pc = ksp.getPC()
        pc.setType("lu")
        pc.setFactorSolverType("mumps")
        self.snes.setConvergenceTest(self._converged)
        self.snes.setTolerances(max_it=opts.max_iterations)
        self.snes.setFromOptions()
        self._history: list[float] = []

        # the multiplier lives on P1 (collapsed first component: dof j ↔ vertex map[j] // 3)
        P1, parent = V.sub(0).collapse()
        self.P1 = P1
        self._node_of = np.asarray(parent) // bs
        self._n1 = P1.dofmap.index_map.size_local
        self.multiplier = dolfinx.fem.Function(P1, name="multiplier")
        self.contact_pressure = dolfinx.fem.Function(P1, name="contact_pressure")
        phi = ufl.TestFunction(P1)
        mass = dolfinx.fem.assemble_vector(dolfinx.fem.form(phi * G.sqrt_a * problem.dx_penalty))
        mass.scatter_reverse(dolfinx.la.InsertMode.add)
        mass.scatter_forward()
        self.mass = mass.array.copy()  # lumped ∫ φ_j √a dy of all local P1 dofs
        self.timings["setup"] = time.perf_counter() - t0

    # -- SNES callbacks -----------------------------------------------------------------------
    def _function(self, snes: PETSc.SNES, x: PETSc.Vec, F: PETSc.Vec) -> None:
        """``F(u) = K'u − f'``."""
        self.Kr.mult(x, F)
        F.axpy(-1.0, self.fr)

    def _jacobian(self, snes: PETSc.SNES, x: PETSc.Vec, J: PETSc.Mat, P: PETSc.Mat) -> None:
        """``K'`` is constant: nothing to do."""

    def _converged(self, snes: PETSc.SNES, it: int, norms: tuple[float, float, float]) -> int:
        """Stop on ``‖F_inactive‖ ≤ max(atol, rtol ‖f'‖, round-off floor)``."""
        _, _, fnorm = norms
        self._history.append(float(fnorm))
        if not math.isfinite(fnorm):
            return PETSc.SNES.ConvergedReason.DIVERGED_FNORM_NAN
        if fnorm <= self._atol:
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_ABS
        if it >= self.options.max_iterations:
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        return PETSc.SNES.ConvergedReason.ITERATING

    # -- helpers ------------------------------------------------------------------------------
    def _round_off(self) -> float:
        """Round-off level of ``‖K'u − f'‖`` at a solution of size ``‖u‖_∞`` (global)."""
        eps = np.finfo(PETSc.ScalarType).eps
        norm_k = self.Kr.norm(PETSc.NormType.NORM_INFINITY)
        size = math.sqrt(self.Kr.getSize()[0])
        return self.options.floor_factor * eps * norm_k * self._u_scale * size

    def _owned(self, vec: PETSc.Vec) -> np.ndarray:
        return vec.array_r.reshape(self.n, self.bs)

    # -- solve --------------------------------------------------------------------------------
    def solve(self) -> ActiveSetResult:
        """Solve the discrete obstacle problem; leave ``ζ^h`` in ``problem.zeta``.

        Returns:
            The :class:`ActiveSetResult` with the multiplier, contact pressure and KKT measures.

        Raises:
            ConvergenceError: if the VI Newton does not converge; ``problem.zeta`` then holds
                the last iterate and ``err.result`` the :class:`ActiveSetResult`.
        """
        opts, problem = self.options, self.problem
        t_start = time.perf_counter()
        comm = self.comm

        ta = time.perf_counter()
        with self.f.localForm() as loc:
            loc.set(0.0)
        b = dolfinx.fem.petsc.assemble_vector(problem.forms["load"])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        dolfinx.fem.petsc.set_bc(b, problem.bcs)
        self.f.array[:] = b.array_r[: self.n * self.bs]
        b.destroy()
        self.Q.multTranspose(self.f, self.fr)
        load_norm = self.f.norm()
        self.timings["assemble"] += time.perf_counter() - ta

        # start: Qᵀζ (warm) or 0, projected onto the bounds (PETSc projects too)
        zeta = problem.zeta
        if opts.warm_start:
            dolfinx.fem.petsc.set_bc(zeta.x.petsc_vec, problem.bcs)
            zeta.x.scatter_forward()
            self.Q.multTranspose(zeta.x.petsc_vec, self.u)
        else:
            self.u.set(0.0)
        self.u.pointwiseMax(self.u, self.lower)
        # round-off floor with the size of the solution bounded by that of the bounds and start
        self._u_scale = max(
            self.u.norm(PETSc.NormType.NORM_INFINITY),
            comm.allreduce(float(np.max(np.abs(self.psi), initial=0.0)), op=MPI.MAX),
        )
        self._atol = max(opts.atol, opts.rtol * load_norm, self._round_off())
        self._history = []

        ts = time.perf_counter()
        self.snes.solve(None, self.u)
        self.timings["solve"] += time.perf_counter() - ts
        reason = self.snes.getConvergedReason()
        iterations = self.snes.getIterationNumber()

        # ζ = Q u
        self.Q.mult(self.u, zeta.x.petsc_vec)
        zeta.x.scatter_forward()

        tk = time.perf_counter()
        result = self._kkt(load_norm)
        self.timings["kkt"] += time.perf_counter() - tk
        result.converged = reason > 0
        result.iterations = iterations
        result.reason = _reason_name(reason)
        result.residual_norms = list(self._history)
        result.timings = dict(self.timings) | {"total": time.perf_counter() - t_start}
        if not result.converged:
            raise ConvergenceError(
                f"the active-set (SNES VI) solver did not converge: {result.reason} after "
                f"{iterations} iterations; inactive-set residual "
                f"{self._history[-1] if self._history else math.nan:.3e} "
                f"(target {self._atol:.3e})",
                result,
            )
        return result

    def _kkt(self, load_norm: float) -> ActiveSetResult:
        """Multiplier, active set and KKT measures of the current ``u`` (``ζ = Qu`` in place)."""
        comm, n, bs = self.comm, self.n, self.bs
        rows = np.flatnonzero(self.constrained)
        u = self._owned(self.u)
        # rotated residual r' = K'u − f'; the multiplier is its constrained component / |c|
        self._function(self.snes, self.u, self.F)
        r = self._owned(self.F)
        g_rot = np.full(n, np.inf)
        g_rot[rows] = self.cn[rows] * (u[rows, self.k[rows]] - self.psi[rows])
        active = g_rot <= self.options.active_tol * self.gap_scale
        lam = np.zeros(n)
        ia = np.flatnonzero(active)
        lam[ia] = r[ia, self.k[ia]] / self.cn[ia]

        # gap and stationarity in the original unknowns: g = θ·q + c·ζ, K ζ − f − Bᵀλ
        eta = self.problem.zeta.x.array[: n * bs].reshape(n, bs)
        g = self.theta_q + np.sum(self.c * eta, axis=1)
        res = self.F.duplicate()
        self.K.mult(self.problem.zeta.x.petsc_vec, res)
        res.axpy(-1.0, self.f)
        ra = res.array.reshape(n, bs)
        ra -= np.where(self.free, self.c, 0.0) * lam[:, None]
        stat = res.norm()
        res.destroy()

        def gmax(x: np.ndarray) -> float:
            return float(comm.allreduce(float(np.max(x, initial=0.0)), op=MPI.MAX))

        force = gmax(np.abs(lam))
        if force == 0.0:
            force = self.f.norm(PETSc.NormType.NORM_INFINITY)
        kkt = {
            "primal_feasibility": gmax(np.maximum(-g, 0.0)),
            "dual_feasibility": gmax(np.maximum(-lam, 0.0)),
            "complementarity": gmax(np.abs(lam * g)),
            "stationarity": stat / load_norm if load_norm > 0 else stat,
        }
        scales = {"gap": self.gap_scale, "force": force, "load": load_norm}

        # λ and λ/m as P1 Functions (owned values, then ghosts)
        lam_local = np.zeros(self._node_of.max(initial=-1) + 1)
        lam_local[:n] = lam
        owned = self._node_of[: self._n1]
        self.multiplier.x.array[: self._n1] = lam_local[owned]
        self.multiplier.x.scatter_forward()
        with np.errstate(divide="ignore", invalid="ignore"):
            pressure = np.where(self.mass > 0, self.multiplier.x.array / self.mass, 0.0)
        self.contact_pressure.x.array[:] = pressure
        self.contact_pressure.x.scatter_forward()
        return ActiveSetResult(
            converged=False,
            iterations=0,
            active_nodes=int(comm.allreduce(int(active.sum()), op=MPI.SUM)),
            reason="",
            kkt=kkt,
            scales=scales,
            multiplier=self.multiplier,
            contact_pressure=self.contact_pressure,
        )
