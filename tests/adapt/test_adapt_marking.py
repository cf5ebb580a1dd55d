"""Dörfler marking and the free-boundary cells (shellobstacle.adapt.marking)."""

# isort: split
from mpi4py import MPI

import dolfinx
import numpy as np
import pytest

from shellobstacle.adapt.marking import (
    dorfler_threshold,
    free_boundary_cells,
    mark_dorfler,
    marked_edges,
)
from shellobstacle.mesh.refinement import refine_marked

COMM = MPI.COMM_WORLD


def _local_share(values: np.ndarray) -> np.ndarray:
    """This rank's slice of a global array (contiguous blocks)."""
    bounds = np.linspace(0, values.size, COMM.size + 1).astype(int)
    return values[bounds[COMM.rank] : bounds[COMM.rank + 1]]


@pytest.mark.mpi
@pytest.mark.parametrize("theta", [0.1, 0.5, 0.9, 1.0])
def test_dorfler_marks_a_minimal_set_holding_the_fraction(theta: float) -> None:
    """The marked cells hold at least θ of Σ η², and without the smallest marked one they
    would not: the set is minimal (the values are distinct). The same set on any number of
    ranks."""
    rng = np.random.default_rng(7)
    eta2 = rng.lognormal(size=1000)
    mine = _local_share(eta2)
    marked = mark_dorfler(mine, theta, COMM)
    held = COMM.allreduce(float(mine[marked].sum()), op=MPI.SUM)
    count = COMM.allreduce(marked.size, op=MPI.SUM)
    smallest = COMM.allreduce(float(mine[marked].min(initial=np.inf)), op=MPI.MIN)
    total = eta2.sum()
    assert held >= theta * total * (1 - 1e-12)
    assert held - smallest < theta * total
    # the k largest values, as a serial sort finds them
    k = np.searchsorted(np.cumsum(np.sort(eta2)[::-1]), theta * total * (1 - 1e-14)) + 1
    assert count == k
    assert dorfler_threshold(mine, theta, COMM) == np.sort(eta2)[::-1][k - 1]


def test_dorfler_marks_round_off_ties_together() -> None:
    """Indicators equal up to round-off (cells mirrored by a symmetry) are marked together."""
    eta2 = np.array([4.0, 1.0, 1.0 * (1 + 1e-12), 1.0 * (1 - 1e-12), 0.5])
    marked = mark_dorfler(eta2, 0.6, MPI.COMM_SELF)
    assert sorted(marked) == [0, 1, 2, 3]


def test_dorfler_edge_cases() -> None:
    assert mark_dorfler(np.zeros(5), 0.5, MPI.COMM_SELF).size == 0
    assert mark_dorfler(np.array([0.0, 1.0, 2.0]), 1.0, MPI.COMM_SELF).tolist() == [1, 2]
    for theta in (0.0, -0.1, 1.5):
        with pytest.raises(ValueError, match="fraction"):
            mark_dorfler(np.ones(3), theta, MPI.COMM_SELF)


@pytest.mark.mpi
def test_free_boundary_cells_and_refinement() -> None:
    """A contact set {y1 < 0.3} on the unit square: the cells with vertices on both sides are
    the free-boundary cells; refining them bisects their edges and nothing far away."""
    mesh = dolfinx.mesh.create_unit_square(
        COMM, 10, 10, ghost_mode=dolfinx.mesh.GhostMode.shared_facet
    )
    P1 = dolfinx.fem.functionspace(mesh, ("Lagrange", 1))
    x = P1.tabulate_dof_coordinates()
    contact = x[:, 0] < 0.35
    cells = free_boundary_cells(mesh, contact)
    mid = dolfinx.mesh.compute_midpoints(mesh, 2, cells)
    assert np.all(np.abs(mid[:, 0] - 0.35) < 0.1)
    assert COMM.allreduce(cells.size, op=MPI.SUM) == 20  # one column of 10 squares
    fine = refine_marked(mesh, marked_edges(mesh, cells))
    before = mesh.topology.index_map(2).size_global
    after = fine.topology.index_map(2).size_global
    assert before < after < 4 * before
    assert fine.geometry.dim == 2
