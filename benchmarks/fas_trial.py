"""FAS (nonlinear full approximation scheme multigrid) for the penalized membrane problem: a
prototype outside the package, measured against Newton with CG and a V-cycle.

The levels are those of ``solver.linear_solver = "multigrid"``: gmsh's mesh and its uniform
refinements (:func:`~shellobstacle.mesh.hierarchy.coarser_meshes`), with the same transfers
(:func:`~shellobstacle.mesh.hierarchy.prolongation`). On every level a
:class:`~shellobstacle.models.problem.PenalizedProblem` at the **same** κ and its
:class:`~shellobstacle.solvers.newton.system.PenalizedSystem` give the nonlinear operator
``R_l(ζ) = K_l ζ − f_l + (1/κ) M_lᵀ min(g_l, 0)`` (the level's own Gauss points).

One FAS V-cycle on level ``l`` (coarsest ``0``):

- ``pre`` smoothing steps: the Jacobian ``J_l = K_l + P_A`` at the iterate, ``δ`` from
  ``cheb`` Chebyshev iterations preconditioned by its diagonal (interval ``[0.1, 1.1] λ_max``,
  ``λ_max(D⁻¹J)`` estimated by the package's Lanczos at the first Jacobian of each κ), then
  the exact line search on the level's energy (every step decreases it);
- the coarse correction: ``ζ_c⁰`` the injection of ``ζ_l`` (coarse nodes are fine nodes),
  the coarse right-hand side ``f_c ← K_c ζ_c⁰ + pen_c(ζ_c⁰) − Pᵀ r_l`` (the τ-correction:
  the coarse problem is ``R_c(ζ_c) = R_c(ζ_c⁰) − Pᵀ r_l``, its Dirichlet rows 0), one cycle on
  it (level 0: Newton with MUMPS' Cholesky until its residual fell by ``coarse_rtol``), then
  ``ζ_l ← ζ_l + t P (ζ_c − ζ_c⁰)`` with ``t`` from the exact line search on level ``l``;
- ``post`` smoothing steps.

Two drivers:

- ``continuation``: the κ ladder of the package (``h^0.5, h, h^1.5``), each κ by V-cycles on
  the finest level from the previous κ's solution until ``‖R‖ ≤ 1e-10 ‖f‖`` or the round-off
  floor (the package's rule);
- ``fmg``: full multigrid at the final κ only: the coarsest level solved (Newton, direct)
  from ``ζ = 0``, interpolated, ``fmg_cycles`` V-cycles on each finer level, then V-cycles on
  the finest level until the same rule.

The coarse problem (the variants behind docs/perf/multigrid.md's "Tried, not kept: FAS"):

- default: textbook FAS, the level's own stiffness and Gauss points at the injected state;
- ``--coarse-points fine``: the coarser levels' penalty at the finest level's points
  (``M ← M_L P``); ``--galerkin-k``: their stiffness ``Pᵀ K_L P``; ``--zero-bc-rows``: the
  transfers' rows at the fine Dirichlet dofs zeroed (a fine boundary node moved onto the
  circle is extrapolated from interior coarse dofs, and ``Pᵀ K P`` then picks up ``w²`` times
  ``K``'s Dirichlet row, 1, against ζ_3's diagonal of about 1e-8);
- ``--coarse-state subspace`` (with ``--coarse-points fine``): the coarse gap is the finer
  level's gap plus ``B P (ζ_c − ζ_c⁰)``, not the injected state's: with ``--galerkin-k`` the
  coarse problem is the fine energy on the coarse subspace (a nonlinear subspace correction,
  not FAS); ``--band b``: only the finer level's points with ``g < b · max|g0|`` enter it;
- ``--truncate b``: the correction zeroed on the cells with ``g < b · max|g0|``;
- ``--gamma 2``: W-cycles; ``--levels n``: the finest ``n`` levels only; ``--coarse-reuse``:
  level 0 by CG preconditioned by the κ's last factorization.

Then the package's own solves on the same mesh (``linear_solver = "multigrid"`` and
``"direct"``; ``--no-fas``: these only) and the differences: contact area,
``‖ζ − ζ_pkg‖ / ‖ζ_pkg‖``. One JSON line per run on stdout (counts, CPU seconds by
``time.process_time``, and ``restriction_gap``: the fine solution's gap against the injected
state's), residual histories with ``--verbose``. The records
(docs/perf/multigrid/fas_trial.jsonl) came from, e.g.:

    export PYTHONPATH=$PWD/src
    S="--pre 1 --post 1 --cheb 4"
    E="$S --coarse-points fine --galerkin-k --coarse-state subspace --zero-bc-rows --band 0.01"
    .venv/bin/python benchmarks/fas_trial.py --h 0.0058 $S --max-cycles 40 --package=
    .venv/bin/python benchmarks/fas_trial.py --h 0.0058 $E
    .venv/bin/python benchmarks/fas_trial.py --h 0.0029 $E
    .venv/bin/python benchmarks/fas_trial.py --h 0.0029 $E --gamma 2 --package=
    .venv/bin/python benchmarks/fas_trial.py --h 0.0029 $E --driver fmg --package=
    .venv/bin/python benchmarks/fas_trial.py --h 0.0029 --no-fas --package multigrid

(The records with ``package_zero_bc_rows`` patched the package's multigrid to zero its
transfers' Dirichlet rows; the package has done so itself since.)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from collections import Counter

from mpi4py import MPI  # (MPI before dolfinx and PETSc)
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np

from shellobstacle.api import make_mesh, solve_problem
from shellobstacle.config.loader import load_config
from shellobstacle.mesh.hierarchy import coarser_meshes, prolongation
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.kappa import kappa_on_mesh
from shellobstacle.post.contact import Postprocessor
from shellobstacle.solvers import libpetsc
from shellobstacle.solvers.linear.multigrid import CHEBYSHEV_INTERVAL, largest_eigenvalue
from shellobstacle.solvers.newton.system import PenalizedSystem
from shellobstacle.solvers.quadrature_penalty import rows_of

PAPER = "examples/paper.toml"


class Level:
    """One mesh level: its penalized problem and system, the load, and its solvers."""

    def __init__(
        self,
        cfg,
        mesh: dolfinx.mesh.Mesh,
        kappa: float,
        coarsest: bool,
        cheb: int,
        reuse: bool,
        coarse_krylov_rtol: float = 1e-2,
    ):
        self.problem = PenalizedProblem(cfg.shell, mesh, cfg.discretization, kappa=kappa)
        self.system = PenalizedSystem(self.problem, incremental=True)
        self.load_norm = self.system.load()
        self.f_load = self.system.f.copy()
        self.bc_dofs = np.concatenate([bc.dof_indices()[0] for bc in self.problem.bcs])
        self.n = self.system.f.getLocalSize()
        self.coarsest = coarsest
        self.ksp = PETSc.KSP().create(MPI.COMM_SELF)
        self.reuse, self.factor_kappa = reuse, None
        if coarsest:
            self.ksp.setType("cg" if reuse else "preonly")
            self.ksp.setTolerances(rtol=coarse_krylov_rtol, max_it=30)
            self.ksp.setErrorIfNotConverged(False)
            pc = self.ksp.getPC()
            pc.setType("cholesky")
            pc.setFactorSolverType("mumps")
        else:
            self.ksp.setType("chebyshev")
            self.ksp.getPC().setType("jacobi")
            self.ksp.setNormType(PETSc.KSP.NormType.NONE)
            self.ksp.setTolerances(max_it=cheb)
            self.estimator = PETSc.KSP().create(MPI.COMM_SELF)
            self.estimator.setType("cg")
            self.estimator.getPC().setType("jacobi")
            self.estimator.setComputeEigenvalues(True)
            self.estimator.setTolerances(rtol=1e-12, atol=1e-300, max_it=10)
        self.operator_set = False
        self.gap_scale = float(np.max(np.abs(self.system.penalty.g0)))
        self.bounds_kappa: float | None = None
        self.counts: Counter = Counter()

    @property
    def zeta(self) -> np.ndarray:
        """The iterate's array (serial: the PETSc vector's)."""
        return self.problem.zeta.x.array

    def set_kappa(self, kappa: float) -> None:
        """A new κ on this level."""
        self.problem.set_kappa(kappa)

    def jacobian(self) -> PETSc.Mat:
        """The Jacobian at the iterate, given to the level's solver (Chebyshev's bounds
        estimated at the first Jacobian of each κ)."""
        A = self.system.jacobian()
        if not self.operator_set:
            A.setOption(PETSc.Mat.Option.SPD, True)
            self.ksp.setOperators(A)
            self.operator_set = True
        if not self.coarsest and self.bounds_kappa != self.system.kappa:
            emax = largest_eigenvalue(self.estimator, A)
            low, high = CHEBYSHEV_INTERVAL
            error = libpetsc.function("KSPChebyshevSetEigenvalues")(
                self.ksp.handle, high * emax, low * emax
            )
            assert not error
            self.bounds_kappa = self.system.kappa
            self.counts["estimates"] += 1
        return A

    def near_dofs(self, band: float) -> np.ndarray:
        """The dofs of the cells that hold a point with ``g < band · max|g0|`` (``band`` 0:
        the active points)."""
        s = self.system
        points = np.flatnonzero(s.g < band * self.gap_scale)
        if points.size == 0:
            return points
        MA = rows_of(s.penalty.M, points)
        _, indices, _ = MA.getValuesCSR()
        MA.destroy()
        self.counts["truncated"] += 1
        return np.unique(indices)

    def descend(self) -> float:
        """Move along ``system.dz`` by the exact line search (``system.R`` holds ``R(ζ)`` on
        entry and on exit); returns the step length (0: not a descent direction)."""
        s = self.system
        s.negate_residual()
        slope0 = s.slope()
        if not (slope0 < 0 and math.isfinite(slope0)):
            s.negate_residual()
            return 0.0
        t, _ = s.line_search(slope0, 0.0)
        s.move(t, False)
        return t

    def smooth(self) -> None:
        """One nonlinear smoothing step: Chebyshev–Jacobi on the linearization, line search."""
        s = self.system
        self.jacobian()
        s.negate_residual()
        self.ksp.solve(s.R, s.dz)
        s.negate_residual()
        self.counts["smooth"] += 1
        self.descend()

    def newton(self, rtol: float, atol: float, max_steps: int) -> int:
        """Newton with the direct solver until ``‖R‖ ≤ max(rtol ‖R_0‖, atol)``."""
        s = self.system
        r0 = s.residual_norm()
        steps = 0
        while steps < max_steps and s.residual_norm() > max(rtol * r0, atol):
            self.jacobian()
            s.negate_residual()
            self._direction()
            s.negate_residual()
            if self.descend() == 0.0:
                break
            steps += 1
        return steps

    def _direction(self) -> None:
        """``dz ← J⁻¹ R``: a factorization, or (``reuse``) CG preconditioned by the κ's last
        one, factorized anew when CG needs more than 30 iterations."""
        s, ksp = self.system, self.ksp
        fresh = not self.reuse or self.factor_kappa != s.kappa
        ksp.getPC().setReusePreconditioner(not fresh)
        ksp.solve(s.R, s.dz)
        if not fresh and ksp.getConvergedReason() < 0:
            ksp.getPC().setReusePreconditioner(False)
            ksp.solve(s.R, s.dz)
            fresh = True
        if fresh:
            self.counts["factorizations"] += 1
            self.factor_kappa = s.kappa
        self.counts["coarse_krylov"] += ksp.getIterationNumber()


def injection(P: PETSc.Mat) -> np.ndarray:
    """For each coarse dof the fine dof at the same node (the rows of ``P`` that are one
    entry 1)."""
    indptr, indices, values = P.getValuesCSR()
    single = np.flatnonzero(np.diff(indptr) == 1)
    ones = single[np.abs(values[indptr[single]] - 1.0) < 1e-10]
    inj = np.full(P.getSize()[1], -1, dtype=np.int64)
    inj[indices[indptr[ones]]] = ones
    assert (inj >= 0).all(), "a coarse node is no fine node"
    return inj


class FAS:
    """The levels, the transfers and the FAS V-cycle (module docstring)."""

    def __init__(self, cfg, mesh, kappa, args):
        meshes = [*coarser_meshes(mesh), mesh][-args.levels if args.levels else 0 :]
        self.levels = [
            Level(cfg, m, kappa, i == 0, args.cheb, args.coarse_reuse, args.coarse_krylov_rtol)
            for i, m in enumerate(meshes)
        ]
        self.P = [None] + [
            prolongation(c.problem.V, f.problem.V)
            for c, f in zip(self.levels[:-1], self.levels[1:], strict=True)
        ]
        self.inj = [None] + [injection(P) for P in self.P[1:]]
        if args.zero_bc_rows:  # no extrapolation onto the fine Dirichlet dofs
            for lev, P in zip(self.levels[1:], self.P[1:], strict=True):
                P.zeroRows(lev.bc_dofs.astype(PETSc.IntType), diag=0.0)
        if args.coarse_state == "subspace" and args.coarse_points != "fine":
            raise SystemExit("--coarse-state subspace needs --coarse-points fine")
        if args.coarse_points == "fine":
            self._fine_points()
        if args.galerkin_k:
            self._galerkin_stiffness()
        self.args = args
        self.cpu: Counter = Counter()
        self.coarse_steps: list[int] = []
        self.corrections: list[float] = []  # the finest level's correction step lengths

    def _to_finest(self) -> list[PETSc.Mat]:
        """For each coarser level the interpolation onto the finest (``P_L ⋯ P_{l+1}``)."""
        maps, Pc = [], None
        for l in range(len(self.levels) - 1, 0, -1):
            Pc = self.P[l] if Pc is None else Pc.matMult(self.P[l])
            maps.append(Pc)
        return maps[::-1]

    def _fine_points(self) -> None:
        """Every coarser level's penalty at the finest level's points: ``M ← M_L P``,
        ``D``, ``g0`` the finest level's (the fine penalty on the coarse subspace)."""
        fine = self.levels[-1].system.penalty
        for lev, Pc in zip(self.levels[:-1], self._to_finest(), strict=True):
            pen = lev.system.penalty
            pen.M = fine.M.matMult(Pc)
            pen.D, pen.g0 = fine.D, fine.g0
            pen._n = fine._n
            pen._work_q, pen._work_v = pen.M.createVecLeft(), pen.M.createVecRight()
            pen.Q = fine.Q
            lev.gap_scale = self.levels[-1].gap_scale

    def _galerkin_stiffness(self) -> None:
        """Every coarser level's stiffness ``Pᵀ K_L P`` (Dirichlet rows kept identity)."""
        K = self.levels[-1].system.K
        for lev, Pc in zip(self.levels[:-1], self._to_finest(), strict=True):
            Kc = K.ptap(Pc)
            Kc.zeroRowsColumns(lev.bc_dofs.astype(PETSc.IntType), 1.0)
            lev.system.K = Kc

    def _band_points(self, lev: Level, c: Level, P: PETSc.Mat) -> None:
        """The coarse penalty at the points of level ``lev``'s penalty where its gap is below
        ``band · max|g0|`` only (the subspace state; its other points left out)."""
        fine, pen = lev.system.penalty, c.system.penalty
        points = np.flatnonzero(lev.system.g < self.args.band * lev.gap_scale)
        sub = rows_of(fine.M, points)
        old = pen.M
        pen.M = sub.matMult(P)
        for obj in (sub, old, pen._work_q, pen._work_v):
            obj.destroy()
        pen.D = fine.D[points]
        pen._n = points.size
        pen._work_q, pen._work_v = pen.M.createVecLeft(), pen.M.createVecRight()
        pen.g0 = lev.system.g[points] - pen.apply_B(c.system.zeta)
        c.system._held = None  # new points: the Jacobian's penalty part summed anew
        c.counts["band_points"] = points.size

    def set_kappa(self, kappa: float) -> None:
        for lev in self.levels:
            lev.set_kappa(kappa)

    def cycle(self, l: int) -> None:
        """One FAS V-cycle on level ``l`` (its ``f`` may hold a τ-corrected right-hand side;
        ``system.R`` holds its residual on entry and exit)."""
        a, lev = self.args, self.levels[l]
        if l == 0:
            t = time.process_time()
            self.coarse_steps.append(lev.newton(a.coarse_rtol, 0.0, a.coarse_max))
            self.cpu["coarse"] += time.process_time() - t
            return
        t = time.process_time()
        for _ in range(a.pre):
            lev.smooth()
        self.cpu["smooth"] += time.process_time() - t
        t = time.process_time()
        c, P, inj = self.levels[l - 1], self.P[l], self.inj[l]
        zc0 = lev.zeta[inj].copy()
        c.zeta[:] = zc0
        if a.coarse_state == "subspace":  # the coarse gap: the fine one plus B P (ζ_c − ζ_c⁰)
            pen = c.system.penalty
            if a.band is None:
                pen.g0 = lev.system.g - pen.apply_B(c.system.zeta)
            else:
                self._band_points(lev, c, P)
        # the τ-corrected coarse right-hand side: K_c ζ_c⁰ + pen_c(ζ_c⁰) − Pᵀ r_l
        c.system.f.set(0.0)
        c.system.residual()  # R_c(ζ_c⁰) with f = 0
        rc = c.system.R.duplicate()
        P.multTranspose(lev.system.R, rc)
        f = c.system.f
        c.system.R.copy(f)
        f.axpy(-1.0, rc)
        rc.destroy()
        f.array[c.bc_dofs] = 0.0
        c.system.residual()  # R_c(ζ_c⁰) − τ-corrected: = Pᵀ r_l
        self.cpu["transfer"] += time.process_time() - t
        for _ in range(a.gamma if l > 1 else 1):  # V-cycle (1) or W-cycle (2)
            self.cycle(l - 1)
        t = time.process_time()
        ec = c.system.zeta.duplicate()
        ec.array[:] = c.zeta - zc0
        P.mult(ec, lev.system.dz)
        ec.destroy()
        lev.system.dz.array[lev.bc_dofs] = 0.0
        if a.truncate is not None:
            lev.system.dz.array[lev.near_dofs(a.truncate)] = 0.0
        step = lev.descend()
        if l == len(self.levels) - 1:
            self.corrections.append(step)
        self.cpu["correction"] += time.process_time() - t
        t = time.process_time()
        for _ in range(a.post):
            lev.smooth()
        self.cpu["smooth"] += time.process_time() - t

    def reset_rhs(self, l: int) -> None:
        """Level ``l``'s own load as its right-hand side, and its residual."""
        lev = self.levels[l]
        self.f_restore(lev)
        lev.system.residual()

    @staticmethod
    def f_restore(lev: Level) -> None:
        lev.f_load.copy(lev.system.f)

    def solve_finest(self, rtol: float, max_cycles: int, history: list[float]) -> int:
        """V-cycles on the finest level until the package's stopping rule; returns them."""
        fine = self.levels[-1]
        s = fine.system
        self.reset_rhs(len(self.levels) - 1)
        scale = fine.load_norm
        cycles = 0
        while True:
            r = s.residual_norm()
            history.append(r / scale)
            if r <= rtol * scale:
                return cycles
            t = time.process_time()
            floor = s.floor(fine.load_norm)
            self.cpu["floor"] += time.process_time() - t
            if r <= floor:
                return cycles
            if cycles >= max_cycles:
                return -cycles
            self.cycle(len(self.levels) - 1)
            cycles += 1


def solve_fas(cfg, mesh, args) -> dict:
    """The FAS solve (``args.driver``), its counts and CPU seconds."""
    ladder = kappa_on_mesh(cfg.penalty, mesh).ladder
    c0 = time.process_time()
    fas = FAS(cfg, mesh, ladder[0], args)
    setup = time.process_time() - c0
    c1 = time.process_time()
    per_kappa, histories, fmg = [], [], []
    if args.driver == "continuation":
        for kappa in ladder:
            fas.set_kappa(kappa)
            hist: list[float] = []
            per_kappa.append(fas.solve_finest(args.rtol, args.max_cycles, hist))
            histories.append(hist)
    else:
        kappa = ladder[-1]
        fas.set_kappa(kappa)
        lev0 = fas.levels[0]
        fas.reset_rhs(0)
        fmg.append(lev0.newton(1e-10, 0.0, 100))
        for l in range(1, len(fas.levels)):
            lev, c = fas.levels[l], fas.levels[l - 1]
            zc = c.system.zeta.duplicate()
            zc.array[:] = c.zeta
            fas.P[l].mult(zc, lev.system.zeta)
            zc.destroy()
            lev.zeta[lev.bc_dofs] = 0.0
            fas.reset_rhs(l)
            if l < len(fas.levels) - 1:
                for _ in range(args.fmg_cycles):
                    fas.cycle(l)
                fmg.append(args.fmg_cycles)
        hist = []
        per_kappa.append(fas.solve_finest(args.rtol, args.max_cycles, hist))
        histories.append(hist)
    cpu = time.process_time() - c1
    fine = fas.levels[-1]
    counts = {f"level{i}": dict(lev.counts) for i, lev in enumerate(fas.levels)}
    return {
        "fas": fas,
        "cycles_per_kappa": per_kappa,
        "cycles": sum(abs(c) for c in per_kappa),
        "converged": all(c >= 0 for c in per_kappa),
        "fmg_coarse": fmg,
        "final_relative_residual": histories[-1][-1],
        "rate_last_cycles": _rates(histories[-1]),
        "coarse_newton_steps": fas.coarse_steps,
        "correction_steps_t": [round(t, 3) for t in fas.corrections],
        "counts": counts,
        "setup_cpu_s": round(setup, 2),
        "solve_cpu_s": round(cpu, 2),
        "cpu_by_phase_s": {k: round(v, 2) for k, v in fas.cpu.items()},
        "zeta": fine.zeta.copy(),
        "problem": fine.problem,
        "histories": histories,
    }


def restriction_gap(fas: FAS) -> dict:
    """At the finest level's solution ``ζ``: its gap at the fine points against that of the
    interpolated injection ``P ζ_c⁰`` (what FAS's coarse problem linearizes at): the active
    points of each, and the size of the change against the deepest penetration."""
    fine, P, inj = fas.levels[-1], fas.P[-1], fas.inj[-1]
    pen = fine.system.penalty
    g = pen.gap(fine.system.zeta)
    zc = P.createVecRight()
    zc.array[:] = fine.zeta[inj]
    z = P.createVecLeft()
    P.mult(zc, z)
    z.array[fine.bc_dofs] = 0.0
    gi = pen.gap(z)
    active, active_i = g < 0, gi < 0
    return {
        "active_points": int(active.sum()),
        "active_points_restricted_state": int(active_i.sum()),
        "active_in_one_only": int((active ^ active_i).sum()),
        "max_penetration": float(-g.min()),
        "gap_change_at_active_max_p95_p50": [
            float(np.percentile(np.abs(gi - g)[active | active_i], q)) for q in (100, 95, 50)
        ],
        "max_zeta3_change": float(np.abs(z.array - fine.zeta)[2::3].max()),
        "max_abs_zeta3": float(np.abs(fine.zeta[2::3]).max()),
    }


def _rates(history: list[float]) -> list[float]:
    """Residual reduction factors per cycle, the last few."""
    r = np.asarray(history)
    return [round(float(x), 3) for x in (r[1:] / r[:-1])[-6:]]


def solve_package(cfg, mesh, linear_solver: str) -> dict:
    """The package's own continuation on ``mesh``."""
    options = dataclasses.replace(cfg.solver, linear_solver=linear_solver)
    c0 = time.process_time()
    result = solve_problem(
        cfg.shell, mesh, cfg.penalty, cfg.discretization, options=options, force=True
    )
    cpu = time.process_time() - c0
    newton = [s.iterations for s in result.steps]
    krylov = [n for s in result.steps for n in s.record.linear_iterations]
    return {
        "newton_per_kappa": newton,
        "newton": sum(newton),
        "krylov_total": int(sum(krylov)),
        "cpu_s": round(cpu, 2),
        "solve_s_wall": round(result.timings.get("solve", float("nan")), 2),
        "zeta": result.problem.zeta.x.array.copy(),
        "problem": result.problem,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--h", type=float, default=0.0058, help="gmsh target size (domain.h)")
    ap.add_argument("--driver", choices=("continuation", "fmg"), default="continuation")
    ap.add_argument("--levels", type=int, default=None, help="the finest levels only (default all)")
    ap.add_argument("--pre", type=int, default=2, help="smoothing steps before the correction")
    ap.add_argument("--post", type=int, default=2, help="smoothing steps after it")
    ap.add_argument("--cheb", type=int, default=2, help="Chebyshev iterations per step")
    ap.add_argument("--gamma", type=int, default=1, help="cycle index: 1 V-cycle, 2 W-cycle")
    ap.add_argument("--coarse-rtol", type=float, default=1e-3)
    ap.add_argument("--coarse-max", type=int, default=20, help="Newton steps on level 0")
    ap.add_argument(
        "--coarse-reuse", action="store_true",
        help="level 0: CG preconditioned by the κ's last factorization (refactorized when CG "
        "needs more than 30 iterations) instead of a factorization per Newton step",
    )  # fmt: skip
    ap.add_argument("--coarse-krylov-rtol", type=float, default=1e-2, help="with --coarse-reuse")
    ap.add_argument("--fmg-cycles", type=int, default=1, help="V-cycles per coarser level")
    ap.add_argument(
        "--truncate", type=float, default=None,
        help="zero the coarse correction on the cells with g < this · max|g0| (0: active)",
    )  # fmt: skip
    ap.add_argument(
        "--coarse-points", choices=("own", "fine"), default="own",
        help="the coarser levels' penalty at their own Gauss points or at the finest level's",
    )  # fmt: skip
    ap.add_argument(
        "--coarse-state", choices=("restricted", "subspace"), default="restricted",
        help="the coarse penalty at the restricted state (FAS) or at the fine state plus the "
        "interpolated correction (with --coarse-points fine: the fine energy on the subspace)",
    )  # fmt: skip
    ap.add_argument(
        "--zero-bc-rows", action="store_true",
        help="P's rows at the fine Dirichlet dofs zeroed (they extrapolate interior coarse dofs)",
    )  # fmt: skip
    ap.add_argument(
        "--band", type=float, default=None,
        help="with --coarse-state subspace: the coarse penalty at the finer level's points "
        "with g < band · max|g0| only (default: all)",
    )  # fmt: skip
    ap.add_argument("--galerkin-k", action="store_true", help="coarse stiffness Pᵀ K P")
    ap.add_argument("--rtol", type=float, default=1e-10)
    ap.add_argument("--max-cycles", type=int, default=200)
    ap.add_argument("--package", default="multigrid,direct", help="package solves to compare")
    ap.add_argument("--fas", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--verbose", action="store_true", help="print the residual histories")
    args = ap.parse_args()
    cfg = load_config(PAPER, [f"domain.h={args.h}"])
    mesh = make_mesh(cfg.domain)
    line = {"h": args.h, "dofs": 3 * mesh.geometry.index_map().size_global}
    zeta = None
    if args.fas:
        out = solve_fas(cfg, mesh, args)
        zeta = out["zeta"]
        keys = ("driver", "pre", "post", "cheb", "coarse_rtol", "coarse_points", "coarse_state")
        line |= {
            "dofs": out["problem"].num_dofs,
            "levels": len(out["fas"].levels),
            **{k: getattr(args, k) for k in (*keys, "galerkin_k", "zero_bc_rows")},
            **{k: v for k, v in out.items() if k not in ("fas", "zeta", "problem", "histories")},
            "contact_area": Postprocessor(out["problem"]).contact()["contact_area"],
            "truncate": args.truncate,
            "band": args.band,
            "levels_used": args.levels,
            "coarse_reuse": args.coarse_reuse,
            "gamma": args.gamma,
        }
        if len(out["fas"].levels) > 1:
            line["restriction_gap"] = restriction_gap(out["fas"])
        if args.verbose:
            for hist in out["histories"]:
                print("# history", " ".join(f"{r:.1e}" for r in hist), flush=True)
    for name in filter(None, args.package.split(",")):
        pkg = solve_package(cfg, mesh, name)
        line[name] = {
            **{k: v for k, v in pkg.items() if k not in ("zeta", "problem")},
            "contact_area": Postprocessor(pkg["problem"]).contact()["contact_area"],
        }
        if zeta is not None:
            diff = np.linalg.norm(zeta - pkg["zeta"]) / np.linalg.norm(pkg["zeta"])
            line[name]["zeta_rel_diff_fas"] = float(diff)
    line["load"] = round(os.getloadavg()[0], 2)
    print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
