"""Global measures of a distributed triangle mesh: size, cell count, area, boundary.

The mesh sizes (:func:`mesh_size`, :func:`mesh_size_min`) are collectives computed once per
mesh and kept with it (a mesh's nodes do not move): later calls on the same mesh reduce
nothing.
"""

from __future__ import annotations

import weakref

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.mesh
import numpy as np
import ufl

__all__ = ["boundary_facets", "domain_area", "mesh_size", "mesh_size_min", "num_cells_global"]


#: mesh → its sizes computed so far ("max", "min": the global cell diameters), while it lives
_SIZES: weakref.WeakKeyDictionary[dolfinx.mesh.Mesh, dict[str, float]] = weakref.WeakKeyDictionary()


def _cell_diameters(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    """Diameters (longest edges) of the locally owned cells."""
    tdim = mesh.topology.dim
    owned = np.arange(mesh.topology.index_map(tdim).size_local, dtype=np.int32)
    return mesh.h(tdim, owned)


def mesh_size(mesh: dolfinx.mesh.Mesh) -> float:
    """Largest cell diameter (longest triangle edge) of the whole distributed mesh.

    Collective on the first call for ``mesh``; later calls return the kept value.

    Args:
        mesh: Triangle mesh.

    Returns:
        The global mesh size h.
    """
    sizes = _SIZES.setdefault(mesh, {})
    if "max" not in sizes:
        local = _cell_diameters(mesh)
        sizes["max"] = mesh.comm.allreduce(float(local.max(initial=0.0)), op=MPI.MAX)
    return sizes["max"]


def mesh_size_min(mesh: dolfinx.mesh.Mesh) -> float:
    """Smallest cell diameter of the whole distributed mesh.

    Collective on the first call for ``mesh``; later calls return the kept value.

    Args:
        mesh: Triangle mesh.

    Returns:
        The global minimum of the cell diameters.
    """
    sizes = _SIZES.setdefault(mesh, {})
    if "min" not in sizes:
        local = _cell_diameters(mesh)
        sizes["min"] = mesh.comm.allreduce(float(local.min(initial=np.inf)), op=MPI.MIN)
    return sizes["min"]


def num_cells_global(mesh: dolfinx.mesh.Mesh) -> int:
    """Number of cells of the whole distributed mesh (ghosts not counted).

    Args:
        mesh: Mesh.

    Returns:
        The global number of cells.
    """
    return int(mesh.topology.index_map(mesh.topology.dim).size_global)


def domain_area(mesh: dolfinx.mesh.Mesh) -> float:
    """Area of the meshed domain, ∫ 1 dx.

    Args:
        mesh: Mesh.

    Returns:
        The global area.
    """
    one = dolfinx.fem.Constant(mesh, dolfinx.default_scalar_type(1.0))
    local = dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * ufl.dx(domain=mesh)))
    return float(mesh.comm.allreduce(local, op=MPI.SUM))


def boundary_facets(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    """Local indices of the exterior (boundary) facets on this rank.

    Args:
        mesh: Mesh.

    Returns:
        Sorted int32 array of local facet indices (owned and ghost) on ∂ω.
    """
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    return dolfinx.mesh.exterior_facet_indices(mesh.topology)
