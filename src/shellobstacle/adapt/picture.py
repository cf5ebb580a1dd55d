"""A picture of an adapted mesh with the boundary of the contact set (rank 0 draws)."""

from __future__ import annotations

from pathlib import Path

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx)

import dolfinx
import numpy as np

__all__ = ["plot_adapted_mesh"]


def _gathered(
    mesh: dolfinx.mesh.Mesh, values: dolfinx.fem.Function
) -> tuple[np.ndarray, np.ndarray] | None:
    """The owned cells' vertex coordinates ``(cells, 3, 2)`` and the P1 ``values`` there, on
    rank 0 (None elsewhere)."""
    tdim = mesh.topology.dim
    owned = mesh.topology.index_map(tdim).size_local
    nodes = mesh.geometry.dofmaps[0][:owned]
    xy = mesh.geometry.x[nodes][:, :, :2]
    dofs = values.function_space.dofmap.list[:owned]
    local = values.x.array[dofs]
    parts = mesh.comm.gather((xy, local), root=0)
    if mesh.comm.rank != 0:
        return None
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def plot_adapted_mesh(
    mesh: dolfinx.mesh.Mesh,
    contact: dolfinx.fem.Function,
    path: Path,
    title: str,
    zooms: list[tuple[float, float, float]] | None = None,
) -> Path:
    """Draw the cells of ``mesh`` and the boundary of the contact set (the 1/2 level line of
    the P1 ``contact`` indicator): the whole domain and a close-up for each ``(y1, y2, half
    width)`` of ``zooms``. Collective; rank 0 writes ``path``."""
    data = _gathered(mesh, contact)
    if mesh.comm.rank != 0:
        return path
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.tri import Triangulation

    assert data is not None
    xy, flags = data
    tri = Triangulation(
        xy[:, :, 0].ravel(), xy[:, :, 1].ravel(), np.arange(xy.shape[0] * 3).reshape(-1, 3)
    )
    zooms = list(zooms or [])
    panels = 1 + len(zooms)
    fig, axes = plt.subplots(1, panels, figsize=(5.5 * panels, 5.5), squeeze=False)
    for k, ax in enumerate(axes[0]):
        cells = PolyCollection(xy, facecolors="none", edgecolors="0.3", linewidths=0.15)
        ax.add_collection(cells)
        if np.any(flags > 0.5) and np.any(flags < 0.5):
            ax.tricontour(tri, flags.ravel(), levels=[0.5], colors="tab:red", linewidths=1.2)
        ax.set_aspect("equal")
        if k == 0:
            ax.set_xlim(xy[:, :, 0].min(), xy[:, :, 0].max())
            ax.set_ylim(xy[:, :, 1].min(), xy[:, :, 1].max())
            ax.set_title(title, fontsize=9)
        else:
            cx, cy, w = zooms[k - 1]
            ax.set_xlim(cx - w, cx + w)
            ax.set_ylim(cy - w, cy + w)
            ax.set_title(
                f"around ({cx:.4g}, {cy:.4g}), ±{w:.2g}; red: boundary of the contact set",
                fontsize=9,
            )
        ax.set_xlabel("y1")
        ax.set_ylabel("y2")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)
    return path
