"""Which cells to refine: Dörfler's bulk criterion and the discrete free boundary.

Dörfler (1996) marks a set ``M`` of least cardinality with ``Σ_{T∈M} η_T² ≥ θ Σ_T η_T²``:
the cells with the largest indicators first. The threshold is computed from every rank's
indicators sorted together, so the marked set does not depend on how the mesh is
distributed; cells whose indicator equals the threshold to a relative ``tie`` are marked too
(cells mirrored by a symmetry of the mesh have indicators equal up to round-off, which
differs between runs on different numbers of ranks).
"""

from __future__ import annotations

from mpi4py import MPI

import dolfinx
import numpy as np

__all__ = ["dorfler_threshold", "free_boundary_cells", "mark_dorfler", "marked_edges"]

#: relative tolerance below the threshold that still marks a cell (round-off ties)
TIE = 1e-6


def dorfler_threshold(eta2: np.ndarray, theta: float, comm: MPI.Comm) -> float:
    """The smallest ``η_T²`` of Dörfler's minimal set for the fraction ``theta`` (collective).

    Args:
        eta2: the squared indicators of this rank's owned cells.
        theta: the bulk fraction ``θ ∈ (0, 1]``.
        comm: the mesh's communicator.

    Returns:
        ``t`` such that the cells with ``η_T² ≥ t`` hold at least ``θ Σ η_T²``, the largest
        such value (the same on every rank); ``inf`` when every indicator vanishes.
    """
    if not 0.0 < theta <= 1.0:
        raise ValueError(f"the marking fraction must be in (0, 1], got {theta}")
    gathered = comm.gather(np.asarray(eta2, dtype=float), root=0)
    threshold = None
    if comm.rank == 0:
        values = np.sort(np.concatenate(gathered))[::-1]
        total = values.sum()
        if total > 0.0:
            cumulative = np.cumsum(values)
            k = int(np.searchsorted(cumulative, theta * total * (1.0 - 1e-14)))
            threshold = float(values[min(k, values.size - 1)])
        else:
            threshold = float("inf")
    return float(comm.bcast(threshold, root=0))


def mark_dorfler(eta2: np.ndarray, theta: float, comm: MPI.Comm, tie: float = TIE) -> np.ndarray:
    """Dörfler's marked set: the owned cells (local indices) with ``η_T² ≥ (1 − tie) t``,
    ``t`` from :func:`dorfler_threshold` (collective)."""
    t = dorfler_threshold(eta2, theta, comm)
    if not np.isfinite(t):
        return np.zeros(0, dtype=np.int32)
    return np.flatnonzero(np.asarray(eta2) >= (1.0 - tie) * t).astype(np.int32)


def free_boundary_cells(mesh: dolfinx.mesh.Mesh, contact: np.ndarray) -> np.ndarray:
    """The owned cells whose vertices are partly in contact and partly not: the cells the
    discrete free boundary (the edge of the contact set) runs through.

    Args:
        mesh: the mesh.
        contact: a flag per local vertex dof of the P1 space on ``mesh`` (owned and ghost),
            e.g. the contact indicator of :class:`~shellobstacle.post.contact.Postprocessor`.
    """
    P1 = dolfinx.fem.functionspace(mesh, ("Lagrange", 1))
    owned = mesh.topology.index_map(mesh.topology.dim).size_local
    flags = np.asarray(contact, dtype=bool)[P1.dofmap.list[:owned]]
    mixed = flags.any(axis=1) & ~flags.all(axis=1)
    return np.flatnonzero(mixed).astype(np.int32)


def marked_edges(mesh: dolfinx.mesh.Mesh, cells: np.ndarray) -> np.ndarray:
    """The edges of ``cells`` (local indices), the input of :func:`dolfinx.mesh.refine`."""
    mesh.topology.create_entities(1)
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim, 1)
    return dolfinx.mesh.compute_incident_entities(
        mesh.topology, np.asarray(cells, dtype=np.int32), tdim, 1
    )
