"""The hybrid bending form of Koiter's model: its blocks, its Schur complement, the interior
factorization through the block matrix, and serial against distributed contact solves.

Its convergence (energy-norm rates on manufactured solutions, the clamped plate, the
membrane limit) is tested with the interior-penalty form's in test_koiter.py.
"""

from __future__ import annotations

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import numpy as np
import pytest
import ufl

from shellobstacle.domains import DomainSpec
from shellobstacle.hybrid_bending import facet_normals
from shellobstacle.meshing import create_mesh
from shellobstacle.model import Discretization, Load, Material, Obstacle, Shell
from shellobstacle.post.contact import Postprocessor
from shellobstacle.problem import PenalizedProblem
from shellobstacle.solvers.base import direct_solver
from shellobstacle.solvers.continuation import continuation
from shellobstacle.solvers.newton import NewtonSolver
from shellobstacle.solvers.zone.interior import InteriorFactor
from shellobstacle.surface import Surface

COMM = MPI.COMM_WORLD
PAPER_LOAD = "Piecewise((-(2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.06), (0, True))"


def paper_koiter(comm: MPI.Comm, h: float, bending: str = "hybrid") -> PenalizedProblem:
    shell = Shell(
        Surface.spherical_cap(1.0, 0.85),
        Material(1e-3, 0.4, 0.012),
        Load(("0", "0", PAPER_LOAD)),
        Obstacle(),
        "koiter",
    )
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


@pytest.mark.mpi
def test_interior_factor_through_the_block_matrix() -> None:
    """Solves with ``K_II`` and the entries of ``K_II⁻¹`` are the same from the block matrix
    ``H_I`` as from ``K_II`` itself (serially and on several ranks)."""
    problem = paper_koiter(COMM, 0.1)
    K = problem.stiffness()
    n = K.getSize()[0]
    Z = np.arange(n // 3, n // 2, dtype=PETSc.IntType)  # a band of dofs as the zone
    r0, r1 = K.getOwnershipRange()
    owned = np.arange(r0, r1, dtype=PETSc.IntType)
    isI = PETSc.IS().createGeneral(owned[~np.isin(owned, Z)], comm=K.getComm())
    plain = InteriorFactor(K, isI, "cholesky")
    hybrid = InteriorFactor(K, isI, "cholesky", problem.condensed)
    assert hybrid.size == plain.size == n - Z.size
    b = PETSc.Vec().createMPI((isI.getLocalSize(), None), comm=K.getComm())
    b.setRandom()
    x, y = b.duplicate(), b.duplicate()
    plain.solve(b, x)
    hybrid.solve(b, y)
    y.axpy(-1.0, x)
    assert y.norm() <= 1e-9 * x.norm()
    rows = np.unique(np.linspace(0, plain.size - 1, 40).astype(PETSc.IntType))
    a, c = plain.inverse_block(rows), hybrid.inverse_block(rows)
    if COMM.rank == 0:
        assert np.abs(a - c).max() <= 1e-9 * np.abs(a).max()
    for obj in (plain, hybrid, b, x, y, isI):
        obj.destroy()


@pytest.mark.mpi
def test_serial_and_parallel_contact_solves_agree() -> None:
    """Koiter's model pushed onto the plane (the paper's problem, Newton with the contact
    zone; the penalty acts at Gauss points, the vertices stay above the plane on this coarse
    mesh): the distributed solve gives the serial one's energies and smallest vertex gap."""
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
