"""Cross-sections of a solved shell along a line of ω (docs/model.md §7, batch 3).

The reference and deformed middle surfaces and their gaps (for the plane: the heights above
it), sampled on the distributed mesh and gathered: the same on every rank. Any other obstacle's
profile in the section's vertical plane comes with them
(:func:`~shellobstacle.post.obstacle_shape.profile_below`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.geometry
import dolfinx.la
import numpy as np

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.obstacle import Plane
from shellobstacle.post.obstacle_shape import profile_below

__all__ = [
    "AXES",
    "CrossSection",
    "cross_section",
    "horizontal_direction",
    "line_tree",
    "mesh_extent",
    "sample",
]

AXES = ("y1", "y2")


@dataclass(frozen=True)
class CrossSection:
    """The shell along a line of ω: reference and deformed points and their heights.

    Attributes:
        axis: ``"y1"`` (line ``y2 = at``) or ``"y2"`` (line ``y1 = at``).
        at: The fixed coordinate.
        s: Parameter along the line (the running coordinate ``y1`` or ``y2``), shape ``(m,)``.
        y: Points of ω, shape ``(m, 2)``.
        zeta: Covariant components ``ζ_i(y)``, shape ``(m, 3)``.
        reference: ``θ(y)``, shape ``(m, 3)``.
        deformed: ``θ(y) + ζ_i(y) a^i(y)``, shape ``(m, 3)``.
        height_reference: ``g(θ)(y)``, the obstacle's gap (the height above the plane),
            shape ``(m,)``.
        height_deformed: ``g(ζ)(y)`` (for the plane ``(θ + ζ_i a^i)(y)·q``), shape ``(m,)``.
        q: Unit normal of the plane (of a curved obstacle: the vertical of the pictures).
        obstacle_s: For an obstacle other than a :class:`~shellobstacle.obstacle.plane.Plane`
            (a ball, a cylinder, a formula), the horizontal coordinates ``x·t``
            (:func:`horizontal_direction`) of its profile, shape ``(k,)``; None for a plane,
            whose gap is the height above it.
        obstacle_height: The heights ``x·q`` of the obstacle's upper surface at ``obstacle_s``
            in the vertical plane through the deformed section (NaN where that plane's
            vertical line misses it), shape ``(k,)``; None for a plane.
    """

    axis: str
    at: float
    s: np.ndarray
    y: np.ndarray
    zeta: np.ndarray
    reference: np.ndarray
    deformed: np.ndarray
    height_reference: np.ndarray
    height_deformed: np.ndarray
    q: np.ndarray
    obstacle_s: np.ndarray | None = None
    obstacle_height: np.ndarray | None = None


def _global_min(comm: MPI.Comm, values: np.ndarray, initial: float = np.inf) -> float:
    return float(comm.allreduce(float(np.min(values, initial=initial)), op=MPI.MIN))


def _global_max(comm: MPI.Comm, values: np.ndarray, initial: float = -np.inf) -> float:
    return float(comm.allreduce(float(np.max(values, initial=initial)), op=MPI.MAX))


def mesh_extent(mesh: dolfinx.mesh.Mesh, k: int) -> tuple[float, float]:
    """Smallest and largest coordinate ``k`` of the mesh's nodes (the same on every rank)."""
    x = mesh.geometry.x[:, k]
    return _global_min(mesh.comm, x), _global_max(mesh.comm, x)


def line_tree(mesh: dolfinx.mesh.Mesh, axis: str, at: float) -> dolfinx.geometry.BoundingBoxTree:
    """Bounding-box tree of the local cells that meet the line of a cross-section.

    The line is ``y2 = at`` for ``axis="y1"`` (``y1 = at`` for ``"y2"``); a tree of these
    cells only (about ``1/√N`` of them) is all the point search along it needs, and costs a
    fraction of a tree of the whole mesh.
    """
    tdim = mesh.topology.dim
    cells = mesh.topology.index_map(tdim)
    nodes = mesh.geometry.dofmaps[0][: cells.size_local + cells.num_ghosts]
    c = mesh.geometry.x[nodes, 1 - AXES.index(axis)]
    pad = 1e-12 * (1.0 + abs(at))
    meets = (c.min(axis=1) <= at + pad) & (c.max(axis=1) >= at - pad)
    return dolfinx.geometry.bb_tree(mesh, tdim, entities=np.flatnonzero(meets).astype(np.int32))


def sample(
    u: dolfinx.fem.Function, points: np.ndarray, tree: dolfinx.geometry.BoundingBoxTree
) -> tuple[np.ndarray, np.ndarray]:
    """Values of ``u`` at the points inside the mesh, gathered on every rank.

    Returns:
        ``(found, values)``: indices of the points found by some rank and ``u`` there (one value
        per point: the lowest rank that has it).
    """
    mesh = u.function_space.mesh
    candidates = dolfinx.geometry.compute_collisions_points(tree, points)
    colliding = dolfinx.geometry.compute_colliding_cells(mesh, candidates, points)
    found, cells = [], []
    for i in range(points.shape[0]):
        links = colliding.links(i)
        if len(links) > 0:
            found.append(i)
            cells.append(links[0])
    idx = np.asarray(found, dtype=np.int64)
    ncomp = int(np.prod(u.ufl_shape))
    vals = np.zeros((0, ncomp))
    if len(idx):
        vals = u.eval(points[idx], np.asarray(cells, dtype=np.int32)).reshape(len(idx), ncomp)
    gathered = mesh.comm.allgather((idx, vals))
    values = np.full((points.shape[0], ncomp), np.nan)
    have = np.zeros(points.shape[0], dtype=bool)
    for i, v in gathered:
        new = ~have[i]
        values[i[new]] = v[new]
        have[i[new]] = True
    where = np.flatnonzero(have)
    return where, values[where]


def cross_section(
    problem: PenalizedProblem,
    n: int = 401,
    axis: str = "y1",
    at: float = 0.0,
    tree: dolfinx.geometry.BoundingBoxTree | None = None,
) -> CrossSection:
    """Sample ``ζ`` along a straight line of ω and build the reference and deformed shell there.

    ``n`` equispaced points span the mesh's extent along ``axis`` on the line (``y2 = at`` for
    ``axis="y1"``); the points outside the mesh (a polygonal disk misses a little of its
    bounding box) are dropped. Each MPI rank evaluates the points its cells contain and every
    rank receives all values (docs/model.md §7, batch 3: cross-sections of ``θ + ζ_i a^i``).

    Args:
        problem: The problem; its current ``zeta`` is sampled.
        n: Number of sample points.
        axis: ``"y1"`` or ``"y2"``: the running coordinate.
        at: The value of the other coordinate.
        tree: A bounding-box tree of (at least) the cells that meet the line (built by
            :func:`line_tree` if not given).

    Returns:
        The :class:`CrossSection` (identical on all ranks).
    """
    if axis not in AXES:
        raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
    if n < 2:
        raise ValueError(f"a cross-section needs n >= 2 points, got {n}")
    mesh = problem.mesh
    k = AXES.index(axis)
    lo, hi = mesh_extent(mesh, k)
    s = np.linspace(lo, hi, n)
    points = np.zeros((n, 3))
    points[:, k] = s
    points[:, 1 - k] = at
    if tree is None:
        tree = line_tree(mesh, axis, at)
    where, zeta = sample(problem.zeta, points, tree)
    y = points[where, :2]
    G = problem.shell.surface.geometry_numpy(y)
    m = len(where)
    reference = np.column_stack([np.broadcast_to(np.asarray(t, float), (m,)) for t in G.theta])
    U = G.cartesian([zeta[:, i] for i in range(3)])
    deformed = reference + np.column_stack([np.broadcast_to(u, (m,)) for u in U])
    obstacle = problem.obstacle
    q = np.asarray(problem.q, float)
    profile: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
    if not isinstance(obstacle, Plane) and m:
        profile = _profile(obstacle, G, axis, q, reference, deformed)
    return CrossSection(
        axis=axis,
        at=float(at),
        s=s[where],
        y=y,
        zeta=zeta,
        reference=reference,
        deformed=deformed,
        height_reference=np.broadcast_to(obstacle.reference_gap(G), (m,)).astype(float),
        height_deformed=np.broadcast_to(
            obstacle.gap(G, [zeta[:, i] for i in range(3)]), (m,)
        ).astype(float),
        q=q,
        obstacle_s=profile[0],
        obstacle_height=profile[1],
    )


def _profile(obstacle, G, axis, q, reference, deformed, n=401) -> tuple[np.ndarray, np.ndarray]:
    """A curved obstacle's profile under a section: ``n`` horizontal positions spanning the
    deformed section and a tenth of its width on either side, in the vertical plane
    (spanned by ``t`` and ``q``) through the deformed points' mean, and the heights of the
    obstacle's upper surface there."""
    t = horizontal_direction(q, axis)
    across = np.cross(q, t)
    s = deformed @ t
    heights = np.concatenate([deformed @ q, reference @ q])
    width = max(float(s.max() - s.min()), 1e-12)
    rise = max(float(heights.max() - heights.min()), width)
    positions = np.linspace(s.min() - 0.1 * width, s.max() + 0.1 * width, n)
    base = np.outer(positions, t) + float(np.mean(deformed @ across)) * across
    top, bottom = float(heights.max()) + rise, float(heights.min()) - 2.0 * rise
    return positions, profile_below(obstacle, G, base, q, top, bottom)


def horizontal_direction(q: Sequence[float], axis: str = "y1") -> np.ndarray:
    """Unit vector of the plane ``x·q = 0`` closest to the Cartesian axis ``e_1`` (or ``e_2``).

    The horizontal coordinate of a cross-section point ``x`` is ``x·t`` (``x_1`` for
    ``q = (0, 0, 1)`` and ``axis = "y1"``).
    """
    q = np.asarray(q, float) / np.linalg.norm(q)
    for e in (np.eye(3)[AXES.index(axis)], *np.eye(3)):
        t = e - (e @ q) * q
        if np.linalg.norm(t) > 1e-8:
            return t / np.linalg.norm(t)
    raise ValueError(f"no horizontal direction for q = {q}")  # pragma: no cover
