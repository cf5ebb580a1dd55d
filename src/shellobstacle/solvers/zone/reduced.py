"""The penalized problem on the contact zone alone, and Newton's steps on it.

While no point outside the zone ``Z`` is active, ``ζ_I = K_II⁻¹ (f_I − K_IZ ζ_Z)`` minimizes
``J_κ`` over ``ζ_I`` and leaves a penalized problem on the zone's dofs,

    j(ζ_Z) = ½ ζ_Zᵀ K_S ζ_Z − f̃·ζ_Z + (1/(2κ)) Σ_{k ∈ P} D_k min(g_k, 0)²,

with ``K_S = K_ZZ − T``, ``f̃ = f_Z − K_ZI K_II⁻¹ f_I`` and the penalty points ``P`` inside the
zone (:mod:`~shellobstacle.solvers.zone.condensation`). From an iterate with ``R_I = 0`` a
Newton step of ``J_κ`` is ``S δ_Z = −∇j``, ``δ_I = −K_II⁻¹ K_IZ δ_Z``, and its exact line
search is that of ``j``: Newton steps of ``J_κ`` that touch only the zone's small matrices.
``∇j(ζ_Z)`` is ``R(ζ)`` on the zone (it vanishes on ``I``). At the end ``ζ_I`` costs one
back-substitution (:meth:`ZoneModel.complete`); if a point outside the zone became active,
Newton's next step is a full one, which grows the zone.

For the hybrid bending form the zone's unknowns also hold its facets' multipliers ``t_Z``
(:mod:`~shellobstacle.solvers.zone.multipliers`): ``j`` is then a function of ``(ζ_Z, t_Z)``,
started from the ``t_Z`` that minimizes it (:meth:`ZoneProblem.start`), and the norms that
stop Newton are taken over ``ζ_Z`` (:meth:`ZoneProblem.norm`), so that the steps are those of
the problem in ``ζ_Z`` alone.

Vectors of the zone's problem are sequential and the same on every rank.
"""

from __future__ import annotations

import time

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers.base import unique_prefix
from shellobstacle.solvers.newton.line_search import exact_step
from shellobstacle.solvers.newton.system import PenalizedSystem, abs_row_sums, floor_of
from shellobstacle.solvers.quadrature_penalty import QuadraturePenalty, gap_scale, penalty_hessian
from shellobstacle.solvers.zone.condensation import Condensation

__all__ = ["ZoneModel", "ZoneProblem"]


class ZoneProblem:
    """``j`` on the zone of ``cond``: its gap, residual, Jacobian and solves with it.

    Args:
        cond: the zone's condensation (``K_S``, ``f̃``, ``S`` and its factorization).
        penalty: the whole problem's penalty.
        points: the owned penalty points inside the zone.
        timings: seconds of the solves are added to its ``"condense"`` entry.
    """

    def __init__(
        self,
        cond: Condensation,
        penalty: QuadraturePenalty,
        points: np.ndarray,
        timings: dict[str, float],
    ) -> None:
        self.cond, self.timings = cond, timings
        self.comm: MPI.Comm = cond.comm
        M = penalty.M
        own = np.flatnonzero(points)
        P = np.concatenate(self.comm.allgather(own + M.getOwnershipRange()[0]))
        self.DP = np.concatenate(self.comm.allgather(penalty.D[own]))
        self.g0P = np.concatenate(self.comm.allgather(penalty.g0[own]))
        seq = PETSc.COMM_SELF
        isP = PETSc.IS().createGeneral(P.astype(PETSc.IntType), comm=seq)
        isZ = PETSc.IS().createGeneral(cond.Z_zeta.astype(PETSc.IntType), comm=seq)
        self.MP = M.createSubMatrices(isP, isZ)[0]  # rows: all the zone's points
        for obj in (isP, isZ):
            obj.destroy()
        m = cond.Z.size
        self.zeta_pos = None if cond.blocks is None else cond.zeta_pos  # ζ among the unknowns
        if self.zeta_pos is not None:  # MP's columns at ζ's positions, zero at multipliers'
            ip, ix, v = self.MP.getValuesCSR()
            self.MP.destroy()
            columns = self.zeta_pos[ix].astype(PETSc.IntType)
            self.MP = PETSc.Mat().createAIJ((P.size, m), csr=(ip, columns, v), comm=seq)
        self.component = np.zeros(m, dtype=np.int64)  # ζ_j of each zone dof
        self.component[cond.zeta_pos] = cond.Z_zeta % cond.bs
        self.wP = self.MP.createVecLeft()
        self.S_now = cond.S.duplicate(copy=False)  # the current Jacobian when S's are reused
        self.ksp_cg: PETSc.KSP | None = None  # CG on the zone, preconditioned by S's factors
        self._row_sums: np.ndarray | None = None  # Σ_j |K_S,ij|, made at the first rounding()
        self._tt: tuple | None = None  # the multipliers' block of K_S (minimize_multipliers)

    def destroy(self) -> None:
        for obj in (self.MP, self.wP, self.S_now, self.ksp_cg):
            if obj is not None:
                obj.destroy()

    def vector(self) -> PETSc.Vec:
        """A new sequential vector on the zone's dofs."""
        return self.cond.wseq.duplicate()

    def start(self, zeta: PETSc.Vec, f: PETSc.Vec, kappa: float, z: PETSc.Vec, r: PETSc.Vec):
        """``z ←`` the zone's unknowns at ``ζ`` (with multipliers, those that minimize ``j`` at
        ``ζ_Z``), ``r ← ∇j(z)``; returns ``g`` at the zone's points."""
        self.cond.gather_state(zeta, z)
        g = self.residual(z, f, kappa, r)
        if self.zeta_pos is not None:
            self._minimize_multipliers(z, r)
            g = self.residual(z, f, kappa, r)
        return g

    def _minimize_multipliers(self, z: PETSc.Vec, r: PETSc.Vec) -> None:
        """``t_Z ← t_Z − K_tt⁻¹ r_t``: ``j``'s minimizer over the multipliers, with ``K_tt``
        their block of ``K_S`` (``C`` on the diagonal, ``−T`` on those of ``Γ``)."""
        if self._tt is None:
            t = np.setdiff1d(np.arange(self.cond.Z.size), self.zeta_pos)
            diagonal = self.cond.Ks.getDiagonal()
            c = diagonal.array_r[t].copy()
            diagonal.destroy()
            gamma_t = np.intersect1d(self.cond.gamma, t).astype(PETSc.IntType)
            self._tt = (t, c, gamma_t, self.cond.Ks.getValues(gamma_t, gamma_t))
        t, c, gamma_t, L = self._tt
        step = np.zeros(z.getSize())
        step[t] = -r.array_r[t] / c
        if gamma_t.size:
            step[gamma_t] = -np.linalg.solve(L, r.array_r[gamma_t])
        z.array[:] += step

    def norm(self, v: PETSc.Vec, kind: PETSc.NormType = PETSc.NormType.NORM_2) -> float:
        """``‖v‖`` over the zone's dofs of ζ (its multipliers left out)."""
        if self.zeta_pos is None:
            return v.norm(kind)
        x = v.array_r[self.zeta_pos]
        if kind == PETSc.NormType.NORM_INFINITY:
            return float(np.abs(x).max(initial=0.0))
        return float(np.linalg.norm(x))

    def gap(self, z: PETSc.Vec) -> np.ndarray:
        """``g`` at the zone's points for ``ζ_Z = z``: the penalty's ``g⁰ + Bζ`` on their rows."""
        self.MP.mult(z, self.wP)
        return self.g0P + self.wP.array_r / self.DP

    def residual(self, z: PETSc.Vec, f: PETSc.Vec, kappa: float, r: PETSc.Vec) -> np.ndarray:
        """``r ← ∇j(z) = K_S z − f̃ + (1/κ) M_Pᵀ min(g, 0)`` for the load ``f``; returns ``g``
        at the zone's points."""
        self.cond.solve_load(f)
        g = self.gap(z)
        self.cond.Ks.mult(z, r)
        r.axpy(-1.0, self.cond.f_tilde)
        self.add_penalty(np.minimum(g, 0.0), kappa, r)
        return g

    def add_penalty(self, values: np.ndarray, kappa: float, r: PETSc.Vec) -> None:
        """``r ← r + (1/κ) M_Pᵀ values`` (``values`` at the zone's points)."""
        self.wP.array[:] = values / kappa
        self.MP.multTransposeAdd(self.wP, r, r)

    def gap_scale(self, z: PETSc.Vec) -> np.ndarray:
        """``|g(θ)| + Σ_j |ζ_j c_j|`` at the zone's points (the shared ``penalty.gap_scale``)."""
        x = z.duplicate()
        total = gap_scale(self.MP, self.DP, self.g0P, z.array_r.copy(), self.component, x, self.wP)
        x.destroy()
        return total

    def rounding(self, z: PETSc.Vec) -> float:
        """``u ‖|K_S| |z|‖``, the rounding of ``K_S z`` in :meth:`residual`, estimated by
        ``(Σ_j |K_S,ij|) |z_i|`` as :meth:`PenalizedSystem.elastic_rounding` does."""
        if self._row_sums is None:
            self._row_sums = abs_row_sums(self.cond.Ks)
        terms = self._row_sums * z.array_r
        if self.zeta_pos is not None:
            terms = terms[self.zeta_pos]
        return float(np.finfo(PETSc.ScalarType).eps * np.linalg.norm(terms))

    def _jacobian(self, S: PETSc.Mat, g: np.ndarray, kappa: float) -> None:
        """``S ← K_S + (1/κ) M_Aᵀ diag(1/D_A) M_A`` (``A``: zone points with g < 0)."""
        S.zeroEntries()
        S.axpy(1.0, self.cond.Ks, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        active = np.flatnonzero(g < 0)
        if active.size:
            P = penalty_hessian(self.MP, self.DP, active, kappa)
            S.axpy(1.0, P, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            P.destroy()

    def _factorize(self, g: np.ndarray, kappa: float) -> None:
        self.cond.S_factor.factorize(self.cond.S)
        self.cond.factor_state = (kappa, g < 0)

    def solve(
        self, g: np.ndarray, kappa: float, b: PETSc.Vec, d: PETSc.Vec, budget: int, rtol: float
    ) -> int:
        """``d ← S⁻¹ b`` for the zone's Jacobian ``S`` at the gap ``g`` (rank 0's on all ranks).

        With a kept factorization at this κ of a Jacobian whose active points differ from
        ``g``'s in at most ``budget`` points (each a rank-one change), conjugate gradients
        preconditioned by it, to ``rtol``; a new factorization when more points changed or
        CG needs more than ``budget`` iterations. Returns the CG iterations (0: factorized).
        """
        t0 = time.perf_counter()
        cond = self.cond
        kept = cond.factor_state
        changed = budget + 1
        if budget > 0 and kept is not None and kept[0] == kappa:
            changed = int(np.count_nonzero(kept[1] != (g < 0)))
        iterations = 0
        if changed <= budget:
            self._jacobian(self.S_now, g, kappa)
            if self.ksp_cg is None:
                self.ksp_cg = PETSc.KSP().create(PETSc.COMM_SELF)
                self.ksp_cg.setOptionsPrefix(unique_prefix("zone_cg"))
                self.ksp_cg.setType("cg")
                self.ksp_cg.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
                self.ksp_cg.getPC().setType("python")
                self.ksp_cg.getPC().setPythonContext(cond.S_factor.preconditioner())
                self.ksp_cg.setFromOptions()
            self.ksp_cg.setTolerances(rtol=rtol, atol=0.0, max_it=budget)
            self.ksp_cg.setOperators(self.S_now)
            self.ksp_cg.solve(b, d)
            iterations = self.ksp_cg.getIterationNumber()
            if self.ksp_cg.getConvergedReason() <= 0:
                self.S_now.copy(cond.S, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
                self._factorize(g, kappa)
                cond.S_factor.solve(b, d)
                iterations = 0
        else:
            self._jacobian(cond.S, g, kappa)
            self._factorize(g, kappa)
            cond.S_factor.solve(b, d)
        self.comm.Bcast(d.array, root=0)
        self.timings["condense"] += time.perf_counter() - t0
        return iterations


class ZoneModel:
    """Newton's model on the zone's problem, from the current iterate of ``system``.

    Args:
        problem: the zone's problem.
        system: the whole problem (its ``ζ`` is gathered now, completed by :meth:`complete`).
        seed: the zone's points to start from as active (a solve from an iterate without
            contact: :mod:`~shellobstacle.solvers.newton.seeds`), or None.
        budget: CG iterations allowed with a kept factorization of ``S``.
        rtol: CG's relative tolerance.
    """

    counts_as_zone_step = True

    def __init__(
        self,
        problem: ZoneProblem,
        system: PenalizedSystem,
        seed: np.ndarray | None,
        budget: int,
        rtol: float,
    ) -> None:
        self.problem, self.system = problem, system
        self.kappa = system.kappa
        self.budget, self.rtol = budget, rtol
        self.z, self.r, self.d = problem.vector(), problem.vector(), problem.vector()
        self.g = problem.start(system.zeta, system.f, self.kappa, self.z, self.r)
        touching = system.comm.allreduce(bool((self.g < 0).any()), op=MPI.LOR)
        self.seed = None if seed is None or touching or not seed.any() else seed

    def residual_norm(self) -> float:
        """``‖∇j(ζ_Z)‖``."""
        return self.problem.norm(self.r)

    def floor(self, load_norm: float) -> float:
        """:meth:`PenalizedSystem.floor` for the zone's problem: its active points, the
        rounding of ``K_S ζ_Z`` at the current iterate (:meth:`ZoneProblem.rounding`) and
        that of ``Kζ`` at the last whole iterate (``f̃`` and ``K_S`` are made of its
        products). The first term matters from ``ζ = 0``, where the second vanishes."""
        scale = self.problem.gap_scale(self.z)
        S = self.z.duplicate()
        S.set(0.0)
        self.problem.add_penalty(np.where(self.g < 0, scale, 0.0), self.kappa, S)
        norm = S.norm()
        S.destroy()
        return (
            floor_of(self.system.floor_factor, load_norm, norm)
            + self.problem.rounding(self.z)
            + self.system.elastic_rounding()
        )

    def direction(self, floor: float) -> int:
        """``d ← S⁻¹(−∇j)``; the first step of a seeded solve goes to the minimizer of the
        model whose active points are the seed's instead, if that descends. Returns the CG
        iterations (at least 1)."""
        problem, r, d = self.problem, self.r, self.d
        cg = -1
        if self.seed is not None:
            cg = self._seed_step(self.seed)
            self.seed = None
            if not r.dot(d) < -floor * problem.norm(d):
                cg = -1  # no descent: the usual Newton step instead
        if cg < 0:
            r.scale(-1.0)
            cg = problem.solve(self.g, self.kappa, r, d, self.budget, self.rtol)
            r.scale(-1.0)
        return max(cg, 1)

    def _seed_step(self, seed: np.ndarray) -> int:
        """``d ← −S_A⁻¹ ∇q_A``: the step to the minimizer of the zone's energy with the
        penalty on the points ``A = seed``, from an iterate where no point has ``g < 0``
        (``∇q_A = r + (1/κ) M_Pᵀ (g on A)``). Returns the CG iterations (0: factorized)."""
        rA = self.r.copy()
        self.problem.add_penalty(np.where(seed, self.g, 0.0), self.kappa, rA)
        rA.scale(-1.0)
        active = np.where(seed, -1.0, 1.0)  # S with the seed's points active
        cg = self.problem.solve(active, self.kappa, rA, self.d, self.budget, self.rtol)
        rA.destroy()
        return cg

    def slope(self) -> float:
        """``∇j·d``."""
        return self.r.dot(self.d)

    def small_step(self, stol: float) -> bool:
        """Whether ``‖d‖_∞ ≤ stol ‖ζ_Z‖_∞``."""
        inf = PETSc.NormType.NORM_INFINITY
        return self.problem.norm(self.d, inf) <= stol * self.problem.norm(self.z, inf)

    def direction_norm(self) -> float:
        """``‖d‖``."""
        return self.problem.norm(self.d)

    def line_search(self, slope0: float, noise: float) -> tuple[float, int]:
        """The exact step of ``j`` along ``d`` (the same on every rank)."""
        problem = self.problem
        problem.MP.mult(self.d, problem.wP)
        Md = problem.wP.array_r.copy()
        Kd = self.d.duplicate()
        problem.cond.Ks.mult(self.d, Kd)
        curvature = Kd.dot(self.d)
        Kd.destroy()
        step = exact_step(
            self.g, Md, Md / problem.DP, curvature, slope0, noise, self.kappa, lambda x: x
        )
        return self.system.comm.bcast(step, root=0)

    def move(self, t: float, small: bool) -> None:
        """``ζ_Z ← ζ_Z + t d`` and ``∇j`` there."""
        self.z.axpy(t, self.d)
        self.g = self.problem.residual(self.z, self.system.f, self.kappa, self.r)

    def complete(self) -> float:
        """``ζ ← (ζ_Z, K_II⁻¹ (f_I − K_IZ ζ_Z))`` and ``R(ζ)`` of the whole problem; returns
        ``‖R(ζ)‖``."""
        system = self.system
        self.problem.cond.extend(self.z, system.zeta, system.f)
        system.problem.zeta.x.scatter_forward()
        system.residual()
        for vec in (self.z, self.r, self.d):
            vec.destroy()
        return system.residual_norm()
