"""Global measures of a distributed triangle mesh: size, cell count, area, boundary."""

from __future__ import annotations

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.mesh
import numpy as np
import ufl

__all__ = ["boundary_facets", "domain_area", "mesh_size", "mesh_size_min", "num_cells_global"]


def _cell_diameters(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    """Diameters (longest edges) of the locally owned cells."""
    tdim = mesh.topology.dim
    owned = np.arange(mesh.topology.index_map(tdim).size_local, dtype=np.int32)
    return mesh.h(tdim, owned)


def mesh_size(mesh: dolfinx.mesh.Mesh) -> float:
    """Largest cell diameter (longest triangle edge) of the whole distributed mesh.

    Args:
        mesh: Triangle mesh.

    Returns:
        The global mesh size h.
    """
    local = _cell_diameters(mesh)
    return mesh.comm.allreduce(float(local.max(initial=0.0)), op=MPI.MAX)


def mesh_size_min(mesh: dolfinx.mesh.Mesh) -> float:
    """Smallest cell diameter of the whole distributed mesh.

    Args:
        mesh: Triangle mesh.

    Returns:
        The global minimum of the cell diameters.
    """
    local = _cell_diameters(mesh)
    return mesh.comm.allreduce(float(local.min(initial=np.inf)), op=MPI.MIN)


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
