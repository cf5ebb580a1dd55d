"""The hybrid bending form of Koiter's model: its blocks, its Schur complement, the contact
zone condensed in the block matrix, and serial against distributed contact solves.

Its convergence (energy-norm rates on manufactured solutions, the clamped plate, the
membrane limit) is tested with the interior-penalty form's in test_koiter.py.
"""

from __future__ import annotations

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
import ufl
from conftest import lu_solve, make_paper_shell, without_petsc_function

from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.models.hybrid_bending import facet_midpoints, facet_normals
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.solvers.base import direct_solver
from shellobstacle.solvers.linear.zone import ZoneStrategy
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.solvers.zone.condensation import Condensation
from shellobstacle.solvers.zone.contact_zone import ContactZone
from shellobstacle.spec import Discretization

COMM = MPI.COMM_WORLD


def paper_koiter(comm: MPI.Comm, h: float, bending: str = "hybrid") -> PenalizedProblem:
    shell = make_paper_shell(model="koiter")
    mesh = create_mesh(DomainSpec(kind="disk", h=h, radius=0.5), comm, ghosted=True)
    return PenalizedProblem(shell, mesh, Discretization(degree=2, bending=bending))


def test_facet_normals_are_unit_normals_of_their_facets() -> None:
    """At every facet's midpoint ``n_F`` is ± the outer normal of each of its cells."""
    problem = paper_koiter(COMM, 0.1)
    mesh = problem.mesh
    n_F = facet_normals(mesh)
    n = ufl.FacetNormal(mesh)
    midpoint = {"quadrature_degree": 1}
    forms = {
        "interior": (1 - ufl.dot(n("+"), n_F("+")) ** 2) ** 2 * ufl.dS(metadata=midpoint),
        "boundary": (1 - ufl.dot(n, n_F) ** 2) ** 2 * ufl.ds(metadata=midpoint),
        "length": ufl.dot(n_F("+"), n_F("+")) * ufl.dS(metadata=midpoint),
        "facets": 1 * ufl.dS(domain=mesh),
    }
    values = {
        k: COMM.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(f)))
        for k, f in forms.items()
    }
    assert values["interior"] < 1e-24 and values["boundary"] < 1e-24
    assert values["length"] == pytest.approx(values["facets"], rel=1e-12)


def test_facet_midpoints_hold_each_cells_outward_normal_and_facet_length() -> None:
    """The midpoint rule of the cells' facets with ``|F|`` and ``n_T``: ``Σ_F |F| x·n_T`` over
    each cell's facets is ``∫_∂T x·n = 2|T|`` (exact for a linear integrand), and ``Σ |F|``
    counts interior facets twice and boundary facets once."""
    mesh = paper_koiter(COMM, 0.1).mesh
    mid = facet_midpoints(mesh)
    weight = mid.length / abs(ufl.JacobianDeterminant(mesh))
    x = ufl.SpatialCoordinate(mesh)

    def total(form: ufl.Form) -> float:
        return COMM.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(form)))

    area = total(1 * ufl.dx(domain=mesh))
    assert total(weight * ufl.dot(x, mid.normal) * mid.dx) == pytest.approx(2 * area, rel=1e-12)
    assert total(weight * (ufl.dot(mid.normal, mid.normal) - 1) ** 2 * mid.dx) < 1e-24
    facets = total(2 * ufl.dS(domain=mesh) + 1 * ufl.ds(domain=mesh))
    assert total(weight * mid.dx) == pytest.approx(facets, rel=1e-12)


def test_stiffness_is_the_schur_complement_of_the_blocks() -> None:
    """``K ζ = f`` and the block system ``[[A, B], [Bᵀ, C]] (ζ, t) = (f, 0)`` have the same ζ,
    and ``t`` is the multiplier that minimizes the energy at ζ (its residual vanishes)."""
    problem = paper_koiter(COMM, 0.1)
    K = problem.stiffness()
    blocks = problem.condensed
    f = problem.load_vector()
    zeta = K.createVecRight()
    direct_solver(K, "cholesky").solve(f, zeta)
    # the block equations at (ζ, t(ζ)): A ζ + B t = f and Bᵀ ζ + C t = 0
    t = blocks.B.createVecRight()
    blocks.multiplier(zeta, t)
    first = f.duplicate()
    blocks.A.mult(zeta, first)
    blocks.B.multAdd(t, first, first)
    first.axpy(-1.0, f)
    second = t.duplicate()
    blocks.B.multTranspose(zeta, second)
    ct = t.duplicate()
    ct.pointwiseMult(blocks.c, t)
    second.axpy(1.0, ct)
    assert first.norm() <= 1e-10 * f.norm()
    assert second.norm() <= 1e-10 * (ct.norm() + 1e-300)
    assert t.norm() > 0  # the multiplier is used: ζ_3's normal derivatives at the midpoints


def koiter_solved(comm: MPI.Comm, h: float) -> tuple[PenalizedProblem, NewtonSolver, list]:
    problem = paper_koiter(comm, h)
    solver = NewtonSolver(problem)
    steps = continuation(problem, solver, [h**0.5, h, h**1.5])
    assert all(s.converged for s in steps)
    return problem, solver, steps


@pytest.mark.mpi
def test_the_zone_condensed_in_the_block_matrix_solves_with_the_jacobian() -> None:
    """The contact zone condensed in ``H`` (its multipliers with it) solves with ``J = K + P``
    exactly, and couples to fewer outside unknowns than the zone condensed in ``K``."""
    problem, solver, _ = koiter_solved(COMM, 0.05)
    zone = solver.zone
    assert zone.cond is not None and zone.cond.blocks is not None
    sizes = zone.sizes
    assert sizes["zone_multipliers"] > 0
    assert zone.cond.F_I.F.getMumpsIcntl(15) == 1  # ordered on the nodes' blocks
    outside = np.setdiff1d(np.arange(zone.cond.K.getSize()[0]), zone.cond.Z)
    runs = zone.cond.blocks.variable_blocks(outside)
    multipliers = problem.condensed.B.getSize()[1] - sizes["zone_multipliers"]
    assert runs.sum() == outside.size and runs.max() == 3
    assert np.count_nonzero(runs == 3) == (outside.size - multipliers) // 3  # whole nodes
    blocks = zone.cond.blocks  # H's numbers of ζ's and t's owned rows
    r0, r1 = problem.stiffness().getOwnershipRange()
    t0, t1 = problem.condensed.B.getOwnershipRangeColumn()
    assert np.array_equal(blocks.rows_zeta.getIndices(), blocks.of_zeta(np.arange(r0, r1)))
    assert np.array_equal(blocks.rows_t.getIndices(), blocks.of_t(np.arange(t0, t1)))
    system = solver.system
    system.zeta.scale(0.9)  # away from the solution: a Newton step of some size
    system.problem.zeta.x.scatter_forward()
    system.residual()
    J = system.jacobian()
    assert zone.covers(system.g < 0)
    zone.set_up(J)
    b = system.R.duplicate()
    b.array[:] = np.random.default_rng(COMM.rank).standard_normal(b.getLocalSize())
    x = b.duplicate()
    zone.cond.apply(b, x)
    exact = lu_solve(J, b)
    x.axpy(-1.0, exact)
    assert x.norm() <= 1e-9 * exact.norm()
    # a Newton step from the state (ζ, t(ζ)): x = −R(ζ)
    system.negate_residual()
    zone.newton_step(system.R, system.zeta, x)
    exact = lu_solve(J, system.R)
    assert exact.norm() > 1e-3 * system.zeta.norm()
    x.axpy(-1.0, exact)
    assert x.norm() <= 1e-9 * exact.norm()
    plain = Condensation(problem.stiffness(), zone.Z, "cholesky", {"factorize": 0.0})
    assert sizes["coupled_dofs"] < plain.sizes["coupled_dofs"]
    plain.destroy()


@pytest.mark.mpi
def test_a_zone_too_large_factorizes_the_block_matrix_with_the_penalty() -> None:
    """Above the zone's largest fraction the hybrid stiffness' Jacobian is solved through
    ``H`` plus the penalty (Cholesky, the nodes as MUMPS blocks): the Newton steps and the
    solution of the unseeded zone, whose steps are those of ``J_κ``."""
    runs = []
    for linear in (ZoneStrategy(seed=False), ZoneStrategy(max_fraction=1e-6)):
        problem = paper_koiter(COMM, 0.05)
        solver = NewtonSolver(problem, linear=linear)
        steps = continuation(problem, solver, [0.05**0.5, 0.05, 0.05**1.5])
        assert all(s.converged for s in steps)
        runs.append(([s.newton.iterations for s in steps], problem.zeta.x.petsc_vec.copy()))
    zone = solver.zone
    assert zone.whole and zone.whole_H is not None
    assert zone.whole_H.getSize() == zone.blocks.H.getSize()
    assert zone.whole_ksp.getPC().getFactorMatrix().getMumpsIcntl(15) == 1
    (condensed, reference), (whole, zeta) = runs
    assert whole == condensed
    zeta.axpy(-1.0, reference)
    assert zeta.norm() <= 1e-9 * reference.norm()


@pytest.mark.mpi
def test_zone_steps_with_and_without_the_multipliers_agree(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The zone's problem in ``(ζ_Z, t_Z)``, started from minimizing multipliers, takes the
    Newton steps of the problem in ``ζ_Z`` alone: the same steps per κ, the same solution."""
    runs = []
    for blocks in (True, False):
        if not blocks:
            monkeypatch.setattr(ContactZone, "_blocks", lambda self: None)
        problem, solver, steps = koiter_solved(COMM, 0.05)
        assert (solver.zone.cond.blocks is not None) == blocks
        runs.append(([s.newton.iterations for s in steps], problem.zeta.x.petsc_vec.copy()))
    (with_t, zeta), (without_t, reference) = runs
    assert with_t == without_t
    zeta.axpy(-1.0, reference)
    assert zeta.norm() <= 1e-9 * reference.norm()


@pytest.mark.mpi
def test_without_mumps_variable_blocks_the_same_steps_and_solution(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """No MatMumpsSetBlk in PETSc: MUMPS orders single variables instead of the nodes' blocks
    (ICNTL(15) stays 0), with the same Newton steps and solution."""
    runs = []
    for blocks in (True, False):
        if not blocks:
            without_petsc_function(monkeypatch, "MatMumpsSetBlk")
        problem, solver, steps = koiter_solved(COMM, 0.05)
        assert (solver.zone.cond.F_I.F.getMumpsIcntl(15) == 1) == blocks
        runs.append(([s.newton.iterations for s in steps], problem.zeta.x.petsc_vec.copy()))
    (with_blocks, reference), (without_blocks, zeta) = runs
    assert without_blocks == with_blocks
    zeta.axpy(-1.0, reference)
    assert zeta.norm() <= 1e-9 * reference.norm()


@pytest.mark.mpi
def test_serial_and_parallel_contact_solves_agree() -> None:
    """Koiter's model pushed onto the plane (the paper's problem, Newton with the contact
    zone; the penalty acts at Gauss points, where the contact is measured): the distributed
    solve gives the serial one's energies and smallest gap."""
    if COMM.size == 1:
        pytest.skip("compares a distributed solve with a serial one")
    out = []
    for comm in (COMM, MPI.COMM_SELF):
        problem = paper_koiter(comm, 0.05)
        solver = NewtonSolver(problem)
        continuation(problem, solver, [0.05**0.5, 0.05, 0.05**1.5])
        assert solver.timings["zone"] > 0  # the contact zone's condensation was used
        energies = problem.energies()
        out.append((energies, Postprocessor(problem).contact()["min_gap"]))
    (par, gap_par), (ser, gap_ser) = out
    assert ser["penalty_energy"] > 1e-6 * abs(ser["energy"])  # the obstacle is active
    for key in ("penalized_energy", "penalty_energy"):
        assert par[key] == pytest.approx(ser[key], rel=1e-8)
    assert gap_par == pytest.approx(gap_ser, rel=1e-8)
