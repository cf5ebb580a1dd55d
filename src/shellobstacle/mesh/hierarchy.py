"""The coarser meshes a mesh was refined from, and the interpolation between their spaces.

A mesh made by uniform refinement (:func:`~shellobstacle.mesh.refinement.red_refinement`, under
:func:`~shellobstacle.mesh.meshing.create_mesh` and the experiments' nested meshes) remembers
the meshes it came from, coarsest first, while it lives: :func:`record` stores them and
:func:`coarser_meshes` gives them back (a weak map from the fine mesh; nothing is copied). Their
Lagrange spaces are nested up to the boundary nodes moved onto a curve, and
:func:`prolongation` is the matrix that interpolates a coarse function at the fine space's
nodes: the transfer of geometric multigrid.
"""

from __future__ import annotations

import weakref

from mpi4py import MPI  # noqa: F401  (loads MPI before dolfinx)
from petsc4py import PETSc

import dolfinx
import dolfinx.geometry
import numpy as np

__all__ = ["coarser_meshes", "prolongation", "record"]

#: fine mesh → the meshes it was refined from, coarsest first
_LEVELS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: fine mesh → coarse mesh → (points, their host cells, reference coordinates): :func:`_located`
_LOCATED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def record(fine: dolfinx.mesh.Mesh, coarse: dolfinx.mesh.Mesh) -> None:
    """``fine`` was refined from ``coarse``: it remembers ``coarse`` and its coarser meshes."""
    _LEVELS[fine] = [*_LEVELS.get(coarse, []), coarse]


def coarser_meshes(mesh: dolfinx.mesh.Mesh) -> list[dolfinx.mesh.Mesh]:
    """The meshes ``mesh`` was refined from, coarsest first (empty if none is known)."""
    return list(_LEVELS.get(mesh, []))


def prolongation(Vc: dolfinx.fem.FunctionSpace, Vf: dolfinx.fem.FunctionSpace) -> PETSc.Mat:
    """The matrix ``P`` with ``u_f = P u_c``: ``u_c ∈ Vc`` interpolated at the nodes of ``Vf``.

    Both spaces are Lagrange spaces of the same (possibly blocked) element on affine triangle
    meshes. Each owned fine node is located in a cell of the coarse mesh on the same rank
    (uniform refinement keeps children on their parent's rank); a node outside every coarse
    cell (a boundary node moved onto a curve) is extrapolated from the closest cell. The rows
    are the fine space's owned dofs, the columns the coarse space's, in PETSc's layout of
    each space's vectors; each component interpolates itself (``bs`` entries per node).

    Raises:
        ValueError: if the elements differ.
    """
    if Vc.ufl_element() != Vf.ufl_element():
        raise ValueError("prolongation needs the same element on both meshes")
    coarse, bs = Vc.mesh, Vf.dofmap.index_map_bs
    n_fine = Vf.dofmap.index_map.size_local
    x = Vf.tabulate_dof_coordinates()[:n_fine]
    cells, X = _located(coarse, Vf.mesh, x)
    element = Vc.ufl_element().basix_element
    weights = element.tabulate(0, X)[0, :, :, 0]  # (fine nodes, coarse cell dofs)
    imap = Vc.dofmap.index_map
    columns = imap.local_to_global(Vc.dofmap.list[cells].ravel()).reshape(weights.shape)
    # the scalar row bs·i + c holds the weights of node i at the scalar columns bs·J + c
    node, k = np.nonzero(np.abs(weights) > 1e-12)  # (row-major: sorted by node)
    comp = np.arange(bs)
    rows = (bs * node[:, None] + comp).ravel()
    indices = (bs * columns[node, k][:, None] + comp).ravel()
    values = np.repeat(weights[node, k], bs)
    order = np.argsort(rows, kind="stable")
    indices, values = indices[order].astype(PETSc.IntType), values[order]
    counts = np.bincount(rows, minlength=bs * n_fine)
    indptr = np.concatenate([[0], np.cumsum(counts)]).astype(PETSc.IntType)
    sizes = ((bs * n_fine, PETSc.DETERMINE), (bs * imap.size_local, PETSc.DETERMINE))
    P = PETSc.Mat().createAIJ(sizes, bsize=bs, csr=(indptr, indices, values), comm=coarse.comm)
    P.assemble()
    return P


def _located(
    coarse: dolfinx.mesh.Mesh, fine: dolfinx.mesh.Mesh, x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The host cells in ``coarse`` of the fine mesh's points ``x`` and their reference
    coordinates there, remembered while both meshes live: nested iteration and the multigrid
    of each of its levels interpolate between the same meshes (the points are compared, so a
    different set of points is located anew)."""
    known = _LOCATED.setdefault(fine, weakref.WeakKeyDictionary()).get(coarse)
    if known is not None and np.array_equal(known[0], x):
        return known[1], known[2]
    cells = _host_cells(coarse, x)
    X = _reference(coarse, cells, x)
    _LOCATED[fine][coarse] = (x, cells, X)
    return cells, X


def _host_cells(mesh: dolfinx.mesh.Mesh, x: np.ndarray) -> np.ndarray:
    """A local cell of ``mesh`` containing each point of ``x``: of the cells whose bounding
    box holds the point, the one whose smallest barycentric coordinate there is largest (the
    closest cell for a point in no box)."""
    tdim = mesh.topology.dim
    cell_map = mesh.topology.index_map(tdim)
    cells = np.arange(cell_map.size_local + cell_map.num_ghosts, dtype=np.int32)
    tree = dolfinx.geometry.bb_tree(mesh, tdim, entities=cells)
    points = np.ascontiguousarray(x, dtype=mesh.geometry.x.dtype)
    boxes = dolfinx.geometry.compute_collisions_points(tree, points)
    counts = np.diff(boxes.offsets)
    point, cell = np.repeat(np.arange(len(points)), counts), boxes.array
    origin, inverse = _affine_inverses(mesh, cells)  # (per cell, not per candidate)
    X = np.einsum("nij,nj->ni", inverse[cell], points[point, :2] - origin[cell])
    score = np.minimum(np.minimum(X[:, 0], X[:, 1]), 1.0 - X[:, 0] - X[:, 1])
    best = np.lexsort((-score, point))  # per point, the largest score first
    first = np.flatnonzero(np.r_[True, point[best][1:] != point[best][:-1]]) if best.size else best
    host = np.full(len(points), -1, dtype=np.int32)
    host[point[best[first]]] = cell[best[first]]
    outside = host < 0
    if outside.any():
        midpoints = dolfinx.geometry.create_midpoint_tree(mesh, tdim, cells)
        host[outside] = dolfinx.geometry.compute_closest_entity(
            tree, midpoints, mesh, points[outside]
        )
    return host


def _affine_inverses(mesh: dolfinx.mesh.Mesh, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The first node ``x_0`` and the inverse Jacobian ``J⁻¹`` of each affine triangle of
    ``cells``: the reference coordinates of a point ``x`` are ``J⁻¹ (x − x_0)``."""
    nodes = mesh.geometry.x[mesh.geometry.dofmaps[0][cells]][:, :, :2]
    a, c = (nodes[:, 1] - nodes[:, 0]).T  # J = [[a, b], [c, d]]: its columns the edges
    b, d = (nodes[:, 2] - nodes[:, 0]).T
    det = a * d - b * c
    inverse = np.stack([np.stack([d, -b], axis=1), np.stack([-c, a], axis=1)], axis=1)
    return nodes[:, 0], inverse / det[:, None, None]


def _reference(mesh: dolfinx.mesh.Mesh, cells: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The reference coordinates ``X`` of the points ``x`` in the affine triangles ``cells``:
    ``x = x_0 + J X``."""
    nodes = mesh.geometry.x[mesh.geometry.dofmaps[0][cells]][:, :, :2]
    J = np.stack([nodes[:, 1] - nodes[:, 0], nodes[:, 2] - nodes[:, 0]], axis=2)
    return np.linalg.solve(J, (x[:, :2] - nodes[:, 0])[:, :, None])[:, :, 0]
