"""A curved obstacle's passes of sequential linearization (solvers/linearization.py): the
penalty's point operators follow the linearized gap in place, Newton's solver is kept from
pass to pass, and the answer is that of a solver built anew at every pass; the passes stop on
the curved problem's first-order quantities (the change of ζ, the curved residual or KKT
conditions), which the summary records, and Aitken's relaxation shortens them."""

from __future__ import annotations

import dataclasses

# isort: split
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import pytest
import ufl
from conftest import VERTEX, ball, global_max_abs, owned_zeta, solve_on, square
from conftest import make_paper_shell as paper_shell

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.methods.newton import NewtonContinuation
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.solvers.quadrature_penalty import QuadraturePenalty

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
    kept, contact_kept = solve_on(ball(10.0))
    assert len(built) == 1 and kept.extra["linearizations"] >= 2
    built.clear()
    monkeypatch.setattr(NewtonContinuation, "keeping", MethodBase.keeping)
    anew, contact_anew = solve_on(ball(10.0))
    assert len(built) == anew.extra["linearizations"] == kept.extra["linearizations"]
    assert kept.iterations == anew.iterations
    assert global_max_abs(owned_zeta(kept) - owned_zeta(anew)) <= 1e-12 * global_max_abs(
        owned_zeta(anew)
    )
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


def _curved_residual(problem: PenalizedProblem) -> float:
    """``‖Kζ − f + (ε/κ) ∫ −{g(ζ)}^- c(ζ)·v/|c| dy‖ / ‖f‖``: the curved penalized equation's
    residual, its penalty differentiated from the curved gap ``g(ζ)`` itself (global)."""
    eps = problem.shell.material.epsilon
    g_minus = ufl.conditional(ufl.lt(problem.g, 0), problem.g, 0)
    penalty = (eps / (2 * problem.kappa_x)) * g_minus**2 / problem.c_norm * problem.dx_penalty
    v = ufl.TestFunction(problem.V)
    b = dolfinx.fem.petsc.assemble_vector(
        dolfinx.fem.form(ufl.derivative(penalty, problem.zeta, v))
    )
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    dolfinx.fem.petsc.set_bc(b, problem.bcs)
    f = problem.load_vector()
    r = b.duplicate()
    problem.stiffness().mult(problem.zeta.x.petsc_vec, r)
    r.axpy(-1.0, f)
    r.axpy(1.0, b)
    return r.norm() / f.norm()


@pytest.mark.mpi
def test_the_passes_stop_on_the_curved_problems_residual() -> None:
    """On the ball of radius 2 the answer solves the curved penalized equation (its penalty
    differentiated from ``g(ζ)``, not from a linearization) to ``RESIDUAL_RTOL ‖f‖``, and the
    summary's record holds each pass's first-order quantities: the change of ζ, settled, and
    the curved residual, at its target; the same on every rank (global norms). The passes
    that stopped on the linearization's second-order error left 7.6e-9 after 2 passes."""
    from shellobstacle.solvers.linearization import RESIDUAL_RTOL, settled

    r, _ = solve_on(ball(2.0))
    passes = r.extra["linearization"]
    n = r.extra["linearizations"]
    for key in ("dzeta", "residual", "residual_target", "change"):
        assert len(passes[key]) == n, key
    assert len(passes["relaxation"]) == n - 1
    dzeta, residual = passes["dzeta"], passes["residual"]
    assert settled(dzeta[-1], dzeta[-2]) and dzeta[-1] <= 1e-8
    assert residual[-1] <= passes["residual_target"][-1] == RESIDUAL_RTOL
    assert _curved_residual(r.problem) <= RESIDUAL_RTOL
    assert all(other == passes for other in COMM.allgather(passes))


@pytest.mark.mpi
def test_the_exact_solvers_passes_stop_on_the_curved_kkt_conditions() -> None:
    """active-set on the ball of radius 2 (the vertex constraint): each pass records the
    largest relative KKT measure with the curved gap and its derivative at the nodes, and
    the last meets the method's ``kkt_rtol``."""
    from shellobstacle.solvers.vi.options import ActiveSetOptions

    r, contact = solve_on(ball(2.0), "active-set", penalty=None, discretization=VERTEX)
    passes = r.extra["linearization"]
    assert "KKT" in passes["residual_of"]
    assert passes["residual"][0] > 1e-6  # the first pass: the gap linearized at ζ = 0
    assert passes["residual"][-1] <= ActiveSetOptions().kkt_rtol == passes["residual_target"][-1]
    assert contact["max_violation"] <= 1e-14


def test_aitkens_relaxation_shortens_the_passes_on_a_small_ball(monkeypatch) -> None:
    """A ball of radius 0.035, under two cells: once the contact set has settled the plain
    passes (ω = 1) divide the change of ζ by about 5 each, and reach the tolerances in 17;
    Aitken's relaxation reaches the same answer in at most 13."""
    from shellobstacle.solvers import linearization

    relaxed, _ = solve_on(ball(0.035))
    monkeypatch.setattr(linearization, "RELAXATION_BOUNDS", (1.0, 1.0))
    plain, _ = solve_on(ball(0.035))
    assert relaxed.extra["linearizations"] <= 13
    assert plain.extra["linearizations"] >= relaxed.extra["linearizations"] + 4
    assert max(plain.extra["linearization"]["relaxation"]) == 1.0
    assert max(relaxed.extra["linearization"]["relaxation"]) > 1.0
    assert global_max_abs(owned_zeta(relaxed) - owned_zeta(plain)) <= 1e-8 * global_max_abs(
        owned_zeta(plain)
    )
