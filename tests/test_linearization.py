"""A curved obstacle's passes of sequential linearization (solvers/linearization.py): the
penalty's point operators follow the linearized gap in place, Newton's solver is kept from
pass to pass, and the answer is that of a solver built anew at every pass."""

from __future__ import annotations

import dataclasses

# isort: split
from mpi4py import MPI

import dolfinx.fem
import numpy as np
import pytest

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.quadrature import QuadraturePenalty
from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.methods.newton import NewtonContinuation
from shellobstacle.solvers.newton import NewtonSolver
from tests.test_active_set import paper_shell, square
from tests.test_obstacle_kinds import _max, _solve, _zeta, ball

COMM = MPI.COMM_WORLD


def _csr(M) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return tuple(np.array(a) for a in M.getValuesCSR())


@pytest.mark.mpi
def test_a_refreshed_penalty_is_the_one_built_anew() -> None:
    """After ``ζ̄`` moves, :meth:`QuadraturePenalty.refresh` gives ``M``, ``Mᵀ``, ``D`` and
    ``g0`` equal to the last bit to those of a penalty built at the new ``ζ̄``."""
    shell = dataclasses.replace(paper_shell(), obstacle=ball(2.0))
    problem = PenalizedProblem(shell, square(n=8), kappa=1e-3)
    problem.linearize()
    penalty = QuadraturePenalty(problem)
    penalty.store_transpose()
    g0_before = penalty.g0.copy()
    problem.zeta.interpolate(
        lambda x: np.vstack([0.01 * x[0], -0.02 * x[1], -0.05 + 0.3 * (x[0] ** 2 + x[1] ** 2)])
    )
    problem.zeta.x.scatter_forward()
    problem.linearize()
    penalty.refresh()
    fresh = QuadraturePenalty(problem)
    fresh.store_transpose()
    assert COMM.allreduce(not np.array_equal(g0_before, penalty.g0), op=MPI.LOR)
    assert np.array_equal(penalty.g0, fresh.g0) and np.array_equal(penalty.D, fresh.D)
    for mine, theirs in ((penalty.M, fresh.M), (penalty._MT, fresh._MT)):
        for a, b in zip(_csr(mine), _csr(theirs), strict=True):
            assert np.array_equal(a, b)


@pytest.fixture
def built(monkeypatch) -> list[NewtonSolver]:
    """Every Newton solver built from now on."""
    solvers: list[NewtonSolver] = []
    original = NewtonSolver.__init__

    def counting(self, *args, **kwargs) -> None:
        solvers.append(self)
        original(self, *args, **kwargs)

    monkeypatch.setattr(NewtonSolver, "__init__", counting)
    return solvers


@pytest.mark.mpi
def test_newton_keeps_its_solver_from_pass_to_pass(built, monkeypatch) -> None:
    """One Newton solver for all the passes on a ball, with the answer, the passes and the
    Newton steps of one solver built anew at every pass (the method keeping nothing)."""
    kept, contact_kept = _solve(ball(10.0))
    assert len(built) == 1 and kept.extra["linearizations"] >= 2
    built.clear()
    monkeypatch.setattr(NewtonContinuation, "keeping", MethodBase.keeping)
    anew, contact_anew = _solve(ball(10.0))
    assert len(built) == anew.extra["linearizations"] == kept.extra["linearizations"]
    assert kept.iterations == anew.iterations
    assert _max(_zeta(kept) - _zeta(anew)) <= 1e-12 * _max(_zeta(anew))
    assert contact_kept["contact_area"] == pytest.approx(contact_anew["contact_area"], rel=1e-12)


def test_balls_of_two_radii_share_their_compiled_forms() -> None:
    """The radius and the centre are Constants: the forms of R = 10 and R = 100 share one
    compiled module per form, and each problem's gap holds its own ball."""
    mesh = square(n=8)
    problems = [
        PenalizedProblem(dataclasses.replace(paper_shell(), obstacle=ball(R)), mesh, kappa=1e-3)
        for R in (10.0, 100.0)
    ]
    modules = [{name: f.module.__name__ for name, f in _forms(p)} for p in problems]
    assert modules[0] == modules[1] and "residual" in modules[0]
    for problem in problems:  # the gap with Constants is the one with literals
        dx = problem.dx
        literal = problem.obstacle.reference_gap(problem.G)
        values = [
            COMM.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(e * dx)))
            for e in (problem.g0, literal)
        ]
        assert values[0] == pytest.approx(values[1], rel=1e-14)


def _forms(problem: PenalizedProblem):
    for name, form in problem.forms.items():
        if isinstance(form, dict):
            yield from ((f"{name}.{k}", f) for k, f in form.items())
        else:
            yield name, form
