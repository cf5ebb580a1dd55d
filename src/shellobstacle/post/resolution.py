"""Does the mesh resolve the obstacle where the shell touches it?

A curved obstacle whose radius of curvature near the contact spans only a few cells is seen by
the constraint at a handful of points: the contact then depends on where those points fall
(a ball of radius two cells can slip between them), and the answer changes with the mesh
more than the discretization error says. :func:`unresolved_obstacle` compares, at the
contact points of a solution (where its constraint acts,
:func:`~shellobstacle.post.points.constraint_points`), the obstacle's smallest
principal radius of curvature (:meth:`~shellobstacle.obstacle.base.Obstacle.curvature_radius`)
with the size in space of the cell holding the point (its longest edge mapped by ``θ``), and
returns a warning naming the cell size that would resolve it.
"""

from __future__ import annotations

from typing import Any

import dolfinx
import dolfinx.fem
import numpy as np
import ufl

__all__ = ["RESOLVE_CELLS", "unresolved_obstacle"]

RESOLVE_CELLS = 4.0
"""The cells a radius of curvature must span near the contact: the chord of a cell then
deviates from the obstacle by ``h²/(8R) ≤ h/32`` and a contact patch of the obstacle's own
size holds several cells' constraint points."""


def unresolved_obstacle(points: Any, tol: float) -> str | None:
    """A warning if the obstacle's radius of curvature at the contact spans fewer than
    :data:`RESOLVE_CELLS` cells, else None. Global (the same on every rank); collective.

    Args:
        points: the solution's :class:`~shellobstacle.post.points.ContactPoints`.
        tol: the contact threshold (a point touches where ``g ≤ tol``).
    """
    problem = points.problem
    obstacle = problem.obstacle
    comm = problem.mesh.comm
    if obstacle.affine:
        return None
    mesh = problem.mesh
    tdim = mesh.topology.dim
    cells = np.arange(mesh.topology.index_map(tdim).size_local, dtype=np.int32)
    points.gap()
    touching = points.values.x.array[points.space.dofmap.list[cells]] <= tol
    hit = np.flatnonzero(touching.any(axis=1))
    worst = (np.inf, np.nan, np.nan)  # (radius / cell size, radius, cell size)
    if hit.size:
        X = points.space.element.interpolation_points
        G = problem.G
        face = ufl.as_vector(obstacle.point(G, [problem.zeta[i] for i in range(3)]))
        x = dolfinx.fem.Expression(face, X).eval(mesh, cells[hit]).reshape(hit.size, -1, 3)
        mask = touching[hit]
        radius = obstacle.curvature_radius(x[mask])
        size = np.repeat(_cell_size_in_space(problem, cells[hit]), mask.sum(axis=1))
        ratio = radius / size
        k = int(np.argmin(ratio))
        worst = (float(ratio[k]), float(radius[k]), float(size[k]))
    ratio, radius, size = min(comm.allgather(worst), key=lambda w: w[0])
    if not ratio < RESOLVE_CELLS:
        return None
    return (
        f"the mesh does not resolve the obstacle near the contact: its radius of curvature "
        f"there, {radius:.3g}, spans {ratio:.2g} cells of size {size:.3g} on the shell "
        f"(at least {RESOLVE_CELLS:g} needed); the contact then depends on where the points "
        f"of the constraint fall: refine to cells of at most {radius / RESOLVE_CELLS:.3g} "
        "near the contact (a smaller domain.h, or [adapt])"
    )


def _cell_size_in_space(problem: Any, cells: np.ndarray) -> np.ndarray:
    """The longest edge of each cell's image under ``θ`` (the vertices' chords)."""
    mesh = problem.mesh
    x = mesh.geometry.x
    vertices = mesh.geometry.dofmaps[0][cells][:, :3]
    theta = problem.shell.surface.theta_numpy(x[vertices.ravel()])
    n = vertices.size
    image = np.column_stack([np.broadcast_to(t, (n,)) for t in theta]).reshape(cells.size, 3, 3)
    edges = image[:, [0, 1, 2], :] - image[:, [1, 2, 0], :]
    return np.linalg.norm(edges, axis=2).max(axis=1)
