"""Newton's round-off floor counts the rounding of ``Kζ`` (solvers/system.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from shellobstacle.model import Discretization
from shellobstacle.problem import PenalizedProblem
from shellobstacle.solvers.newton import NewtonSolver
from tests.test_active_set import paper_shell
from tests.test_active_set_p2 import square


@pytest.mark.mpi
@pytest.mark.parametrize("model", ["membrane", "koiter"])
def test_elastic_rounding_is_u_times_abs_K_abs_zeta(model: str) -> None:
    """The row-sum estimate ``(Σ_j |K_ij|) |ζ_i|`` of ``|K||ζ|`` at a solution is within 2 %
    of the product itself, and the floor of Newton's stopping rule contains it."""
    shell = dataclasses.replace(paper_shell(), model=model)
    problem = PenalizedProblem(shell, square(16), Discretization(degree=2))
    problem.set_kappa((0.5 / 16) ** 1.5)
    solver = NewtonSolver(problem)
    solver.solve()
    system = solver.system
    K = system.K.copy()
    rows, cols, values = K.getValuesCSR()
    K.setValuesCSR(rows, cols, np.abs(values))
    K.assemble()
    zeta = system.zeta.copy()
    zeta.abs()
    product = K.createVecLeft()
    K.mult(zeta, product)
    exact = np.finfo(float).eps * product.norm()
    assert system.elastic_rounding() == pytest.approx(exact, rel=0.02)
    assert system.floor(system.load()) >= system.elastic_rounding() > 0
    # the same on every rank
    values = problem.mesh.comm.allgather(system.elastic_rounding())
    assert max(values) == min(values)
    for obj in (K, zeta, product):
        obj.destroy()
