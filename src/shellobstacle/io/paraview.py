"""ParaView output (ADIOS2 VTX ``.bp``) of a solved penalized problem (docs/model.md §1, §3, §7).

:func:`write_paraview` writes, into one folder:

* ``parameter_domain.bp``: the flat parameter mesh ω with P1 (vertex) fields ``zeta``
  (covariant components ζ_i), ``U`` (Cartesian displacement ζ_i a^i), ``position`` (θ),
  ``deformed_position`` (θ + U), ``gap`` (g(ζ)) and ``contact`` (1 on contact vertices).
* ``parameter_domain_p2.bp`` (only for P2 ζ): ``zeta``, ``U``, ``position`` and
  ``deformed_position`` in the P2 space of ζ (VTX needs one element per file).
* ``surface.bp``: the middle surface θ(ω) itself as a triangulated 3D surface (node
  coordinates θ(y)) with the same P1 fields. In ParaView: open it, then *Filters → Warp By
  Vector* with vector ``U`` (scale factor 1, or larger to exaggerate) shows the deformed
  shell; colour by ``gap`` or ``contact``.
* ``deformed_surface.bp``: the deformed middle surface (node coordinates θ(y) + U(y)),
  ready to view as is, with ``U``, ``gap`` and ``contact``.

ParaView (5.10 or newer) opens the ``.bp`` folders with its ADIOS2 VTX reader. The 3D
surface mesh shares the distributed 2D mesh's cells and nodes (:class:`SurfaceMesh`), so this
works on any number of MPI ranks.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from pathlib import Path

from mpi4py import MPI

import basix.ufl
import dolfinx
import dolfinx.cpp
import dolfinx.fem
import dolfinx.io
import dolfinx.mesh
import numpy as np
import ufl

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor

__all__ = ["SurfaceMesh", "surface_mesh", "write_paraview"]


def _check_affine(mesh: dolfinx.mesh.Mesh) -> None:
    if mesh.geometry.cmaps[0].degree != 1:
        raise NotImplementedError("ParaView surface output needs an affine (degree-1) mesh")


def _node_values(f: dolfinx.fem.Function) -> np.ndarray:
    """Values of a P1 Function at the geometry nodes (owned and ghost) of its affine mesh.

    Returns:
        Array of shape ``(num local nodes, block size)``.
    """
    V = f.function_space
    mesh = V.mesh
    bs = V.dofmap.index_map_bs
    geo = mesh.geometry.dofmaps[0]
    out = np.zeros((mesh.geometry.x.shape[0], bs))
    # in a P1 space on an affine mesh, cell dof k and geometry node k are the same vertex
    out[geo.ravel()] = f.x.array.reshape(-1, bs)[V.dofmap.list.ravel()]
    return out


class SurfaceMesh:
    """A 3D triangulated surface with the cells of an affine 2D mesh and given node coordinates.

    The surface shares the 2D mesh's topology and node numbering (a second geometry, with
    three coordinates per node, on the same cells and nodes), so nodal values of the 2D mesh
    transfer exactly (:meth:`transfer`) and nothing is partitioned or renumbered: building it
    costs no more than copying the coordinates.
    """

    def __init__(self, mesh2d: dolfinx.mesh.Mesh, coordinates: np.ndarray) -> None:
        _check_affine(mesh2d)
        geometry = mesh2d.geometry
        nodes = geometry.index_map()
        n_nodes = nodes.size_local + nodes.num_ghosts
        if len(coordinates) < n_nodes:
            raise ValueError(
                f"SurfaceMesh needs coordinates for all {n_nodes} local nodes (owned and "
                f"ghost) of the 2D mesh, got {len(coordinates)}"
            )
        x = np.ascontiguousarray(coordinates[:n_nodes, :3], dtype=np.float64)
        surface = dolfinx.cpp.mesh.Geometry_float64(
            nodes, geometry.dofmaps[0], geometry._cpp_object.cmaps[0], x,
            geometry.input_global_indices,
        )  # fmt: skip
        element = basix.ufl.element("Lagrange", mesh2d.basix_cell(), 1, shape=(3,))
        self.mesh = dolfinx.mesh.Mesh(
            dolfinx.cpp.mesh.Mesh_float64(mesh2d.comm, mesh2d.topology._cpp_object, surface),
            ufl.Mesh(element),
        )
        self.P1 = dolfinx.fem.functionspace(self.mesh, ("Lagrange", 1))
        self.P1v = dolfinx.fem.functionspace(self.mesh, ("Lagrange", 1, (3,)))

    def move(self, coordinates: np.ndarray) -> None:
        """Put every node at ``coordinates`` (array over the 2D mesh's local nodes).

        The cells stay: a VTX writer opened afterwards writes the moved surface (it writes
        the geometry as it is at each ``write``).
        """
        self.mesh.geometry.x[:, :3] = coordinates[: len(self.mesh.geometry.x), :3]

    def transfer(self, f: dolfinx.fem.Function) -> dolfinx.fem.Function:
        """The P1 Function ``f`` of the 2D mesh as a P1 Function on the surface (same name)."""
        bs = f.function_space.dofmap.index_map_bs
        space = self.P1 if bs == 1 else self.P1v
        out = dolfinx.fem.Function(space, name=f.name)
        if np.array_equal(f.function_space.dofmap.list, space.dofmap.list):
            out.x.array[:] = f.x.array  # the same cells, nodes and element: the same dofs
            return out
        values = _node_values(f)
        geo = self.mesh.geometry.dofmaps[0]
        out.x.array.reshape(-1, bs)[space.dofmap.list.ravel()] = values[geo.ravel()]
        return out


def surface_mesh(mesh2d: dolfinx.mesh.Mesh, coordinates: np.ndarray) -> dolfinx.mesh.Mesh:
    """A 3D surface mesh with the cells of ``mesh2d`` and node ``i`` at ``coordinates[i]``.

    Args:
        mesh2d: Affine triangle mesh of ω (distributed).
        coordinates: Array ``(num local geometry nodes, 3)`` (owned and ghost nodes), e.g.
            ``θ`` at ``mesh2d.geometry.x``.

    Returns:
        The mesh (geometric dimension 3), on the cells and nodes of ``mesh2d``.
    """
    return SurfaceMesh(mesh2d, coordinates).mesh


def _owned_cells(functions: list[dolfinx.fem.Function]) -> list[dolfinx.fem.Function]:
    """``functions`` (on one mesh) on the sub-mesh of each rank's owned cells (collective).

    VTX writes every local cell of a rank, ghost cells included, so a mesh ghosted for
    interior facets (Koiter's model, adaptivity) would hold those cells twice in the file.
    On the owned cells every cell appears once. The sub-mesh keeps each cell's vertex order,
    so the same element has the same cell dofs there: the values are copied, cell by cell.
    """
    if not functions:
        return functions
    mesh = functions[0].function_space.mesh
    tdim = mesh.topology.dim
    cells = mesh.topology.index_map(tdim)
    if mesh.comm.allreduce(cells.num_ghosts, op=MPI.MAX) == 0:
        return functions
    owned = np.arange(cells.size_local, dtype=np.int32)
    sub, entity_map, _, _ = dolfinx.mesh.create_submesh(mesh, tdim, owned)
    sub_map = sub.topology.index_map(tdim)
    sub_cells = np.arange(sub_map.size_local + sub_map.num_ghosts, dtype=np.int32)
    parent_cells = entity_map.sub_topology_to_topology(sub_cells, inverse=False)
    spaces: dict[int, dolfinx.fem.FunctionSpace] = {}
    out = []
    for f in functions:
        V = f.function_space
        if id(V) not in spaces:
            spaces[id(V)] = dolfinx.fem.functionspace(sub, V.ufl_element())
        g = dolfinx.fem.Function(spaces[id(V)], name=f.name)
        bs = V.dofmap.index_map_bs
        target, source = g.x.array.reshape(-1, bs), f.x.array.reshape(-1, bs)
        target[g.function_space.dofmap.list[sub_cells]] = source[V.dofmap.list[parent_cells]]
        out.append(g)
    return out


def _write(comm: MPI.Comm, path: Path, functions: list[dolfinx.fem.Function]) -> Path:
    """Write ``functions`` to the VTX folder ``path`` atomically, each cell once.

    All ranks write (collectively) into a hidden temporary ``.bp`` folder next to ``path``;
    once the writer is closed, rank 0 renames it into place, so ``path`` is either absent, the
    previous complete output, or the new complete output, never a partial one.
    """
    tag = comm.bcast(os.getpid() if comm.rank == 0 else None, root=0)
    tmp = path.with_name(f".{path.stem}.{tag}.tmp.bp")
    if comm.rank == 0:  # a leftover of an interrupted run with the same process id
        shutil.rmtree(tmp, ignore_errors=True)
    comm.barrier()
    functions = _owned_cells(functions)
    try:
        with dolfinx.io.VTXWriter(comm, tmp, functions, engine="BP4") as writer:
            writer.write(0.0)
    except BaseException:
        if comm.rank == 0:  # no barrier here: the other ranks may not have failed
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    comm.barrier()  # every rank has closed the writer: the folder is complete
    error = None
    if comm.rank == 0:
        try:
            _replace_dir(tmp, path)
        except OSError as err:
            shutil.rmtree(tmp, ignore_errors=True)
            error = f"cannot move {tmp} to {path}: {err}"
    error = comm.bcast(error, root=0)
    if error:
        raise OSError(error)
    return path


def _replace_dir(src: Path, dst: Path) -> None:
    """Rename the folder ``src`` to ``dst``, replacing an existing ``dst`` (file or folder)."""
    if not dst.exists() and not dst.is_symlink():
        os.replace(src, dst)
        return
    old = dst.with_name(f".{dst.name}.{os.getpid()}.old")
    os.replace(dst, old)  # a folder cannot be renamed onto a non-empty folder: move it aside
    try:
        os.replace(src, dst)
    except OSError:
        os.replace(old, dst)
        raise
    if old.is_dir() and not old.is_symlink():
        shutil.rmtree(old, ignore_errors=True)
    else:
        old.unlink(missing_ok=True)


def write_paraview(
    problem: PenalizedProblem,
    post: Postprocessor,
    folder: Path,
    extra: Sequence[dolfinx.fem.Function] = (),
) -> list[Path]:
    """Write the current solution ``problem.zeta`` for ParaView (see the module docstring).

    Args:
        problem: The solved problem.
        post: Its :class:`~shellobstacle.post.contact.Postprocessor`.
        folder: Output folder (created if needed).
        extra: More scalar fields in the nodes' space (e.g. the contact pressure of the exact
            solver), written at the vertices with the gap and the contact indicator.

    Returns:
        The paths of the written ``.bp`` folders (the same list on every rank).
    """
    folder = Path(folder)
    comm = problem.mesh.comm
    if comm.rank == 0:
        folder.mkdir(parents=True, exist_ok=True)
    comm.barrier()

    # fields in the space of ζ: ζ, U, θ, θ + U (θ interpolated exactly at the dofs)
    V = problem.V
    U = post.cartesian_displacement()
    points = V.tabulate_dof_coordinates()
    theta = np.column_stack(problem.shell.surface.theta_numpy(points))
    position = dolfinx.fem.Function(V, name="position")
    position.x.array[:] = theta.ravel()
    deformed = dolfinx.fem.Function(V, name="deformed_position")
    deformed.x.array[:] = position.x.array + U.x.array
    zeta = dolfinx.fem.Function(V, name="zeta")
    zeta.x.array[:] = problem.zeta.x.array
    vectors = [zeta, U, position, deformed]

    gap = post.nodal_gap()
    contact = post.indicator()
    paths: list[Path] = []
    if problem.disc.degree == 1:
        p1_vectors = vectors
    else:
        paths.append(_write(comm, folder / "parameter_domain_p2.bp", vectors))
        W = dolfinx.fem.functionspace(problem.mesh, ("Lagrange", 1, (3,)))
        p1_vectors = []
        for f in vectors:
            g = dolfinx.fem.Function(W, name=f.name)
            g.interpolate(f)  # vertex values of the P2 field
            p1_vectors.append(g)
        S = dolfinx.fem.functionspace(problem.mesh, ("Lagrange", 1))
        extra = [_vertex_values(f, S) for f in extra]
    flat = [*p1_vectors, gap, contact, *extra]
    paths.insert(0, _write(comm, folder / "parameter_domain.bp", flat))

    # the reference and the deformed middle surface as 3D meshes
    pos_nodes = _node_values(p1_vectors[2])
    disp_nodes = _node_values(p1_vectors[1])
    reference = SurfaceMesh(problem.mesh, pos_nodes)
    surface_fields = [
        reference.transfer(f) for f in (p1_vectors[0], p1_vectors[1], gap, contact, *extra)
    ]
    paths.append(_write(comm, folder / "surface.bp", surface_fields))
    reference.move(pos_nodes + disp_nodes)  # the same cells: no second mesh to build
    deformed_fields = [reference.transfer(f) for f in (p1_vectors[1], gap, contact)]
    paths.append(_write(comm, folder / "deformed_surface.bp", deformed_fields))
    return paths


def _vertex_values(f: dolfinx.fem.Function, S: dolfinx.fem.FunctionSpace) -> dolfinx.fem.Function:
    """``f`` at the vertices, as a Function on the scalar P1 space ``S`` (same name)."""
    g = dolfinx.fem.Function(S, name=f.name)
    g.interpolate(f)
    return g
