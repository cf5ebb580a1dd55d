"""Refinement of triangle meshes: uniform ("red", nested meshes with h halved exactly) and
local (Plaza's edge bisection of marked edges, for adaptivity)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mpi4py import MPI  # (loads MPI before dolfinx)

import dolfinx
import dolfinx.graph
import dolfinx.mesh
import numpy as np
import ufl

from shellobstacle.mesh.facet_tags import inherit
from shellobstacle.mesh.hierarchy import record
from shellobstacle.mesh.measures import boundary_facets

if TYPE_CHECKING:
    from shellobstacle.mesh.domains import DomainSpec

__all__ = ["keep_ranks", "prepare", "red_refinement", "refine_marked", "refine_uniformly"]


def prepare(mesh: dolfinx.mesh.Mesh) -> None:
    """Create the edges and facet-cell connectivity used by refinement and boundary search."""
    tdim = mesh.topology.dim
    mesh.topology.create_entities(1)
    mesh.topology.create_connectivity(tdim - 1, tdim)


def refine_uniformly(mesh: dolfinx.mesh.Mesh, ghosted: bool = False) -> dolfinx.mesh.Mesh:
    """Refine once uniformly ("red"): every edge is bisected, each triangle split into four.

    The four children are similar to their parent, so the mesh size halves exactly and the
    meshes are nested: the P1 space of ``mesh`` is a subspace of the refined one. (Plaza
    refinement, ``dolfinx.mesh.refine``, also bisects every edge but cuts along a median,
    so its children are not similar and h does not halve.) The children stay on their
    parent's rank (nothing is repartitioned); the refined mesh is a 2D mesh
    (``geometry.dim == 2``).

    Args:
        mesh: Triangle mesh.
        ghosted: in parallel, give the refined mesh one layer of facet-sharing ghost cells
            (interior-facet integrals across ranks need them).

    Returns:
        The refined mesh, with edges and facet-cell connectivity created; it remembers
        ``mesh`` (:func:`red_refinement`).
    """
    fine = red_refinement(mesh, ghosted=ghosted)
    prepare(fine)
    return fine


def refine_marked(mesh: dolfinx.mesh.Mesh, edges: np.ndarray) -> dolfinx.mesh.Mesh:
    """Refine the cells around the marked ``edges`` (local indices) by Plaza's algorithm
    (``dolfinx.mesh.refine``): each cell with a marked edge is bisected through its longest
    edge, and the edges it must bisect to stay conforming are added, so the refined mesh is
    conforming and nested (the P1 space of ``mesh`` is a subspace of the refined one) and its
    angles stay bounded below over repeated refinements. Children stay on their parent's
    rank, the ghost layer of a ghosted mesh is rebuilt; new boundary nodes are the midpoints
    of boundary edges (the polygon of the first mesh is kept).

    Returns:
        The refined mesh, with edges and facet-cell connectivity created.
    """
    mesh.topology.create_entities(1)
    fine, _, _ = dolfinx.mesh.refine(
        mesh, np.asarray(edges, dtype=np.int32), option=dolfinx.mesh.RefinementOption.parent_cell
    )
    prepare(fine)
    inherit(fine, mesh)
    return fine


def red_refinement(
    mesh: dolfinx.mesh.Mesh, curve: DomainSpec | None = None, ghosted: bool = False
) -> dolfinx.mesh.Mesh:
    """DOLFINx's uniform refinement with a 2D geometry; ``curve``: a disk or ellipse whose
    boundary the new boundary nodes are moved onto (radially from its centre); ``ghosted``:
    in parallel, with facet-sharing ghost cells (:func:`keep_ranks`).

    The children stay on their parent's rank, so the refined mesh remembers ``mesh`` and its
    coarser meshes (the levels of geometric multigrid and nested iteration,
    :mod:`~shellobstacle.mesh.hierarchy`, whose interpolation finds each fine node in a
    coarse cell of its own rank).

    DOLFINx 0.11's ``uniform_refine`` returns a geometry with three coordinates per node: the
    refined topology gets a new 2D geometry on the same nodes (no ``create_mesh``, whose cell
    cell reordering alone is a large part of a refinement's time).
    """
    mesh.topology.create_entities(1)
    partitioner = None
    if ghosted and mesh.comm.size > 1:
        partitioner = dolfinx.mesh.create_cell_partitioner(
            keep_ranks, dolfinx.mesh.GhostMode.shared_facet, 2
        )
    fine = dolfinx.mesh.uniform_refine(mesh, partitioner)
    geometry = fine.geometry
    x = np.ascontiguousarray(geometry.x[:, :2])
    if curve is not None and curve.kind in ("disk", "ellipse"):
        onto_curve(fine, x, curve)
    planar = dolfinx.cpp.mesh.Geometry_float64(
        geometry.index_map(), geometry.dofmaps[0], geometry._cpp_object.cmaps[0], x,
        geometry.input_global_indices,
    )  # fmt: skip
    refined = dolfinx.mesh.Mesh(
        dolfinx.cpp.mesh.Mesh_float64(mesh.comm, fine.topology._cpp_object, planar),
        ufl.Mesh(mesh.ufl_domain().ufl_coordinate_element()),
    )
    record(refined, mesh)
    inherit(refined, mesh)
    return refined


def keep_ranks(
    comm: MPI.Comm, nparts: int, graph: dolfinx.cpp.graph.AdjacencyList_int64, ghosting: bool
) -> dolfinx.cpp.graph.AdjacencyList_int32:
    """A graph partitioner (``dolfinx.mesh.create_cell_partitioner``) that leaves every cell
    on its rank and, with ``ghosting``, ghosts it on the ranks of its neighbours in ``graph``
    (the cells' facet-dual graph: a layer of facet-sharing ghost cells).

    DOLFINx's partitioners balance a graph anew: after a refinement the children would leave
    their parent's rank and the levels could not be interpolated rank by rank. The graph's
    nodes are this rank's cells, numbered globally in rank order; a cell's destinations are its
    rank, then its ghosts' ranks.
    """
    n = graph.num_nodes
    offsets, links = np.asarray(graph.offsets), np.asarray(graph.array)
    starts = np.cumsum(comm.allgather(n)) - n  # each rank's first global cell
    node = np.repeat(np.arange(n), np.diff(offsets))
    owner = np.searchsorted(starts, links, side="right") - 1
    other = (owner != comm.rank) & ghosting  # (no ghosts: only the owner)
    pairs = np.unique(np.stack([node[other], owner[other]], axis=1), axis=0).reshape(-1, 2)
    counts = 1 + np.bincount(pairs[:, 0], minlength=n)
    dest_offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    dest = np.full(dest_offsets[-1], comm.rank, dtype=np.int32)
    first = np.searchsorted(pairs[:, 0], pairs[:, 0])  # each pair's rank among its node's
    dest[dest_offsets[pairs[:, 0]] + 1 + np.arange(len(pairs)) - first] = pairs[:, 1]
    return dolfinx.graph.adjacencylist(dest, dest_offsets)._cpp_object


def onto_curve(mesh: dolfinx.mesh.Mesh, x: np.ndarray, spec: DomainSpec) -> None:
    """Move the nodes ``x`` of ``mesh``'s boundary facets that are off the curve of the disk
    or ellipse ``spec`` radially onto it, in place (a chord's midpoint is ``O(h²)`` inside;
    the nodes already on the curve, to 1e-12, are left bitwise as they are).

    Each rank moves the nodes of its own boundary facets: a new boundary node is the midpoint
    of a boundary edge, and all the cells through it are children of the one cell that had
    that edge, on that cell's rank (``uniform_refine`` keeps children on their parent's
    rank); a rank that holds such cells as ghosts moves its copies of the node alike.
    """
    facets = boundary_facets(mesh)
    nodes = np.unique(dolfinx.mesh.entities_to_geometry(mesh, mesh.topology.dim - 1, facets))
    c = np.asarray(spec.center, dtype=float)
    a, b = (spec.radius, spec.radius) if spec.kind == "disk" else spec.semi_axes
    d = x[nodes] - c
    s = np.hypot(d[:, 0] / a, d[:, 1] / b)
    off = np.abs(s - 1.0) > 1e-12
    x[nodes[off]] = c + d[off] / s[off, None]
