"""Local solutions on an obstacle whose admissible set is not known to be convex, and the side
of the obstacle that the contact lies on (docs/model.md, Curved obstacles).

Outside a ball or a cylinder, or for a user's curved ``g``, the energy can have several local
minimizers and a solver reaches one of them. Which one shows in where the contact face
touches: at a contact point the obstacle's outward normal ``∇g`` at the deformed face
``φ = θ + s a_3 + ζ_i a^i`` is compared with ``∇g`` at the undeformed one ``θ + s a_3``;
``∇g(φ)·∇g(θ + s a_3) > 0`` is the *near* side (the side the undeformed shell faces), ``≤ 0``
the *far* side (the shell has passed around or through the obstacle).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mpi4py import MPI

import dolfinx.fem
import numpy as np
import ufl

from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.points import ContactPoints

__all__ = ["contact_sides", "facing", "local_solution", "local_solution_text"]


def local_solution(problem: Any, constraint: str = "penalty") -> dict[str, Any]:
    """What the summary records of the answer in ``problem.zeta``: nothing for a convex
    admissible set; otherwise ``local_solution`` (True), ``local_solution_reason`` (one line)
    and ``contact_sides`` (:func:`contact_sides`). Collective."""
    convex = problem.obstacle.convex
    if convex:
        return {}
    why = "is not convex" if convex is False else "is not known to be convex (a curved g)"
    return {
        "local_solution": True,
        "local_solution_reason": (
            f"the admissible set {{g ≥ 0}} {why}: the energy may have several local "
            "minimizers, and this answer is the one the solver reached"
        ),
        "contact_sides": contact_sides(problem, constraint),
    }


def local_solution_text(summary: Mapping[str, Any]) -> str:
    """The command line's one line on a local solution (the keys of :func:`local_solution`)."""
    sides = summary["contact_sides"]
    return (
        f"a local solution: {summary['local_solution_reason']}; contact on the near side "
        f"{sides['near_points']} points (area {sides['near_area']:.4g}), on the far side "
        f"{sides['far_points']} (area {sides['far_area']:.4g})"
    )


def contact_sides(problem: Any, constraint: str = "penalty", tol_rel: float = 1e-12) -> dict:
    """The contact points on each side of the obstacle (:func:`facing`): those of
    :func:`~shellobstacle.post.points.constraint_points` where ``g(ζ) ≤ tol``, the
    summary's contact set (:meth:`~shellobstacle.post.contact.Postprocessor.tolerance`).

    Returns:
        ``near_points``, ``far_points`` (counts), ``near_area``, ``far_area`` (their weights
        ``Σ w_k √a(x_k)``) and ``points`` (which points). Global values.
    """
    post = Postprocessor(problem, constraint)
    points = post.points
    comm: MPI.Comm = problem.mesh.comm
    touching = points.gap() <= post.tolerance(tol_rel)
    y = _at_points(points, ufl.SpatialCoordinate(problem.mesh))
    near = facing(problem.obstacle, problem.shell.surface, y, _at_points(points, problem.zeta))
    out: dict[str, Any] = {"points": points.kind}
    for side, mask in (("near", touching & near), ("far", touching & ~near)):
        out[f"{side}_points"] = int(comm.allreduce(int(mask.sum()), op=MPI.SUM))
        out[f"{side}_area"] = float(comm.allreduce(float(points.mass[mask].sum()), op=MPI.SUM))
    return out


def facing(obstacle: Any, surface: Any, y: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """``∇g(θ + s a_3 + ζ_i a^i) · ∇g(θ + s a_3) > 0`` at the points ``y`` of ω (shape
    ``(n, ≥2)``) displaced by ``zeta`` (shape ``(n, 3)``): True on the near side."""
    G = surface.geometry_numpy(y)
    deformed = obstacle.gradient(G, obstacle.point(G, [zeta[:, i] for i in range(3)]))
    undeformed = obstacle.gradient(G, obstacle.point(G))
    product = sum(np.asarray(a, dtype=float) * b for a, b in zip(deformed, undeformed, strict=True))
    return np.broadcast_to(product > 0, (y.shape[0],))


def _at_points(points: ContactPoints, e: Any) -> np.ndarray:
    """The UFL vector ``e`` at the owned points, shape ``(n, size)``: evaluated at the points'
    reference coordinates in every owned cell, each point taking its dof's value."""
    space = points.space
    mesh = space.mesh
    cells = np.arange(mesh.topology.index_map(mesh.topology.dim).size_local, dtype=np.int32)
    values = dolfinx.fem.Expression(e, space.element.interpolation_points).eval(mesh, cells)
    size = int(np.prod(e.ufl_shape))
    imap = space.dofmap.index_map
    out = np.zeros((imap.size_local + imap.num_ghosts, size))
    out[space.dofmap.list[cells].ravel()] = values.reshape(-1, size)
    return out[: points.n]
