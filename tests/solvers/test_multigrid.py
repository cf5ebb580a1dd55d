"""Geometric multigrid on the mesh hierarchy (solver.linear_solver = "multigrid")."""

from __future__ import annotations

import ctypes
import dataclasses
from pathlib import Path

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
from conftest import disk, ladder
from conftest import make_paper_shell as paper_shell

from shellobstacle.api import make_mesh, solve_problem
from shellobstacle.config.loader import load_config
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.hierarchy import coarser_meshes, prolongation
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.messages import ConfigError
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.norms import l2_norm
from shellobstacle.solvers import libpetsc
from shellobstacle.solvers.linear import multigrid
from shellobstacle.solvers.linear.multigrid import MultigridStrategy
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonOptions, NewtonSolver

KOITER = Path(__file__).parents[2] / "examples" / "cylinder_koiter.toml"


def direct_and_multigrid(
    mesh: dolfinx.mesh.Mesh, kappas: list[float] | None = None
) -> tuple[PenalizedProblem, PenalizedProblem, NewtonSolver, list]:
    """The paper's problem on ``mesh`` continued along ``kappas`` (default :func:`ladder`) by
    the direct path and by multigrid: both problems, multigrid's solver and its steps."""
    kappas = ladder(mesh) if kappas is None else kappas
    direct = PenalizedProblem(paper_shell(), mesh)
    continuation(direct, NewtonSolver(direct), kappas)
    problem = PenalizedProblem(paper_shell(), mesh)
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="multigrid"))
    return direct, problem, solver, continuation(problem, solver, kappas)


@pytest.mark.mpi
def test_the_prolongation_interpolates_the_coarse_space_exactly() -> None:
    """``P u_c`` is the coarse function at the fine nodes: exact for functions the coarse P1
    space holds (affine ones), each component on its own, on every rank."""
    fine = disk(2)
    levels = coarser_meshes(fine)
    assert len(levels) == 2
    spaces = [dolfinx.fem.functionspace(m, ("Lagrange", 1, (3,))) for m in (levels[-1], fine)]
    u_c, u_f = (dolfinx.fem.Function(V) for V in spaces)
    for u in (u_c, u_f):
        u.interpolate(lambda x: np.stack([x[0] + 2 * x[1], 1 + 0 * x[0], 3 * x[0] - x[1]]))
    P = prolongation(*spaces)
    v = P.createVecLeft()
    P.mult(u_c.x.petsc_vec, v)
    owned = u_f.x.petsc_vec.getLocalSize()
    error = MPI.COMM_WORLD.allreduce(np.max(np.abs(v.array - u_f.x.array[:owned])), op=MPI.MAX)
    assert error < 1e-12


@pytest.mark.mpi
def test_multigrid_gives_the_direct_solution() -> None:
    """The continuation to κ = h^1.5 by CG with the V-cycle on the three mesh levels ends at
    the direct path's ζ and contact area to the solver's tolerance (serially and on 2 ranks)."""
    direct, multigrid, solver, steps = direct_and_multigrid(disk(2))
    assert isinstance(solver.linear, MultigridStrategy) and solver.linear.levels == 3
    assert all(s.newton.converged for s in steps)
    assert l2_norm(direct.zeta - multigrid.zeta) <= 1e-8 * l2_norm(direct.zeta)
    areas = [Postprocessor(p).contact()["contact_area"] for p in (direct, multigrid)]
    assert areas[0] > 0 and abs(areas[1] - areas[0]) <= 1e-10 * areas[0]


@pytest.mark.mpi
def test_multigrid_gives_the_direct_solution_of_koiters_model() -> None:
    """Koiter's model (P2, the hybrid bending form's condensed stiffness, facet terms across
    ranks): the continuation by CG with multigrid on the ghosted mesh's two levels (geometric
    on 2 ranks too: the ghosted refinement keeps the children on their parent's rank) ends at
    the direct path's ζ and contact area, within one Newton step per κ."""
    cfg = load_config(KOITER, ["domain.h=0.05", "domain.refinements=1"])
    mesh = make_mesh(cfg.domain, ghosted=True)
    runs = []
    for linear_solver in ("direct", "multigrid"):
        options = dataclasses.replace(cfg.solver, linear_solver=linear_solver)
        result = solve_problem(cfg.shell, mesh, cfg.penalty, cfg.discretization, options=options)
        assert result.converged
        runs.append(result)
    direct, geometric = runs
    linear = geometric.extra["linear_solver"]
    assert linear == "multigrid"
    # within one Newton step per κ (inexact directions; the direct path's contact zone)
    pairs = zip(geometric.steps, direct.steps, strict=True)
    assert all(abs(g.iterations - d.iterations) <= 1 for g, d in pairs)
    zeta = [r.problem.zeta for r in runs]
    assert l2_norm(zeta[0] - zeta[1]) <= 1e-8 * l2_norm(zeta[0])
    areas = [Postprocessor(r.problem).contact()["contact_area"] for r in runs]
    assert areas[0] > 0 and abs(areas[1] - areas[0]) <= 1e-10 * areas[0]
    iterations = [n for s in geometric.steps for n in s.record.linear_iterations]
    assert 1 < max(iterations) <= 40, iterations  # GAMG on 2 ranks took 100-900


def test_koiters_cg_iterations_per_newton_step_stay_bounded_as_h_halves() -> None:
    """Koiter's fourth-order bending in W-cycles (its default): the mean CG iterations per
    Newton step over the continuation grow by at most 1.3× from 2 to 3 levels (measured 10.4
    to 12.3 at 9.6k and 38k dofs; V-cycles, ``pc_mg_cycle_type = v``, give 10.4 to 15.9)."""
    means = []
    for refinements in (1, 2):
        cfg = load_config(KOITER, ["domain.h=0.05", f"domain.refinements={refinements}"])
        mesh = make_mesh(cfg.domain, ghosted=True)
        options = dataclasses.replace(cfg.solver, linear_solver="multigrid")
        result = solve_problem(cfg.shell, mesh, cfg.penalty, cfg.discretization, options=options)
        assert result.converged
        means.append(np.mean([n for s in result.steps for n in s.record.linear_iterations]))
    assert means[1] <= 1.3 * means[0], means


def test_koiters_model_without_levels_is_refused() -> None:
    """Algebraic multigrid took 100-900 CG iterations per Newton step on Koiter's model: the
    strategy refuses a mesh without coarser levels and names the fix."""
    cfg = load_config(KOITER, ["domain.h=0.1"])
    mesh = make_mesh(cfg.domain, ghosted=True)
    assert coarser_meshes(mesh) == []
    options = dataclasses.replace(cfg.solver, linear_solver="multigrid")
    with pytest.raises(ConfigError, match=r"domain\.refinements >= 1"):
        solve_problem(cfg.shell, mesh, cfg.penalty, cfg.discretization, options=options)


def test_without_a_hierarchy_it_is_algebraic_multigrid() -> None:
    """A mesh made outside ``create_mesh`` has no coarser meshes: GAMG on the whole system
    (one level of its own), with the direct path's answer."""
    mesh = dolfinx.mesh.create_rectangle(MPI.COMM_WORLD, [[-0.25, -0.25], [0.25, 0.25]], [16, 16])
    assert coarser_meshes(mesh) == []
    direct, algebraic, solver, _ = direct_and_multigrid(mesh, [1e-1, 1e-2, 1e-3])
    assert solver.linear.levels == 1
    assert solver.linear.ksp.getPC().getType() == "gamg"
    assert l2_norm(direct.zeta - algebraic.zeta) <= 1e-8 * l2_norm(direct.zeta)


def test_a_direction_that_keeps_the_active_set_is_finished() -> None:
    """A direction whose full step keeps the active set is continued by CG to Newton's
    threshold: every κ ends with such a step, the continuation takes fewer Newton steps than
    with Eisenstat–Walker's terms alone (none more at any κ), and ζ is the same."""
    mesh = disk(2)
    runs = []
    for finish in (True, False):
        problem = PenalizedProblem(paper_shell(), mesh)
        linear = MultigridStrategy(finish=finish)
        steps = continuation(problem, NewtonSolver(problem, linear=linear), ladder(mesh))
        assert all(s.newton.converged for s in steps)
        newton = [s.newton.iterations for s in steps]
        runs.append((newton, linear.finished, problem.zeta.x.array.copy()))
    (finished, count, zeta), (plain, none, zeta_plain) = runs
    assert none == 0 and count >= len(finished)
    assert sum(finished) < sum(plain) and all(a <= b for a, b in zip(finished, plain, strict=True))
    assert np.linalg.norm(zeta - zeta_plain) <= 1e-8 * np.linalg.norm(zeta_plain)


def test_cg_iterations_per_newton_step_stay_bounded_as_h_halves() -> None:
    """Each direction solved to a fixed 1e-8: the CG iterations per Newton step, averaged
    over the continuation to κ = h^1.5, grow by at most 1.5× from 2 to 4 mesh levels (h
    halved twice). A V-cycle with Galerkin coarse operators contracts the error by a factor
    independent of h; a one-level preconditioner would need about 2× more CG iterations per
    halving (the condition number grows like h⁻²)."""
    means = []
    for refinements in (1, 2, 3):
        mesh = disk(refinements)
        problem = PenalizedProblem(paper_shell(), mesh)
        linear = MultigridStrategy(1e-8, forcing="fixed")
        solver = NewtonSolver(problem, linear=linear)
        assert solver.linear is linear and solver.linear_solver == "MultigridStrategy"
        steps = continuation(problem, solver, ladder(mesh))
        assert linear.levels == refinements + 1
        iterations = [n for s in steps for n in s.newton.linear_iterations]
        means.append(float(np.mean(iterations)))
    assert max(means) <= 1.5 * min(means), means


def test_cg_iterations_per_newton_step_stay_bounded_as_the_penalty_stiffens() -> None:
    """Each direction solved to a fixed 1e-8 on three mesh levels, κ from 100 ε down to
    ε/1000 (the penalty's weight ε/κ over five decades; the paper's κ = h^1.5 is ε/κ = 1.4 to
    31): the CG iterations per Newton step, averaged over each κ, vary by at most 1.25×.
    The coarser operators carry the penalty part ``Pᵀ H P`` of every Jacobian, so the
    V-cycle corrects the stiff active points on every level; with ``Pᵀ K P`` alone they grow
    from 22 to 75 per step over the same κ. (At ε/κ = 10⁴ this mesh takes 1.5× more, 15.4
    per step: its coarsest level, gmsh's mesh at h = 0.1, does not resolve the contact zone;
    the paper's meshes from 82k dofs on show no rise: benchmarks/multigrid_robustness.py,
    docs/perf/multigrid.md.)"""
    mesh = disk(2)
    eps = paper_shell().material.epsilon
    kappas = [eps / ratio for ratio in (1e-2, 1.0, 1e2, 1e3)]
    problem = PenalizedProblem(paper_shell(), mesh, kappa=kappas[0])
    linear = MultigridStrategy(1e-8, forcing="fixed", finish=False)
    steps = continuation(problem, NewtonSolver(problem, linear=linear), kappas)
    assert linear.levels == 3 and all(s.newton.converged for s in steps)
    means = [float(np.mean(s.newton.linear_iterations)) for s in steps]
    assert max(means) <= 1.25 * min(means), means


def test_the_levels_are_set_up_once_per_kappa() -> None:
    """The V-cycle's levels (the coarser operators, the coarse factorization, Chebyshev's
    bounds) are set up at each κ's first Newton step; over its other steps Chebyshev's bounds
    are kept, and PETSc's own eigenvalue estimator, which would run at every step, is off on
    every smoothed level; the coarse level is factorized by MUMPS' Cholesky."""
    mesh = disk(2)
    kappas = ladder(mesh)
    problem = PenalizedProblem(paper_shell(), mesh)
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="multigrid"))
    assert solver.linear_solver == "multigrid"
    steps = continuation(problem, solver, kappas)
    linear = solver.linear
    directions = sum(len(s.newton.linear_iterations) for s in steps)
    assert directions > 2 * len(kappas)
    assert linear.multigrid_builds == len(kappas)
    assert linear.estimates == len(kappas) * (linear.levels - 1)
    assert 0 < linear.coarse_updates <= directions - len(kappas)  # where the active set moved
    coarse = linear.ksp.getPC().getMGCoarseSolve().getPC()  # (PCMG's default: PETSc's LU)
    assert (coarse.getType(), coarse.getFactorSolverType()) == ("cholesky", "mumps")
    estimator_of = libpetsc.function("KSPChebyshevEstEigGetKSP")
    for level in range(1, linear.levels):
        estimator = ctypes.c_void_p()
        smoother = linear.ksp.getPC().getMGSmoother(level)
        assert smoother.getType() == "chebyshev"
        assert estimator_of(smoother.handle, ctypes.byref(estimator)) == 0
        assert estimator.value is None


@pytest.mark.mpi
@pytest.mark.parametrize("share", [multigrid.COARSE_UPDATE_SHARE, 0.05])
def test_the_coarser_operators_follow_the_jacobian(share: float, monkeypatch) -> None:
    """At every direction, each coarser level's operator is ``Pᵀ J_c P`` (to round-off) with
    ``J_c = K + H`` at the active points it was made for, and those differ from the current
    Jacobian's in at most ``share`` of them, also at the steps of a κ after its first, where
    the active points moved (``share = 0``, the default: the current Jacobian's own); the
    answer is the direct path's."""
    from shellobstacle.solvers.linear import active_changes
    from shellobstacle.solvers.quadrature_penalty import penalty_hessian

    monkeypatch.setattr(multigrid, "COARSE_UPDATE_SHARE", share)
    gaps: list[float] = []
    shares: list[float] = []
    solve_once = MultigridStrategy._solve_once

    def checked(self: MultigridStrategy, b) -> None:
        system, then = self.system, self._coarse_active
        comm = system.comm
        shares.append(
            active_changes(comm, then, system.held_active)
            / max(1, comm.allreduce(int(np.count_nonzero(then))))
        )
        pen = system.penalty
        galerkin = system.K.copy()
        if comm.allreduce(int(np.count_nonzero(then))):
            H = penalty_hessian(pen.M, pen.D, np.flatnonzero(then), system.kappa)
            galerkin.axpy(1.0, H)
        for level in reversed(range(self.levels - 1)):
            galerkin = galerkin.ptap(self._P[level])
            difference = galerkin.copy()
            difference.axpy(-1.0, self._A[level])
            gaps.append(difference.norm() / galerkin.norm())
        solve_once(self, b)

    monkeypatch.setattr(MultigridStrategy, "_solve_once", checked)
    direct, problem, solver, steps = direct_and_multigrid(disk(2))
    assert all(s.newton.converged for s in steps)
    assert len(gaps) > 2 * len(steps) and max(gaps) <= 1e-12, max(gaps)
    assert max(shares) <= share and solver.linear.coarse_updates > 0
    assert l2_norm(direct.zeta - problem.zeta) <= 1e-8 * l2_norm(direct.zeta)


def test_a_stagnating_cg_with_kept_levels_sets_them_up_again(monkeypatch) -> None:
    """A direction whose CG with the kept levels needs more than the cap (here one
    iteration) is solved again with the levels set up for its Jacobian; the answer is the
    direct path's."""
    monkeypatch.setattr(multigrid, "KEPT_MIN_ITERATIONS", 1)
    monkeypatch.setattr(multigrid, "KEPT_ITERATION_FACTOR", 0)
    direct, problem, solver, steps = direct_and_multigrid(disk(1))
    assert all(s.newton.converged for s in steps)
    assert solver.linear.multigrid_builds > len(steps) + 2
    assert l2_norm(direct.zeta - problem.zeta) <= 1e-8 * l2_norm(direct.zeta)


def test_without_petscs_setter_petsc_estimates_the_bounds(monkeypatch) -> None:
    """A PETSc without ``KSPChebyshevSetEigenvalues``: the smoothers keep PETSc's own
    estimates (none of the strategy's) and the answer is the direct path's."""
    lookup = libpetsc._lookup

    def failing(name: str):
        if name == "KSPChebyshevSetEigenvalues":
            raise AttributeError(f"undefined symbol: {name}")
        return lookup(name)

    monkeypatch.setattr(libpetsc, "_lookup", failing)
    direct, problem, solver, _ = direct_and_multigrid(disk(1))
    assert solver.linear.levels == 2 and solver.linear.estimates == 0
    assert l2_norm(direct.zeta - problem.zeta) <= 1e-8 * l2_norm(direct.zeta)


@pytest.mark.mpi
@pytest.mark.parametrize("transverse", ["clamped", "free"])
def test_the_transfers_vanish_at_the_finer_levels_dirichlet_dofs(transverse: str) -> None:
    """On gmsh's disk refined twice, the new boundary nodes moved onto the circle: each
    transfer's rows at its finer level's Dirichlet dofs are zero (ζ_3's too only when
    clamped), its other rows interpolate (their weights sum to 1), and the coarse operator
    ``Pᵀ K P`` holds no part of ``K``'s unit Dirichlet diagonal: its ζ_3 diagonal off the
    coarse boundary stays within 10× of its median (with the boundary rows kept, the moved
    nodes' extrapolation weights put about 1,500× the median next to the boundary)."""
    from shellobstacle.spec import Discretization

    mesh = create_mesh(DomainSpec(kind="disk", radius=0.5, h=0.03, gmsh_max_vertices=150))
    problem = PenalizedProblem(paper_shell(), mesh, Discretization(transverse=transverse))
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="multigrid"))
    linear = solver.linear
    assert linear.levels == 3
    meshes = [*coarser_meshes(mesh), mesh]
    V = problem.V
    for P, fine in zip(linear._P, meshes[1:], strict=True):
        Vf = V if fine is mesh else dolfinx.fem.functionspace(fine, V.ufl_element())
        fixed = problem.dirichlet_rows(Vf)
        assert fixed.size and set(fixed % 3) == set(problem.dirichlet_components)
        sums = P.getRowSum().array_r
        np.testing.assert_array_equal(sums[fixed], 0.0)
        free = np.setdiff1d(np.arange(sums.size), fixed)
        np.testing.assert_allclose(sums[free], 1.0, rtol=0, atol=1e-12)
    K = problem.stiffness()
    K_coarse = K.ptap(linear._P[-1])
    Vc = dolfinx.fem.functionspace(meshes[-2], V.ufl_element())
    interior = np.setdiff1d(np.arange(0, K_coarse.getLocalSize()[0], 3),
                            problem.dirichlet_rows(Vc))  # fmt: skip
    zeta3 = K_coarse.getDiagonal().array_r[interior + 2]
    gathered = np.concatenate(MPI.COMM_WORLD.allgather(zeta3))
    assert 0 < gathered.max() <= 10 * np.median(gathered)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial")
@pytest.mark.parametrize("refinements", [0, 1])
def test_multigrid_without_levels_says_that_it_runs_gamg(capsys, tmp_path, refinements: int):
    """``--set solver.linear_solver=multigrid`` on a mesh without refinements runs algebraic
    multigrid: a warning on stderr and the summary's ``linear_solver_used`` say so, with the
    fix; with the mesh's levels, neither."""
    import json

    from cli_helpers import run

    small = Path(__file__).parents[2] / "examples" / "small.toml"
    sets = ["solver.linear_solver=multigrid", "domain.h=0.1", f"domain.refinements={refinements}"]
    sets += ["output.figures=false", "output.paraview=false"]
    out = tmp_path / "run"
    code, _, err = run(capsys, "solve", str(small), "-o", str(out), *(f"--set={s}" for s in sets))
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["linear_solver"] == "multigrid"
    said = [line for line in err.splitlines() if "algebraic multigrid (GAMG)" in line]
    if refinements:
        assert not said and "linear_solver_used" not in summary, err
    else:
        assert len(said) == 1 and "warning:" in said[0] and "domain.refinements" in said[0], err
        assert summary["linear_solver_used"] == "gamg"
        assert "domain.refinements >= 1" in summary["linear_solver_reason"]
