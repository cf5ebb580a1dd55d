"""The experiments solve through the method registry and take κ from the penalty: no solver
below :data:`~shellobstacle.solvers.registry.METHODS` is built in ``experiments/``."""

from __future__ import annotations

import ast
import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from conftest import PENALTY, make_paper_shell, square

from shellobstacle.experiments.load import load_study
from shellobstacle.experiments.mesh import mesh_levels, mesh_study
from shellobstacle.experiments.penalty import PenaltyStudyOptions, penalty_study
from shellobstacle.experiments.solvers import compare_solvers
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.brezis_sibony.options import BrezisSibonyOptions
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import Discretization

EXPERIMENTS = Path(__file__).parents[2] / "src" / "shellobstacle" / "experiments"
#: the solvers and loops below the registry's methods
BELOW_METHODS = (
    "shellobstacle.solvers.newton.solver",
    "shellobstacle.solvers.newton.continuation",
    "shellobstacle.solvers.brezis_sibony.iteration",
    "shellobstacle.solvers.vi",
)


def test_no_experiment_imports_a_solver_below_the_registry() -> None:
    """Every module of ``experiments/`` reaches Newton, Brezis–Sibony and the exact solvers
    through ``METHODS`` only."""
    found = []
    for path in sorted(EXPERIMENTS.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            found += [f"{path.name}: {n}" for n in names if n.startswith(BELOW_METHODS)]
    assert found == []


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> Counter:
    """The solves of each method of the registry, counted."""
    counted: Counter = Counter()
    for name, method in METHODS.items():

        def solve(*args, _solve=method.solve, _name=name, **kwargs):
            counted[_name] += 1
            return _solve(*args, **kwargs)

        monkeypatch.setattr(method, "solve", solve)
    return counted


def test_the_batches_solve_through_the_newton_method(calls: Counter) -> None:
    """Batch 1 solves each κ, batch 2 each (q, level), batch 3 each load by
    ``METHODS["newton"]``."""
    shell = make_paper_shell()
    mesh = square(n=8, half=0.5)
    study = penalty_study(shell, mesh, Discretization(), PenaltyStudyOptions(q_max=1.5))
    assert calls == {"newton": len(study.solves)} and len(study.solves) == 3

    calls.clear()
    levels = mesh_levels(shell, mesh, 1, Discretization())
    mesh_study(levels, 1.0, tol=0.0)
    assert calls == {"newton": 2}

    calls.clear()
    loaded = make_paper_shell(load="-ell*1e-6", parameters={"ell": 0.0})
    load_study(loaded, mesh, Discretization(), PENALTY, [0.0, 1.0])
    assert calls == {"newton": 2}


def test_the_solver_comparison_solves_through_both_methods(calls: Counter) -> None:
    """Newton against Brezis–Sibony: one solve of each method per mesh."""
    bs = BrezisSibonyOptions(max_iterations=50)
    rows = compare_solvers(make_paper_shell(), [square(n=8, half=0.5)], 1.0, bs_options=bs)
    assert calls == {"newton": 1, "brezis-sibony": 1}
    assert rows[0]["bs_iterations"] > 0 and rows[0]["newton_iterations"] > 0


def _problem() -> tuple[PenalizedProblem, float, list[float]]:
    """The paper's shell on a small square, at rest, with its ladder to κ = h^1.5."""
    mesh = square(n=8, half=0.5)
    problem = PenalizedProblem(make_paper_shell(), mesh, Discretization())
    h = mesh_size(mesh)
    return problem, h, PENALTY.ladder(h)


def test_kept_solves_that_go_on_are_one_continuation() -> None:
    """Inside ``keeping(problem, go_on=True)`` the κ of a ladder solved one at a time are its
    continuation: the same Newton steps and the same ζ, the Euler prediction included (the
    direct strategy predicts; the contact zone does not)."""
    newton = METHODS["newton"]
    options = NewtonOptions(contact_zone=False, nested_iteration="off")
    problem, h, kappas = _problem()
    whole = newton.solve(problem, h, kappas, options)
    expected = problem.zeta.x.array.copy()

    problem.zeta.x.array[:] = 0.0
    with newton.keeping(problem, go_on=True):
        steps = [newton.solve(problem, h, [k], options).steps[0] for k in kappas]
        solver = newton.kept_solver(problem, options)
    assert [s.iterations for s in steps] == [s.iterations for s in whole.steps]
    assert solver.timings["predict"] > 0
    assert np.allclose(problem.zeta.x.array, expected, rtol=0, atol=1e-13)


def test_the_kept_solver_of_a_plane_is_not_refreshed(monkeypatch: pytest.MonkeyPatch) -> None:
    """``kept_solver`` is the solver the kept solves use; a plane's gap does not move, so it
    is not refreshed between them; outside ``keeping`` there is none."""
    refreshed = []
    monkeypatch.setattr(NewtonSolver, "refresh", lambda self: refreshed.append(self))
    newton = METHODS["newton"]
    options = NewtonOptions(nested_iteration="off")
    problem, h, kappas = _problem()
    with newton.keeping(problem):
        solver = newton.kept_solver(problem, options)
        for kappa in kappas:
            assert newton.solve(problem, h, [kappa], options).converged
        assert newton.kept_solver(problem, options) is solver
        with newton.keeping(problem):  # an inner keeping keeps the same solver
            newton.solve(problem, h, kappas[-1:], options)
        assert newton.kept_solver(problem, options) is solver
    assert refreshed == []
    with pytest.raises(ValueError, match="inside keeping"):
        newton.kept_solver(problem, options)
    other = dataclasses.replace(options)
    with newton.keeping(problem):
        assert newton.kept_solver(problem, other) is not solver
