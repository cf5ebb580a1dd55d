"""Nested iteration on the mesh levels (solvers/newton/nested.py) and the relaxation of ζ_3 after a
cut Newton step (solvers/newton/normal_relaxation.py)."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
from conftest import ball, disk, ladder
from conftest import make_paper_shell as paper_shell

from shellobstacle.mesh.hierarchy import coarser_meshes, prolongation
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.norms import l2_norm
from shellobstacle.solvers.auto import check_nested, resolve
from shellobstacle.solvers.methods.newton import NewtonContinuation
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.nested import interpolate
from shellobstacle.solvers.newton.normal_relaxation import NormalRelaxation
from shellobstacle.solvers.newton.solver import NewtonOptions, NewtonSolver
from shellobstacle.spec import Discretization

MULTIGRID = NewtonOptions(linear_solver="multigrid")
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def solved_plainly(mesh) -> tuple[PenalizedProblem, list]:
    """The paper's problem on ``mesh`` by the continuation on the ladder, multigrid."""
    problem = PenalizedProblem(paper_shell(), mesh)
    return problem, continuation(problem, NewtonSolver(problem, MULTIGRID), ladder(mesh))


def interpolated_start(mesh) -> tuple[PenalizedProblem, NewtonSolver]:
    """The paper's problem on ``mesh`` at its last κ, started from the next coarser mesh's
    solution (its own continuation) interpolated: the start that misses the contact ring."""
    coarse_mesh = coarser_meshes(mesh)[-1]
    coarse = PenalizedProblem(paper_shell(), coarse_mesh)
    continuation(coarse, NewtonSolver(coarse), ladder(mesh))
    problem = PenalizedProblem(paper_shell(), mesh, kappa=ladder(mesh)[-1])
    interpolate(coarse, problem)
    return problem, NewtonSolver(problem, dataclasses.replace(MULTIGRID, normal_relaxation=True))


@pytest.mark.mpi
def test_nested_iteration_ends_at_the_continuations_solution() -> None:
    """The coarser levels first, then the last κ alone on the finest: the same ζ and contact
    area as the continuation on the finest mesh (solver tolerance), in fewer Newton steps
    there, serially and on 2 ranks."""
    mesh = disk(2)
    plain, steps = solved_plainly(mesh)
    problem = PenalizedProblem(paper_shell(), mesh)
    options = dataclasses.replace(MULTIGRID, nested_iteration="on")
    out = NewtonContinuation().solve(problem, 0.0, ladder(mesh), options)
    assert out.converged and len(out.steps) == 1
    assert out.steps[0].kappa == ladder(mesh)[-1]
    levels = out.extra["nested_iteration"]["levels"]
    assert [lv["dofs"] for lv in levels] == [
        PenalizedProblem(paper_shell(), m).num_dofs for m in coarser_meshes(mesh)
    ]
    assert len(levels[0]["newton"]) == 3 and all(len(lv["newton"]) == 1 for lv in levels[1:])
    assert l2_norm(problem.zeta - plain.zeta) <= 1e-8 * l2_norm(plain.zeta)
    areas = [Postprocessor(p).contact()["contact_area"] for p in (plain, problem)]
    assert areas[0] > 0 and abs(areas[1] - areas[0]) <= 1e-10 * areas[0]
    assert out.steps[0].iterations < sum(s.iterations for s in steps)


@pytest.mark.mpi
def test_the_relaxation_minimizes_over_zeta3_alone() -> None:
    """From the interpolated start: ζ_1, ζ_2 are untouched, the normal residual falls below
    its tolerance, the energy decreases, and the residual and gaps the system updated in place
    are those computed anew."""
    _, solver = interpolated_start(disk(2))
    system = solver.system
    system.load()
    system.residual()
    before, energy = system.zeta.array_r.copy(), system.energy()
    relaxation = NormalRelaxation(system, rtol=1e-6)
    assert relaxation.relax() >= 1
    after = system.zeta.array_r.reshape(-1, 3)
    assert np.array_equal(after[:, :2], before.reshape(-1, 3)[:, :2])
    assert system.energy() < energy
    R3 = system.R.array_r.reshape(-1, 3)[:, 2]
    normal = np.sqrt(MPI.COMM_WORLD.allreduce(float(R3 @ R3)))
    assert normal <= 1e-6 * system.residual_norm()
    kept_R, kept_g = system.R.copy(), system.g.copy()
    system.residual()
    kept_R.axpy(-1.0, system.R)
    assert kept_R.norm() <= 1e-10 * system.residual_norm()
    assert np.allclose(kept_g, system.g, rtol=0, atol=1e-12)
    relaxation.destroy()


def test_the_relaxed_full_step_removes_the_crawl() -> None:
    """From the interpolated start the first step is cut far below 1; with the relaxation the
    next steps are full and Newton needs fewer of them than without it."""
    counts = {}
    for relax in (True, False):
        _, solver = interpolated_start(disk(2))
        solver.options = dataclasses.replace(solver.options, normal_relaxation=relax)
        result = solver.solve()
        assert result.converged
        assert result.step_lengths[0] < 0.5
        counts[relax] = result.iterations
        assert (result.relaxed_steps >= 1) is relax
    assert counts[True] < counts[False]


def test_nested_iteration_names_what_it_needs() -> None:
    """A mesh without coarser levels and Koiter's model are refused with the fix."""
    flat = PenalizedProblem(paper_shell(), disk(0))
    with pytest.raises(ValueError, match=r"domain\.refinements"):
        check_nested(flat)
    koiter = PenalizedProblem(paper_shell(model="koiter"), disk(1), Discretization(degree=2))
    with pytest.raises(ValueError, match="membrane"):
        check_nested(koiter)
    with pytest.raises(ValueError, match="membrane"):
        NewtonSolver(koiter, NewtonOptions(normal_relaxation=True))


def test_a_full_step_no_better_than_the_cut_one_is_undone(monkeypatch) -> None:
    """Without relaxing, the full step's energy is above the exact line search's minimum on
    the segment: :meth:`NormalRelaxation.full_step` goes back to the cut step, with the
    residual and gaps of the cut step."""
    _, solver = interpolated_start(disk(2))
    system = solver.system
    system.load()
    system.residual()
    solver.linear.begin()
    solver.linear.direction([system.residual_norm()], 0.0)
    t, _ = system.line_search(system.slope(), 0.0)
    assert t < 0.5
    system.move(t, False)
    cut, R, g = system.zeta.array_r.copy(), system.R.copy(), system.g.copy()
    relaxation = NormalRelaxation(system)
    monkeypatch.setattr(relaxation, "relax", lambda: 0)
    assert not relaxation.full_step(t)
    assert np.array_equal(system.zeta.array_r, cut)
    R.axpy(-1.0, system.R)
    assert R.norm() <= 1e-12 * system.residual_norm()
    assert np.allclose(g, system.g, rtol=0, atol=1e-14)
    relaxation.destroy()


def test_a_nested_iteration_that_fails_falls_back_to_the_continuation(monkeypatch, caplog) -> None:
    """A coarser level that does not converge is reported, and the finest mesh is then solved
    by the continuation on the whole ladder, from ζ = 0: the plain continuation's solution."""
    import shellobstacle.solvers.newton.nested as nested
    from shellobstacle.solvers.result import ConvergenceError

    def fails(problem, *args, **kwargs):
        problem.zeta.x.array[:] = 1.0  # a failed level leaves something behind
        raise ConvergenceError("Newton did not converge for kappa = 1")

    monkeypatch.setattr(nested, "nested_start", fails)
    mesh = disk(2)
    plain, _ = solved_plainly(mesh)
    problem = PenalizedProblem(paper_shell(), mesh)
    options = dataclasses.replace(MULTIGRID, nested_iteration="on")
    with caplog.at_level(logging.INFO, logger="shellobstacle"):
        out = NewtonContinuation().solve(problem, 0.0, ladder(mesh), options)
    assert out.converged and len(out.steps) == 3
    assert out.extra["nested_iteration"] == {"failed": "Newton did not converge for kappa = 1"}
    assert any("nested iteration failed" in line for line in caplog.messages)
    assert l2_norm(problem.zeta - plain.zeta) <= 1e-8 * l2_norm(plain.zeta)


def test_the_config_refuses_nested_iteration_for_koiter(tmp_path) -> None:
    """``model.kind = 'koiter'`` with ``solver.nested_iteration = true`` names the fix."""
    from shellobstacle.config.loader import ConfigError, load_config

    with pytest.raises(ConfigError, match="nested_iteration"):
        load_config(EXAMPLES / "cylinder_koiter.toml", ['solver.nested_iteration="on"'])


@pytest.mark.mpi
def test_auto_takes_nested_iteration_with_multigrid_on_one_rank_only() -> None:
    """``nested_iteration = "auto"`` (the default): on with multigrid on a refined mesh on
    one rank (off on several), off with the direct path there and with multigrid on a mesh
    without levels (GAMG); ``"on"`` and ``"off"`` as asked, on any number of ranks."""
    refined = PenalizedProblem(paper_shell(), disk(1))
    flat = PenalizedProblem(paper_shell(), disk(0))
    assert NewtonOptions().nested_iteration == "auto"

    def nested(problem: PenalizedProblem, options: NewtonOptions) -> str:
        return resolve(problem, options).options.nested_iteration

    assert nested(refined, MULTIGRID) == ("on" if MPI.COMM_WORLD.size == 1 else "off")
    assert nested(refined, dataclasses.replace(MULTIGRID, nested_iteration="on")) == "on"
    assert nested(refined, NewtonOptions(linear_solver="direct")) == "off"
    assert nested(refined, NewtonOptions()) == "off"  # "auto" is direct at this size
    assert nested(flat, MULTIGRID) == "off"
    assert nested(refined, dataclasses.replace(MULTIGRID, nested_iteration="off")) == "off"


@pytest.mark.mpi
def test_the_located_points_are_reused_only_for_the_same_points() -> None:
    """The prolongation remembers where the fine nodes lie in the coarse mesh: P1, then P2
    (other points), then P1 again between the same meshes all interpolate exactly."""
    fine = disk(1)
    coarse = coarser_meshes(fine)[-1]

    def error(degree: int) -> float:
        spaces = [dolfinx.fem.functionspace(m, ("Lagrange", degree, (3,))) for m in (coarse, fine)]
        u_c, u_f = (dolfinx.fem.Function(V) for V in spaces)

        def f(x: np.ndarray) -> np.ndarray:  # in both spaces
            return np.stack([x[0] * x[1] ** (degree - 1), 1 + x[0], x[1] ** degree])

        for u in (u_c, u_f):
            u.interpolate(f)
        P = prolongation(*spaces)
        v = P.createVecLeft()
        P.mult(u_c.x.petsc_vec, v)
        owned = u_f.x.petsc_vec.getLocalSize()
        return MPI.COMM_WORLD.allreduce(np.max(np.abs(v.array - u_f.x.array[:owned])), op=MPI.MAX)

    assert max(error(1), error(2), error(1)) < 1e-12


def test_the_finest_levels_newton_steps_stay_flat_as_h_halves() -> None:
    """With nested iteration the finest mesh takes as many Newton steps (within one) on 1, 2
    and 3 refinements (2k–31k dofs; 5, 6, 6 when written), fewer than the continuation's over
    the ladder (12, 11, 13)."""
    nested, plain = [], []
    for refinements in (1, 2, 3):
        mesh = disk(refinements)
        for mode, counts in (("on", nested), ("off", plain)):
            problem = PenalizedProblem(paper_shell(), mesh)
            options = dataclasses.replace(MULTIGRID, nested_iteration=mode)
            out = NewtonContinuation().solve(problem, 0.0, ladder(mesh), options)
            assert out.converged
            counts.append(sum(s.iterations for s in out.steps))
    assert max(nested) - min(nested) <= 1, nested
    assert all(n < p for n, p in zip(nested, plain, strict=True)), (nested, plain)


@pytest.mark.mpi
def test_nested_iteration_on_a_curved_obstacle_ends_at_the_plain_answer(monkeypatch) -> None:
    """A ball (its gap linearized, the passes of solvers/linearization.py): each coarser level
    is linearized at its start, the finest mesh's passes solve the last κ only and settle the
    gap, nested iteration runs on the first pass alone, and ζ is the plain continuation's
    (solver tolerance), serially and on 2 ranks."""
    from shellobstacle.solvers.linearization import solve_with
    from shellobstacle.solvers.newton import nested as nested_module

    calls: list[int] = []
    original = nested_module.nested_start

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(nested_module, "nested_start", counted)
    mesh = disk(2)
    shell = dataclasses.replace(paper_shell(), obstacle=ball(2.0))
    zeta, outs = {}, {}
    for nested in ("on", "off"):
        problem = PenalizedProblem(shell, mesh)
        assert problem.linearized
        options = dataclasses.replace(MULTIGRID, nested_iteration=nested)
        method = NewtonContinuation()
        outs[nested] = solve_with(method, problem, 0.0, ladder(mesh), options)
        assert outs[nested].converged
        passes = outs[nested].extra["linearization"]
        assert passes["residual"][-1] <= passes["residual_target"][-1]
        zeta[nested] = problem.zeta
    out = outs["on"]
    assert len(calls) == 1  # the later passes go on from the finest mesh's answer
    levels = out.extra["nested_iteration"]["levels"]
    assert [level["kappas"] for level in levels] == [ladder(mesh), ladder(mesh)[-1:]]
    assert out.extra["linearizations"] >= 1 and len(out.steps) == out.extra["linearizations"]
    assert {step.kappa for step in out.steps} == {ladder(mesh)[-1]}
    diff = l2_norm(zeta["on"] - zeta["off"], mesh=mesh)
    assert diff <= 1e-7 * l2_norm(zeta["off"], mesh=mesh)
