"""The parameter domain ω ⊂ R² of the shell and the size of its mesh: :class:`DomainSpec`.

Plain data and its validation (no DOLFINx): :mod:`shellobstacle.mesh.meshing` meshes it,
:mod:`shellobstacle.mesh.refinement` refines the meshes, :mod:`shellobstacle.mesh.measures`
measures them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shellobstacle.messages import not_one_of

__all__ = ["KINDS", "DomainSpec", "coarsening_steps", "estimated_vertices", "validate"]

KINDS = ("disk", "ellipse", "polygon", "rectangle", "file")
#: the kinds whose meshes can be graded towards the boundary (edge_h, edge_width)
GRADED_KINDS = ("disk", "ellipse", "polygon")
#: uniform refinements after meshing (each multiplies the cells by 4)
MAX_REFINEMENTS = 8


@dataclass(frozen=True)
class DomainSpec:
    """Description of the parameter domain ω and of its mesh.

    Attributes:
        kind: One of ``"disk"``, ``"ellipse"``, ``"polygon"``, ``"rectangle"``, ``"file"``.
        h: Target mesh size (gmsh characteristic length; for rectangles the cell legs are
            ``length / ceil(length / h)``). Unused for ``"file"``.
        radius: Radius of the disk.
        center: Center of the disk, the ellipse, and of the central refinement zone.
        semi_axes: Semi-axes ``(a, b)`` of the ellipse (along x and y).
        vertices: Vertices of a simple polygon, in either orientation.
        corners: Lower-left and upper-right corners of the rectangle.
        path: Path of a gmsh ``.msh`` file made of linear triangles.
        refinements: Number of uniform refinements applied after generation.
        central_h: Disk/ellipse only: mesh size inside ``|y - center| < central_radius``.
        central_radius: Radius of the centrally refined zone (needed with ``central_h``).
        edge_h: Disk, ellipse, polygon: mesh size along the boundary, growing to ``h`` beyond
            ``edge_width`` (to resolve a boundary layer).
        edge_width: Width of the band along the boundary meshed at ``edge_h``.
        gmsh_max_vertices: Disk, ellipse and polygon: when the mesh would have more vertices
            than this, gmsh meshes with a size ``2^k`` times larger and the distributed mesh
            is refined uniformly ``k`` times (new boundary vertices moved onto the curved
            boundary), which is several times faster than gmsh at full size. 0: never.
    """

    kind: str
    h: float | None = None
    radius: float = 0.5
    center: tuple[float, float] = (0.0, 0.0)
    semi_axes: tuple[float, float] | None = None
    vertices: tuple[tuple[float, float], ...] | None = None
    corners: tuple[tuple[float, float], tuple[float, float]] | None = None
    path: str | None = None
    refinements: int = 0
    central_h: float | None = None
    central_radius: float | None = None
    edge_h: float | None = None
    edge_width: float | None = None
    gmsh_max_vertices: int = 8_000

    def __post_init__(self) -> None:
        validate(self)


def _diameter(spec: DomainSpec) -> float:
    """Validate the shape data of a non-file spec and return the domain's diameter."""
    if spec.kind == "disk":
        if spec.radius <= 0:
            raise ValueError(f"disk radius must be positive, got {spec.radius}")
        return 2.0 * spec.radius
    if spec.kind == "ellipse":
        if spec.semi_axes is None or len(spec.semi_axes) != 2 or min(spec.semi_axes) <= 0:
            raise ValueError(f"ellipse needs semi_axes=(a, b) with a, b > 0, got {spec.semi_axes}")
        return 2.0 * max(spec.semi_axes)
    if spec.kind == "rectangle":
        if spec.corners is None:
            raise ValueError("rectangle needs corners=((x0, y0), (x1, y1))")
        (x0, y0), (x1, y1) = spec.corners
        if x1 <= x0 or y1 <= y0:
            raise ValueError(f"rectangle corners must be lower-left, upper-right: {spec.corners}")
        return math.hypot(x1 - x0, y1 - y0)
    # polygon
    if spec.vertices is None:
        raise ValueError("polygon needs vertices=((x0, y0), (x1, y1), ...)")
    v = np.asarray(spec.vertices, dtype=float)
    if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
        raise ValueError(f"polygon needs at least 3 vertices (x, y), got {len(v)}")
    if len(np.unique(v, axis=0)) != len(v):
        raise ValueError("polygon vertices must be distinct")
    if not _is_simple(v):
        raise ValueError("polygon must be simple (its edges may not cross, touch or fold back)")
    return float(np.max(np.linalg.norm(v[:, None, :] - v[None, :, :], axis=-1)))


def _is_simple(v: np.ndarray) -> bool:
    """Whether the closed polygon with distinct vertices ``v`` (n x 2) is simple."""
    n, p = len(v), v
    q = np.roll(v, -1, axis=0)
    e = q - p  # edge i runs from p[i] to q[i]

    def side(a, b, c):  # orientation of the triangle (a, b, c): -1, 0, +1
        return np.sign((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])

    # consecutive edges may only meet at their common vertex: no fold-back
    e_next = np.roll(e, -1, axis=0)
    if np.any((e[:, 0] * e_next[:, 1] == e[:, 1] * e_next[:, 0]) & (np.sum(e * e_next, 1) < 0)):
        return False
    i, j = np.triu_indices(n, 2)  # non-consecutive edge pairs
    i, j = i[(j - i) < n - 1], j[(j - i) < n - 1]
    boxes = np.all(
        (np.minimum(p[i], q[i]) <= np.maximum(p[j], q[j]))
        & (np.minimum(p[j], q[j]) <= np.maximum(p[i], q[i])),
        axis=1,
    )
    cross_i = side(p[j], q[j], p[i]) * side(p[j], q[j], q[i]) <= 0
    cross_j = side(p[i], q[i], p[j]) * side(p[i], q[i], q[j]) <= 0
    return not np.any(boxes & cross_i & cross_j)


def validate(spec: DomainSpec) -> None:
    """Raise ValueError (identically on every rank) for an inconsistent spec; the messages
    name the keys of ``[domain]``, as the config loader reports them."""
    if spec.kind not in KINDS:
        raise ValueError(not_one_of("domain.kind", spec.kind, KINDS))
    if not 0 <= spec.refinements <= MAX_REFINEMENTS:
        raise ValueError(
            f"domain.refinements must be in 0..{MAX_REFINEMENTS} (each multiplies the cells "
            f"by 4), got {spec.refinements}"
        )
    if spec.gmsh_max_vertices < 0:
        raise ValueError(
            f"domain.gmsh_max_vertices must be >= 0 (0: never), got {spec.gmsh_max_vertices}"
        )
    if spec.kind == "file":
        if not spec.path:
            raise ValueError("kind 'file' needs path=<gmsh .msh file>")
        return
    if spec.h is None:
        raise ValueError(f"[domain] needs 'h' (target mesh size) for kind = '{spec.kind}'")
    if not spec.h > 0:
        raise ValueError(f"domain.h must be > 0, got {spec.h}")
    diameter = _diameter(spec)
    if spec.h > diameter:
        raise ValueError(f"mesh size h={spec.h} exceeds the domain's diameter {diameter:g}")
    central_kinds = ("disk", "ellipse")
    _check_refined_zone(spec, "central_h", "central_radius", central_kinds, "disk and ellipse")
    _check_refined_zone(spec, "edge_h", "edge_width", GRADED_KINDS, "disk, ellipse and polygon")


def _check_refined_zone(
    spec: DomainSpec, size: str, extent: str, kinds: tuple[str, ...], kinds_text: str
) -> None:
    """A finer zone's mesh size and extent: both or neither, ``0 < size <= h``, extent > 0."""
    h_zone, width = getattr(spec, size), getattr(spec, extent)
    if h_zone is None and width is None:
        return
    if spec.kind not in kinds:
        raise ValueError(f"{size}/{extent} are only supported for {kinds_text}")
    if h_zone is None or width is None:
        raise ValueError(f"{size} and {extent} must be given together")
    if not 0 < h_zone <= spec.h or not width > 0:
        raise ValueError(
            f"need 0 < {size} <= h and {extent} > 0, got {size}={h_zone}, {extent}={width}"
        )


def _area_perimeter(spec: DomainSpec) -> tuple[float, float]:
    """Area and perimeter of a disk, ellipse (Ramanujan's perimeter) or polygon (``inf`` for
    sizes whose square overflows: products of floats overflow to ``inf``, powers raise)."""
    if spec.kind == "disk":
        return math.pi * spec.radius * spec.radius, 2 * math.pi * spec.radius
    if spec.kind == "ellipse":
        a, b = spec.semi_axes
        return math.pi * a * b, math.pi * (3 * (a + b) - math.sqrt((3 * a + b) * (a + 3 * b)))
    v = np.asarray(spec.vertices, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        area = 0.5 * abs(float(np.dot(v[:, 0], np.roll(v[:, 1], -1) - np.roll(v[:, 1], 1))))
        return area, float(np.linalg.norm(np.roll(v, -1, axis=0) - v, axis=1).sum())


def estimated_vertices(spec: DomainSpec, grow: float = 1.0) -> float:
    """Vertices of a mesh of ``spec`` with every size times ``grow``: area / (√3/2 h²).

    Never raises for tiny or huge sizes: a count beyond the floats is ``inf``.
    """
    area, perimeter = _area_perimeter(spec)

    def per_area(size: float) -> float:  # x / size / size: inf rather than 1/0 when size² = 0
        return 2.0 / math.sqrt(3.0) / (size * grow) / (size * grow)

    count = area * per_area(spec.h)
    if spec.central_h is not None:
        zone = min(area, math.pi * spec.central_radius * spec.central_radius)
        count += zone * (per_area(spec.central_h) - per_area(spec.h))
    if spec.edge_h is not None:
        band = min(area, perimeter * (spec.edge_width + 2.0 * (spec.h - spec.edge_h)))
        count += band * (per_area(spec.edge_h) - per_area(spec.h))
    return math.inf if math.isnan(count) else count  # nan: inf - inf, both sizes tiny


def coarsening_steps(spec: DomainSpec) -> int:
    """How many uniform refinements replace gmsh at full size (see ``gmsh_max_vertices``)."""
    if spec.kind not in ("disk", "ellipse", "polygon") or spec.gmsh_max_vertices <= 0:
        return 0
    steps = 0
    while estimated_vertices(spec, 2.0**steps) > spec.gmsh_max_vertices:
        steps += 1
    # the coarse mesh must still resolve the domain (a few cells across)
    while steps and spec.h * 2.0**steps > _diameter(spec) / 8:
        steps -= 1
    return steps
