"""Newton's method: small κ, cold starts, failures, serial vs MPI (docs/model.md §6)."""

from __future__ import annotations

import itertools
import math

from mpi4py import MPI
from petsc4py import PETSc

import basix
import numpy as np
import pytest
from conftest import make_paper_shell as paper_shell
from conftest import square

from shellobstacle.api import solve_problem
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.norms import l2_norm
from shellobstacle.solvers.base import ConvergenceError
from shellobstacle.solvers.linear import iterative as iterative_module
from shellobstacle.solvers.linear.iterative import WARM_FORCING, IterativeStrategy
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonOptions, NewtonSolver
from shellobstacle.spec import Discretization, Obstacle, Shell


@pytest.mark.parametrize("quadrature", ["gauss", "vertex"])
def test_kappa_down_to_1e_12(quadrature: str) -> None:
    """Warm-started Newton converges for κ = 1e-1 … 1e-12; the penetration left is bounded."""
    problem = PenalizedProblem(
        paper_shell(), square(), Discretization(penalty_quadrature=quadrature)
    )
    solver = NewtonSolver(problem)
    kappas = [10.0**-k for k in range(1, 13)]
    steps = continuation(problem, solver, kappas)
    assert [s.newton.converged for s in steps] == [True] * len(kappas)
    assert all(s.newton.iterations <= 30 for s in steps)
    post = Postprocessor(problem)
    c = post.contact()
    assert c["num_contact_points"] > 0 and c["num_contact_nodes"] > 0
    # where the penalty acts: violation ~ κ·(load/ε), here ~1e-13
    assert c["max_violation"] < 1e-9
    if quadrature == "gauss":  # between its Gauss points the vertices may cross by O(h²)
        h = np.sqrt(2) * 0.5 / 24
        assert 0 < c["max_violation_nodal"] < h**2


def test_violation_proportional_to_kappa() -> None:
    """Nodal penalty: the largest violation max{g}^- scales like κ (Lemma 5.1 / the penalty)."""
    problem = PenalizedProblem(paper_shell(), square(), Discretization(penalty_quadrature="vertex"))
    solver = NewtonSolver(problem)
    post = Postprocessor(problem)
    violations = []
    for kappa in [1e-2, 1e-3, 1e-4, 1e-5]:
        continuation(problem, solver, [kappa])
        violations.append(post.contact()["max_violation"])
    ratios = np.array(violations[:-1]) / np.array(violations[1:])
    assert np.all(violations) and np.all((ratios > 8) & (ratios < 12.5)), ratios


def test_cold_start_small_kappa_with_continuation() -> None:
    """``solve`` with one small κ reaches it from ζ = 0 through its continuation ladder."""
    shell = paper_shell()
    mesh = square()
    result = solve_problem(shell, mesh, PenaltySpec(kappa=1e-10))
    assert result.converged
    assert result.steps[-1].kappa == 1e-10
    assert len(result.steps) > 1
    warm = PenalizedProblem(shell, mesh, kappa=1.0)
    continuation(warm, NewtonSolver(warm), [10.0**-k for k in range(0, 11)])
    diff = l2_norm(result.problem.zeta - warm.zeta)
    assert diff <= 1e-8 * l2_norm(warm.zeta)


def test_nonconvergence_is_reported_with_the_iterate() -> None:
    """A Newton that runs out of iterations raises ConvergenceError carrying its history."""
    problem = PenalizedProblem(paper_shell(), square(), kappa=1e-10)
    solver = NewtonSolver(problem, NewtonOptions(max_iterations=2))
    with pytest.raises(ConvergenceError, match="did not converge") as info:
        solver.solve()
    result = info.value.result
    assert not result.converged
    assert result.iterations == 2
    assert len(result.residual_norms) == 3
    # and solve_problem() turns it into a failed result, not a success
    failed = solve_problem(
        paper_shell(),
        square(),
        PenaltySpec(kappa=1e-10, continuation=False),
        options=NewtonOptions(max_iterations=2),
    )
    assert not failed.converged
    assert "did not converge" in (failed.error or "")


def test_no_load_gives_zero() -> None:
    """Zero load: ζ = 0 is the solution, found without a Newton step."""
    problem = PenalizedProblem(paper_shell("0"), square(n=8))
    r = NewtonSolver(problem).solve()
    assert r.converged and r.iterations == 0
    assert np.all(problem.zeta.x.array == 0.0)


def test_iterative_matches_direct() -> None:
    """CG + GAMG gives the direct solver's answer on a contact problem."""
    mesh = square(n=16)
    a = PenalizedProblem(paper_shell(), mesh)
    b = PenalizedProblem(paper_shell(), mesh)
    kappas = [1e-1, 1e-2, 1e-3, 1e-4]
    continuation(a, NewtonSolver(a), kappas)
    continuation(b, NewtonSolver(b, NewtonOptions(linear_solver="iterative")), kappas)
    assert l2_norm(a.zeta - b.zeta) <= 1e-8 * l2_norm(a.zeta)


def _builds_and_solution(kappas, drift: float, monkeypatch) -> tuple[int, np.ndarray, list]:
    """GAMG builds, the solution and the Newton results of an iterative continuation on the
    paper's shell over the square with ``MULTIGRID_DRIFT = drift``."""
    monkeypatch.setattr(iterative_module, "MULTIGRID_DRIFT", drift)
    problem = PenalizedProblem(paper_shell(), square(n=16))
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"))
    steps = continuation(problem, solver, kappas)
    return solver.linear.multigrid_builds, problem.zeta.x.array.copy(), steps


def test_gamg_is_kept_across_kappa_while_the_diagonal_holds(monkeypatch) -> None:
    """The hierarchy is built once while the Jacobian's ζ_α diagonal stays within the drift
    bound, and again whenever the diagonal moved with a bound of 0; the solutions agree to
    Newton's tolerance."""
    kappas = [1e-1, 1e-2, 1e-3]
    kept, z_kept, steps = _builds_and_solution(kappas, math.inf, monkeypatch)
    every, z_every, steps_every = _builds_and_solution(kappas, 0.0, monkeypatch)
    assert all(s.newton.converged for s in steps + steps_every)
    assert kept == 1
    # (a bound of 0 builds whenever the diagonal moved at all: not between two steps whose
    # active sets are the same)
    assert 1 < every <= sum(len(s.newton.linear_iterations) for s in steps_every)
    assert np.linalg.norm(z_every - z_kept) <= 1e-8 * np.linalg.norm(z_kept)


def test_a_drifting_diagonal_builds_gamg_again() -> None:
    """Past the drift bound the hierarchy is built again. With the plane tilted (q = (0.3, 0,
    0.954)), ``c_1 = a^1·q`` is about 0.3 where the shell touches, and from κ = 1e-3 on the
    penalty moves the ζ_α diagonal by more than 5 %: every build after the first happened at
    a drift above the bound, every kept solve below it, and the solution is the direct
    solver's."""
    base = paper_shell()
    q = (0.3, 0.0, math.sqrt(1.0 - 0.09))
    shell = Shell(base.surface, base.material, base.load, Obstacle(q))
    kappas = [1e-1, 1e-2, 1e-3, 1e-4]
    mesh = square(n=16)
    problem = PenalizedProblem(shell, mesh)
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"))
    linear = solver.linear
    drifts: list[tuple[float, int]] = []
    measure = linear._multigrid_drift

    def record(diagonal: np.ndarray) -> float:
        drift = measure(diagonal)
        drifts.append((drift, linear.multigrid_builds))
        return drift

    linear._multigrid_drift = record
    steps = continuation(problem, solver, kappas)
    assert all(s.newton.converged for s in steps)
    drifts.append((math.nan, linear.multigrid_builds))
    rebuilt = [d for (d, before), (_, after) in itertools.pairwise(drifts) if after > before]
    kept = [d for (d, before), (_, after) in itertools.pairwise(drifts) if after == before]
    assert linear.multigrid_builds == 1 + len(rebuilt) > 2
    assert min(rebuilt) > 0.05 and kept and max(kept) <= 0.05
    reference = PenalizedProblem(shell, mesh)
    continuation(reference, NewtonSolver(reference), kappas)
    assert l2_norm(reference.zeta - problem.zeta) <= 1e-8 * l2_norm(reference.zeta)


def test_a_failed_solve_with_the_kept_gamg_is_repeated_with_a_new_one() -> None:
    """A solve whose kept hierarchy fails (here: CG capped at one iteration for it) is solved
    again with a new hierarchy; the failed iterations count in the step's total."""
    mesh = square(n=16)
    problem = PenalizedProblem(paper_shell(), mesh)
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"))
    linear = solver.linear
    original = linear._solve_split
    failed: list[int] = []
    repeated: list[int] = []  # the iterations of the repeated solve

    def capped(b, build, diagonal) -> None:
        if build or failed:
            original(b, build, diagonal)
            if failed and not repeated:
                repeated.append(linear.ksp.getIterationNumber())
            return
        linear.ksp.setTolerances(max_it=1)
        original(b, build, diagonal)
        linear.ksp.setTolerances(max_it=2000)
        failed.append(linear.ksp.getConvergedReason())

    linear._solve_split = capped
    steps = continuation(problem, solver, [1e-1, 1e-2])
    assert all(s.newton.converged for s in steps)
    assert failed and failed[0] < 0
    assert linear.multigrid_builds == 2
    iterations = [n for s in steps for n in s.newton.linear_iterations]
    assert repeated[0] + 1 in iterations  # the failed solve's one iteration counted
    reference = PenalizedProblem(paper_shell(), mesh)
    continuation(reference, NewtonSolver(reference), [1e-1, 1e-2])
    assert l2_norm(reference.zeta - problem.zeta) <= 1e-8 * l2_norm(reference.zeta)


def test_the_split_keeps_its_blocks_between_builds() -> None:
    """After the first set-up the field split keeps its diagonal blocks instead of extracting
    them from each Jacobian: the ζ_α block (GAMG's finest level) is the Jacobian's at the last
    build, the ζ_3 block carries the current Jacobian's diagonal."""
    problem = PenalizedProblem(paper_shell(), square(n=16))
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"))
    linear = solver.linear
    seen: list[tuple] = []
    original = linear._solve_split

    def watched(b, build, diagonal) -> None:
        if linear._split is not None:
            before = linear._split[0].getOperators()[1]
        original(b, build, diagonal)
        ksp_alpha, ksp_3 = linear._split
        P_alpha, P_3 = ksp_alpha.getOperators()[1], ksp_3.getOperators()[1]
        is_alpha = linear.ksp.getPC().getFieldSplitSubIS("0")
        current = solver.system.A.createSubMatrix(is_alpha, is_alpha)
        current.axpy(-1.0, P_alpha)
        d_3 = P_3.getDiagonal()
        seen.append(
            (
                build,
                current.norm(PETSc.NormType.NORM_INFINITY),
                np.abs(d_3.array_r - diagonal[:, 2]).max(initial=0.0),
                len(seen) == 0 or before.handle == P_alpha.handle,
            )
        )
        current.destroy()
        d_3.destroy()

    linear._solve_split = watched
    steps = continuation(problem, solver, [1e-1, 1e-2, 1e-3])
    assert all(s.newton.converged for s in steps)
    assert len(seen) > 3 and all(same for *_, same in seen)  # one ζ_α block throughout
    assert all(d3 == 0.0 for _, _, d3, _ in seen)  # the current ζ_3 diagonal, exactly
    assert all(diff == 0.0 for build, diff, _, _ in seen if build)  # refreshed at a build
    assert any(diff > 0.0 for build, diff, _, _ in seen if not build)  # kept between builds


def test_a_kept_gamg_gets_a_bounded_number_of_iterations(monkeypatch) -> None:
    """A solve with a kept hierarchy may take at most ``KEPT_ITERATION_FACTOR`` times the
    most iterations since the build (here capped to one iteration): every kept solve that
    needs more is repeated with a new hierarchy, the solution is unchanged and the KSP's own
    iteration limit is left as it was."""
    monkeypatch.setattr(iterative_module, "KEPT_ITERATION_FACTOR", 0)
    monkeypatch.setattr(iterative_module, "KEPT_MIN_ITERATIONS", 1)
    mesh = square(n=16)
    kappas = [1e-1, 1e-2]
    problem = PenalizedProblem(paper_shell(), mesh)
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"))
    linear = solver.linear
    limits: list[int] = []
    original = linear._solve_split

    def watched(b, build, diagonal) -> None:
        original(b, build, diagonal)
        limits.append(linear.ksp.getTolerances()[3])

    linear._solve_split = watched
    steps = continuation(problem, solver, kappas)
    assert all(s.newton.converged for s in steps)
    directions = sum(len(s.newton.linear_iterations) for s in steps)
    assert linear.multigrid_builds > 2  # (a solve in one iteration keeps it)
    # (a finished direction is two solves, the second continuing the first)
    assert len(limits) == directions + linear.finished + linear.multigrid_builds - 1
    assert set(limits) == {2000}
    reference = PenalizedProblem(paper_shell(), mesh)
    continuation(reference, NewtonSolver(reference), kappas)
    assert l2_norm(reference.zeta - problem.zeta) <= 1e-8 * l2_norm(reference.zeta)


def test_inexact_newton_needs_fewer_cg_iterations_for_the_same_solution() -> None:
    """Eisenstat–Walker forcing: the solution of every κ as with CG solved to 1e-12 at each
    Newton step, for fewer CG iterations in all; every tolerance asked is in [1e-12, 0.1], the
    first of the cold start 0.1 and the first of every warm-started κ WARM_FORCING."""
    mesh = square(n=16)
    kappas = [1e-1, 1e-2, 1e-3, 1e-4]
    solutions, totals, etas = [], [], []
    for forcing in ("eisenstat-walker", "fixed"):
        problem = PenalizedProblem(paper_shell(), mesh)
        linear = IterativeStrategy(forcing=forcing, finish=False)
        solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"), linear)
        asked: list[float] = []
        firsts: list[float] = []  # the η of each solve's first step
        forcing_term = linear._forcing

        def record(norms, target, _asked=asked, _firsts=firsts, _forcing=forcing_term) -> float:
            _asked.append(_forcing(norms, target))
            if len(norms) == 1:
                _firsts.append(_asked[-1])
            return _asked[-1]

        linear._forcing = record
        steps = continuation(problem, solver, kappas)
        assert all(s.newton.converged for s in steps)
        if forcing == "eisenstat-walker":
            assert firsts == [0.1] + [WARM_FORCING] * (len(kappas) - 1)
        solutions.append(problem.zeta.x.array.copy())
        totals.append(sum(sum(s.newton.linear_iterations) for s in steps))
        etas.append(asked)
    (inexact, exact), (n_inexact, n_exact) = solutions, totals
    assert np.linalg.norm(inexact - exact) <= 1e-8 * np.linalg.norm(exact)
    assert n_inexact < n_exact
    assert etas[1] and all(eta == 1e-12 for eta in etas[1])
    assert max(etas[0]) <= 0.1 and min(etas[0]) >= 1e-12 and max(etas[0]) > 1e-12


def test_a_seeded_first_step_shortens_the_iterative_solvers_cold_start() -> None:
    """From ζ = 0 at the large first κ of a continuation, the iterative solver's first step
    goes to the minimizer of the model whose active points are where a coarse-grid step
    penetrates: fewer Newton steps at the first κ (7 against 9), the same solutions.

    (From a cold start at a small κ the seed can cost steps instead: 14 against 11 at
    κ = 1e-2 on this problem with n = 32; continuations start at κ = 1 or h^0.5.)"""
    mesh = square(n=64)
    kappas = [1e-1, 1e-2, 1e-3]
    runs = []
    for seed in (True, False):
        problem = PenalizedProblem(paper_shell(), mesh)
        options = NewtonOptions(linear_solver="iterative")
        solver = NewtonSolver(problem, options, IterativeStrategy(seed=seed))
        steps = continuation(problem, solver, kappas)
        runs.append(([s.newton.iterations for s in steps], problem.zeta.x.array.copy()))
    (seeded, z_seeded), (plain, z_plain) = runs
    assert seeded[0] < plain[0]
    assert np.linalg.norm(z_seeded - z_plain) <= 1e-8 * np.linalg.norm(z_plain)


def test_a_seeded_direction_that_does_not_descend_is_replaced_by_the_newton_step() -> None:
    """Forced: the seeded model's gradient reversed makes an ascent direction; the solver
    takes the usual Newton step instead and repeats the unseeded run (to CG's accuracy: GAMG
    keeps the aggregates of the first matrix it saw, here the seeded Jacobian)."""
    mesh = square(n=32)
    runs = []
    for seed in (True, False):
        problem = PenalizedProblem(paper_shell(), mesh)
        linear = IterativeStrategy(forcing="fixed", seed=seed)
        solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"), linear)
        seeded_gradient = linear.seeded_gradient

        def reversed_gradient(gaps, _gradient=seeded_gradient):
            b = _gradient(gaps)
            b.scale(-1.0)
            return b

        linear.seeded_gradient = reversed_gradient
        problem.kappa.value = 1e-1
        result = solver.solve()
        runs.append((result, problem.zeta.x.array.copy()))
    (seeded, z_seeded), (plain, z_plain) = runs
    assert seeded.iterations == plain.iterations
    assert seeded.step_lengths == pytest.approx(plain.step_lengths, rel=1e-8)
    assert seeded.linear_iterations[0] > plain.linear_iterations[0]  # the discarded solve
    assert np.linalg.norm(z_seeded - z_plain) <= 1e-10 * np.linalg.norm(z_plain)


def test_the_iterative_solvers_jacobian_is_updated_by_the_changed_points() -> None:
    """At one κ the iterative solver updates its Jacobian by the points that changed activity;
    the result is K + P_A of the last active set to round-off."""
    from petsc4py import PETSc

    from shellobstacle.solvers.quadrature_penalty import penalty_hessian

    problem = PenalizedProblem(paper_shell(), square(n=16))
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"))
    system = solver.system
    changed = []
    jacobian = system.jacobian

    def counting(g: np.ndarray | None = None) -> PETSc.Mat:
        held = system.held_active
        A = jacobian(g)
        if held is not None:
            changed.append(int(np.count_nonzero(held != system.held_active)))
        return A

    system.jacobian = counting
    problem.set_kappa(1e-3)
    result = solver.solve()
    assert result.converged and result.iterations >= 3
    assert len(changed) >= 2 and max(changed) > 0  # updates that changed something
    fresh = system.K.duplicate(copy=True)
    held = np.flatnonzero(system.held_active)
    P = penalty_hessian(system.penalty.M, system.penalty.D, held, system.kappa)
    fresh.axpy(1.0, P, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
    fresh.axpy(-1.0, system.A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
    assert fresh.norm() <= 1e-13 * system.A.norm()


def test_the_iterative_solver_finishes_a_direction_that_keeps_the_active_set() -> None:
    """The field split's CG, continued from a direction whose full step keeps the active set
    to Newton's threshold, the others solved to 0.1 (the first of a warm start to
    WARM_FORCING): fewer Newton steps than with Eisenstat–Walker's terms, none more at any κ,
    the same ζ."""
    mesh = square(n=16)
    runs = []
    for finish in (True, False):
        problem = PenalizedProblem(paper_shell(), mesh)
        linear = IterativeStrategy(finish=finish)
        solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"), linear)
        asked: list[float] = []
        forcing_term = linear._forcing

        def record(norms, target, _asked=asked, _forcing=forcing_term) -> float:
            _asked.append(_forcing(norms, target))
            return _asked[-1]

        linear._forcing = record
        steps = continuation(problem, solver, [1e-1, 1e-2, 1e-3])
        if finish:
            assert set(asked) == {0.1, WARM_FORCING}
        assert all(s.newton.converged for s in steps)
        runs.append(([s.newton.iterations for s in steps], linear.finished, problem.zeta.x.array))
    (finished, count, zeta), (plain, none, zeta_plain) = runs
    assert count > 0 and none == 0
    assert sum(finished) < sum(plain) and all(a <= b for a, b in zip(finished, plain, strict=True))
    assert np.linalg.norm(zeta - zeta_plain) <= 1e-8 * np.linalg.norm(zeta_plain)


def test_an_unknown_forcing_is_refused() -> None:
    with pytest.raises(ValueError, match="forcing"):
        IterativeStrategy(forcing="exact")


@pytest.mark.mpi
def test_gauss_point_active_set_thins_out_once_kappa_passes_h_squared() -> None:
    """With Gauss penalty points (6 per cell) a contact cell has all its points active while
    the penetration (≈ κλ) exceeds the gap's curvature within a cell (O(h²), which P1
    displacements cannot remove), and at most 3 once κ ≪ h²: the active set moves by a
    structural amount between κ = h^1.5 and h^4, whatever the solver (docs/performance.md,
    "Why Gauss points need more Newton steps at κ ≈ h²")."""
    mesh = square(n=32)
    h = mesh_size(mesh)
    problem = PenalizedProblem(paper_shell(), mesh, Discretization(penalty_quadrature="gauss"))
    solver = NewtonSolver(problem)
    comm = mesh.comm

    def contact_cells() -> tuple[np.ndarray, float, float]:
        g = solver.penalty.by_cell(solver.penalty_gaps)
        assert g.shape[1] == 6
        active = solver.penalty.by_cell(solver.active_points)
        counts = comm.allreduce(np.bincount(active.sum(axis=1), minlength=7), op=MPI.SUM)
        g = g[(g < 0).any(axis=1)]
        affine = np.column_stack([np.ones(6), basix.make_quadrature(basix.CellType.triangle, 4)[0]])
        curved = np.abs(g - g @ np.linalg.pinv(affine).T @ affine.T).max(axis=1, initial=0.0)
        return (
            counts,
            comm.allreduce(-g.min(initial=0.0), op=MPI.MAX),
            comm.allreduce(curved.max(initial=0.0), op=MPI.MAX),
        )

    continuation(problem, solver, [h**0.5, h])
    counts, penetration, curvature = contact_cells()
    assert counts[1:6].sum() == 0 and counts[6] > 20  # every contact cell fully active
    assert penetration > 10 * curvature
    continuation(problem, solver, [h**1.5, h**2, h**3, h**4])
    counts, penetration, curvature = contact_cells()
    assert counts[4:].sum() == 0 and counts[1:4].sum() > 20  # at most 3 points per cell
    assert penetration < curvature / 10


@pytest.mark.mpi
def test_iterative_serial_and_parallel_agree() -> None:
    """The iterative solver on the distributed mesh gives the serial solution (to CG's
    accuracy: the smoothers and the aggregates depend on the partition)."""
    kappas = [1e-1, 1e-2, 1e-3, 1e-4]
    norms, areas = [], []
    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):
        problem = PenalizedProblem(paper_shell(), square(comm, n=20))
        solver = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"))
        continuation(problem, solver, kappas)
        norms.append(l2_norm(problem.zeta))
        areas.append(Postprocessor(problem).contact()["contact_area"])
    assert norms[0] == pytest.approx(norms[1], rel=1e-8)
    assert areas[0] == pytest.approx(areas[1], rel=1e-8)


@pytest.mark.mpi
def test_serial_and_parallel_agree() -> None:
    """The distributed solve equals a serial solve of the same mesh (each rank solves alone)."""
    kappas = [1e-1, 1e-2, 1e-3, 1e-4, 1e-6]
    results = []
    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):
        problem = PenalizedProblem(paper_shell(), square(comm, n=20))
        steps = continuation(problem, NewtonSolver(problem), kappas)
        post = Postprocessor(problem)
        c = post.contact()
        results.append(
            {
                "iterations": [s.newton.iterations for s in steps],
                "energy": problem.energies()["energy"],
                "area": c["contact_area"],
                "nodes": c["num_contact_nodes"],
                "violation": c["max_violation"],
                "zeta3_min": post.zeta3_range()[0],
                "norm": l2_norm(problem.zeta),
            }
        )
    par, ser = results
    assert par["nodes"] == ser["nodes"] and par["nodes"] > 0
    for key in ("energy", "area", "violation", "zeta3_min", "norm"):
        assert par[key] == pytest.approx(ser[key], rel=1e-9, abs=1e-15), key


def test_an_iterative_solvers_options_never_reach_a_later_direct_solver() -> None:
    """Solver options live under a prefix of their own and leave with the solver.

    (Prefixes made from id() would be reused by later solvers, and a direct solver would then
    pick up a freed iterative solver's field split.)
    """
    import gc

    from petsc4py import PETSc

    problem = PenalizedProblem(paper_shell(), square(n=8))
    iterative = NewtonSolver(problem, NewtonOptions(linear_solver="iterative"))
    prefix = iterative.linear.ksp.getOptionsPrefix()
    assert PETSc.Options().hasName(prefix + "pc_type")
    del iterative
    gc.collect()
    assert not PETSc.Options().hasName(prefix + "pc_type")
    for _ in range(5):
        direct = NewtonSolver(problem, NewtonOptions(contact_zone=False))
        assert direct.linear.ksp.getOptionsPrefix() != prefix
        assert direct.linear.ksp.getPC().getType() == "cholesky"  # the default factorization


def test_phase_timings_do_not_overlap() -> None:
    """The solver's phase seconds are exclusive: their sum stays within the solves' time (the
    zone's Newton steps exclude its build, condensation and line searches)."""
    problem = PenalizedProblem(paper_shell(), square(n=32))
    solver = NewtonSolver(problem)
    steps = continuation(problem, solver, [1e-2, 1e-3, 1e-4])
    assert solver.timings["zone_newton"] > 0 and solver.timings["factorize"] > 0
    total = sum(s.newton.timings["total"] for s in steps)
    phases = sum(v for k, v in solver.timings.items() if k not in ("setup", "predict"))
    assert phases <= total


@pytest.mark.mpi
def test_moved_iterate_has_the_residual_and_gaps_computed_anew() -> None:
    """After a line search and the move, the gaps and residual the system updated in place
    (from ``Bδ`` and ``Kδ``) are those of the new iterate computed from scratch, and a
    ``penalty_gaps`` taken earlier keeps its values (a copy)."""
    problem = PenalizedProblem(paper_shell(), square(n=16), Discretization())
    solver = NewtonSolver(problem)
    continuation(problem, solver, [0.05])
    before = solver.penalty_gaps
    kept = before.copy()
    system = solver.system
    problem.set_kappa(0.01)
    system.residual()
    solver.linear.begin()
    solver.linear.direction([system.residual_norm()], 0.0)
    system.dz.scale(3.0)  # three times Newton's step: the line search cuts it
    slope0 = system.slope()
    t, _ = system.line_search(slope0, 0.0)
    assert 0.1 < t < 0.9
    mask = system.penetrated_by_full_step()
    expected = system.g + system.penalty.apply_B(system.dz) < 0
    assert np.array_equal(mask, expected)
    system.move(t, small=False)
    assert abs(system.R.dot(system.dz)) <= 1e-8 * abs(slope0)  # φ'(t) = 0: the exact step
    g_updated, R_updated = system.g.copy(), system.R.copy()
    system.residual()
    scale = np.abs(system.g).max()
    assert np.allclose(g_updated, system.g, rtol=0.0, atol=1e-13 * scale)
    R_updated.axpy(-1.0, system.R)
    assert R_updated.norm() <= 1e-10 * system.R.norm() + 1e-14 * system.f.norm()
    assert np.array_equal(before, kept)
    assert not before.flags.writeable
