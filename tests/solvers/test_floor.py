"""Newton's round-off floor counts the rounding of ``Kζ`` (solvers/newton/system.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import make_paper_shell as paper_shell
from conftest import square

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.spec import Discretization


@pytest.mark.mpi
@pytest.mark.parametrize("model", ["membrane", "koiter"])
def test_elastic_rounding_is_u_times_abs_K_abs_zeta(model: str) -> None:
    """The row-sum estimate ``(Σ_j |K_ij|) |ζ_i|`` of ``|K||ζ|`` at a solution is within 2 %
    of the product itself, and the floor of Newton's stopping rule contains it."""
    shell = dataclasses.replace(paper_shell(), model=model)
    problem = PenalizedProblem(shell, square(n=16), Discretization(degree=2))
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


def test_the_zone_floor_counts_the_rounding_of_its_own_products(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """From ``ζ = 0`` the zone's problem is solved before any whole iterate exists, so the
    whole system's ``u ‖|K||ζ|‖`` is 0 there: the zone's floor contains ``u ‖|K_S||ζ_Z|‖`` of
    its current iterate (against the dense product) and is positive once
    ``ζ_Z ≠ 0``."""
    from shellobstacle.solvers.linear.zone import ZoneStrategy
    from shellobstacle.solvers.newton.solver import NewtonOptions
    from shellobstacle.solvers.zone.reduced import ZoneModel

    seen: list[tuple[float, float, float]] = []
    floor = ZoneModel.floor

    def recording(self: ZoneModel, load_norm: float) -> float:
        value = floor(self, load_norm)
        rows, cols, values = self.problem.cond.Ks.getValuesCSR()
        Ks = np.zeros((rows.size - 1, rows.size - 1))
        Ks[np.repeat(np.arange(rows.size - 1), np.diff(rows)), cols] = values
        exact = np.finfo(float).eps * np.linalg.norm(np.abs(Ks) @ np.abs(self.z.array_r))
        seen.append((value, exact, self.system.elastic_rounding()))
        return value

    problem = PenalizedProblem(paper_shell(), square(n=32))
    problem.set_kappa(1e-2)
    # floor_factor ≈ 0 leaves only the rounding terms in the floor
    solver = NewtonSolver(problem, NewtonOptions(floor_factor=1e-30), ZoneStrategy(seed=True))
    monkeypatch.setattr(ZoneModel, "floor", recording)
    assert solver.solve().converged
    assert seen, "the zone's problem was not used"
    assert seen[0][2] == 0.0  # no whole iterate yet: ζ = 0
    for value, exact, whole in seen:
        # (Σ_j |K_S,ij|) |z_i| estimates |K_S||z|: 4 % apart here
        assert value == pytest.approx(whole + exact, rel=0.1, abs=1e-40)
    assert any(exact > 0 for _, exact, _ in seen)


@pytest.mark.mpi
@pytest.mark.parametrize("kind", ["aij", "baij"])
def test_abs_row_sums_are_the_rows_absolute_sums(kind: str) -> None:
    """``Σ_j |K_ij|`` of the owned rows: PETSc's own sums for AIJ (``MatGetRowSumAbs``), the
    copied rows' for another format, both the sums of the entries' absolute values."""
    from petsc4py import PETSc

    from shellobstacle.solvers.newton.system import ROW_SUM_ABS_TYPES, abs_row_sums

    problem = PenalizedProblem(paper_shell(), square(n=8), Discretization(degree=1))
    K = problem.stiffness()
    A = K if kind == "aij" else K.convert(PETSc.Mat.Type.BAIJ)
    assert (A.getType() in ROW_SUM_ABS_TYPES) == (kind == "aij")
    start, end = A.getOwnershipRange()
    expected = np.array([np.abs(A.getRow(i)[1]).sum() for i in range(start, end)], dtype=float)
    sums = abs_row_sums(A)
    assert sums.shape == (end - start,)
    assert np.all(expected > 0)
    np.testing.assert_allclose(sums, expected, rtol=1e-14, atol=0)
