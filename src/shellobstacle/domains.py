"""Triangle meshes of the 2D parameter domain ω ⊂ R² of the shell.

Curved and polygonal domains are meshed by gmsh on rank 0 only and distributed over the
communicator by :func:`dolfinx.mesh.create_mesh`; a large mesh is gmsh's mesh at a coarser size,
distributed, then refined uniformly in parallel (:func:`refine_uniformly`, new boundary nodes
moved onto the curve). Rectangles get a structured DOLFINx mesh. All meshes are affine (linear)
triangles with geometric dimension 2.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass

from shellobstacle import compat  # noqa: F401  (must precede dolfinx / petsc4py)

# isort: split
import dolfinx
import dolfinx.fem
import dolfinx.io.gmsh
import dolfinx.mesh
import numpy as np
import ufl
from mpi4py import MPI

__all__ = [
    "KINDS",
    "DomainSpec",
    "boundary_facets",
    "create_mesh",
    "domain_area",
    "mesh_size",
    "mesh_size_min",
    "num_cells_global",
    "refine_uniformly",
]

KINDS = ("disk", "ellipse", "polygon", "rectangle", "file")
_TRIANGLE = 2  # gmsh element type of the 3-node triangle
_DOMAIN_TAG, _BOUNDARY_TAG = 1, 2  # physical groups: surface "domain", curves "boundary"


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
    gmsh_max_vertices: int = 8_000


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


def _validate(spec: DomainSpec) -> None:
    """Raise ValueError (identically on every rank) for an inconsistent spec."""
    if spec.kind not in KINDS:
        raise ValueError(f"unknown domain kind {spec.kind!r}; valid kinds: {', '.join(KINDS)}")
    if spec.refinements < 0:
        raise ValueError(f"refinements must be >= 0, got {spec.refinements}")
    if spec.gmsh_max_vertices < 0:
        raise ValueError(f"gmsh_max_vertices must be >= 0 (0: never), got {spec.gmsh_max_vertices}")
    if spec.kind == "file":
        if not spec.path:
            raise ValueError("kind 'file' needs path=<gmsh .msh file>")
        return
    if spec.h is None or not spec.h > 0:
        raise ValueError(f"mesh size h must be positive, got {spec.h}")
    diameter = _diameter(spec)
    if spec.h > diameter:
        raise ValueError(f"mesh size h={spec.h} exceeds the domain's diameter {diameter:g}")
    if spec.central_h is not None or spec.central_radius is not None:
        if spec.kind not in ("disk", "ellipse"):
            raise ValueError("central_h/central_radius are only supported for disk and ellipse")
        if spec.central_h is None or spec.central_radius is None:
            raise ValueError("central_h and central_radius must be given together")
        if not 0 < spec.central_h <= spec.h or not spec.central_radius > 0:
            raise ValueError(
                f"need 0 < central_h <= h and central_radius > 0, got central_h="
                f"{spec.central_h}, central_radius={spec.central_radius}"
            )


@contextlib.contextmanager
def _gmsh_model(name: str, options: dict[str, float]) -> Iterator[object]:
    """A fresh, silent gmsh model; gmsh is finalized (or its state restored) on exit."""
    import gmsh

    owner = not gmsh.isInitialized()
    if owner:
        gmsh.initialize(readConfigFiles=False, interruptible=False)
    options = {"General.Terminal": 0, **options}
    saved = {key: gmsh.option.getNumber(key) for key in options}
    previous = None if owner else gmsh.model.getCurrent()
    for key, value in options.items():
        gmsh.option.setNumber(key, value)
    gmsh.model.add(name)
    try:
        yield gmsh.model
    finally:
        gmsh.model.remove()
        if owner:
            gmsh.finalize()
        else:
            for key, value in saved.items():
                gmsh.option.setNumber(key, value)
            with contextlib.suppress(Exception):
                gmsh.model.setCurrent(previous)


def _build_model(model, spec: DomainSpec) -> None:
    """Create the geometry of ``spec`` (disk, ellipse, polygon), its groups, and mesh it."""
    occ = model.occ
    cx, cy = spec.center
    if spec.kind == "polygon":
        points = [occ.addPoint(x, y, 0.0) for x, y in spec.vertices]
        lines = [occ.addLine(p, q) for p, q in zip(points, points[1:] + points[:1], strict=True)]
        surface = occ.addPlaneSurface([occ.addCurveLoop(lines)])
    else:
        a, b = (spec.radius, spec.radius) if spec.kind == "disk" else spec.semi_axes
        # OCC wants rx >= ry: put the major axis along y through xAxis when b > a
        rx, ry, x_axis = (a, b, [1, 0, 0]) if a >= b else (b, a, [0, 1, 0])
        surface = occ.addDisk(cx, cy, 0.0, rx, ry, zAxis=[0, 0, 1], xAxis=x_axis)
    occ.synchronize()
    curves = [tag for _, tag in model.getBoundary([(2, surface)], oriented=False)]
    model.addPhysicalGroup(2, [surface], _DOMAIN_TAG, name="domain")
    model.addPhysicalGroup(1, curves, _BOUNDARY_TAG, name="boundary")
    if spec.central_h is not None:
        field = model.mesh.field
        ball = field.add("Ball")
        for key, value in {
            "XCenter": cx,
            "YCenter": cy,
            "ZCenter": 0.0,
            "Radius": spec.central_radius,
            "Thickness": 4.0 * (spec.h - spec.central_h),  # size grows with slope ~ 1/4
            "VIn": spec.central_h,
            "VOut": spec.h,
        }.items():
            field.setNumber(ball, key, value)
        field.setAsBackgroundMesh(ball)
    model.mesh.generate(2)


def _gmsh_options(spec: DomainSpec) -> dict[str, float]:
    """Gmsh options: linear triangles, Frontal-Delaunay, sizes from h (and the size field)."""
    options = {"Mesh.Algorithm": 6, "Mesh.ElementOrder": 1, "Mesh.RecombineAll": 0}
    if spec.kind == "file":
        return options
    options |= {"Mesh.MeshSizeMin": spec.central_h or spec.h, "Mesh.MeshSizeMax": spec.h}
    if spec.central_h is not None:
        options |= {
            "Mesh.MeshSizeFromPoints": 0,
            "Mesh.MeshSizeFromCurvature": 0,
            "Mesh.MeshSizeExtendFromBoundary": 0,
        }
    return options


def _check_file(model, path: str) -> str:
    """Merge a .msh file into ``model``; return an error message ("" if it is usable)."""
    import gmsh

    if not os.path.isfile(path):
        return f"mesh file {path!r} does not exist"
    gmsh.merge(path)
    types = {int(t) for dim in (2, 3) for t in model.mesh.getElementTypes(dim)}
    if types != {_TRIANGLE}:
        found = ", ".join(model.mesh.getElementProperties(t)[0] for t in sorted(types))
        return f"mesh file {path!r} is not made of linear triangles (found: {found or 'none'})"
    if not model.getPhysicalGroups(2):  # unmarked file: mark every surface
        model.addPhysicalGroup(2, [tag for _, tag in model.getEntities(2)], name="domain")
    return ""


def _partitioner():
    """Cell partitioner with one layer of facet-sharing ghost cells (as DOLFINx's built-ins)."""
    return dolfinx.mesh.create_cell_partitioner(dolfinx.mesh.GhostMode.shared_facet, 2)


def _gmsh_triangles(model) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ``(n, 2)`` and triangles ``(m, 3)`` (numbered from 0) of the 2D physical groups."""
    tags, coords, _ = model.mesh.getNodes()
    index = np.full(int(tags.max(initial=0)) + 1, -1, dtype=np.int64)
    index[tags] = np.arange(len(tags))
    groups = model.getPhysicalGroups(2)
    entities = sorted({int(e) for _, g in groups for e in model.getEntitiesForPhysicalGroup(2, g)})
    cells = [
        index[nodes.astype(np.int64)].reshape(-1, 3)
        for e in entities
        for etype, _, nodes in zip(*model.mesh.getElements(2, e), strict=True)
        if etype == _TRIANGLE
    ]
    cells = np.concatenate(cells) if cells else np.zeros((0, 3), dtype=np.int64)
    used, cells = np.unique(cells, return_inverse=True)  # drop nodes of no triangle
    return coords.reshape(-1, 3)[used, :2].copy(), cells.reshape(-1, 3)


def _gmsh_arrays(spec: DomainSpec, comm: MPI.Comm, steps: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and triangles of the gmsh mesh of ``spec`` at ``2^steps`` times its sizes (or of
    its file), on rank 0; empty arrays on the other ranks. Errors are raised on every rank."""
    x, cells = np.zeros((0, 2)), np.zeros((0, 3), dtype=np.int64)
    error = ""
    if comm.rank == 0:
        coarse = spec
        if steps:
            grow = 2.0**steps
            coarse = dataclasses.replace(
                spec, h=spec.h * grow, central_h=spec.central_h and spec.central_h * grow
            )
        with _gmsh_model("shellobstacle-domain", _gmsh_options(coarse)) as model:
            try:
                if spec.kind == "file":
                    error = _check_file(model, str(spec.path))
                else:
                    _build_model(model, coarse)
                if not error:
                    x, cells = _gmsh_triangles(model)
                    if not len(cells):
                        error = f"gmsh made no triangles for {spec}"
            except Exception as exc:  # let the other ranks fail too instead of hanging
                error = f"gmsh failed for {spec}: {exc}"
    error = comm.bcast(error, root=0)
    if error:
        raise ValueError(error)
    return x, cells


def _gmsh_mesh(spec: DomainSpec, comm: MPI.Comm, steps: int = 0) -> dolfinx.mesh.Mesh:
    """Build (or read) the gmsh mesh on rank 0, distribute it, refine it ``steps`` times."""
    x, cells = _gmsh_arrays(spec, comm, steps)
    domain = dolfinx.io.gmsh.ufl_mesh(_TRIANGLE, 2, dtype=np.float64)
    mesh = dolfinx.mesh.create_mesh(comm, cells, domain, x, _partitioner())
    for _ in range(steps):
        mesh = _red_refinement(mesh, spec)
    return mesh


def create_mesh(spec: DomainSpec, comm: MPI.Comm = MPI.COMM_WORLD) -> dolfinx.mesh.Mesh:
    """Mesh the parameter domain described by ``spec`` with linear triangles.

    Args:
        spec: Domain and mesh description.
        comm: Communicator over which the mesh is distributed.

    Returns:
        The (distributed) mesh, with ``spec.refinements`` uniform refinements applied.

    Raises:
        ValueError: If ``spec`` is inconsistent, or the mesh file is missing or unusable.
    """
    _validate(spec)
    if spec.kind == "rectangle":
        (x0, y0), (x1, y1) = spec.corners
        n = [math.ceil((x1 - x0) / spec.h), math.ceil((y1 - y0) / spec.h)]
        mesh = dolfinx.mesh.create_rectangle(
            comm, [np.array([x0, y0]), np.array([x1, y1])], n,
            cell_type=dolfinx.mesh.CellType.triangle, diagonal=dolfinx.mesh.DiagonalType.right,
        )  # fmt: skip
    else:
        mesh = _gmsh_mesh(spec, comm, _coarsening_steps(spec))
    for _ in range(spec.refinements):
        mesh = refine_uniformly(mesh)
    _prepare(mesh)
    return mesh


def _estimated_vertices(spec: DomainSpec, h: float, central_h: float | None) -> float:
    """Vertices of a mesh of ``spec`` with sizes ``h`` (and ``central_h``): area / (√3/2 h²)."""
    if spec.kind == "disk":
        area = math.pi * spec.radius**2
    elif spec.kind == "ellipse":
        area = math.pi * spec.semi_axes[0] * spec.semi_axes[1]
    else:
        v = np.asarray(spec.vertices, dtype=float)
        area = 0.5 * abs(float(np.dot(v[:, 0], np.roll(v[:, 1], -1) - np.roll(v[:, 1], 1))))
    count = area / (math.sqrt(3.0) / 2.0 * h * h)
    if central_h is not None:
        zone = min(area, math.pi * spec.central_radius**2)
        count += zone / (math.sqrt(3.0) / 2.0) * (1.0 / central_h**2 - 1.0 / h**2)
    return count


def _coarsening_steps(spec: DomainSpec) -> int:
    """How many uniform refinements replace gmsh at full size (see ``gmsh_max_vertices``)."""
    if spec.kind not in ("disk", "ellipse", "polygon") or spec.gmsh_max_vertices <= 0:
        return 0
    steps = 0
    while (
        _estimated_vertices(
            spec, spec.h * 2.0**steps, spec.central_h and spec.central_h * 2.0**steps
        )
        > spec.gmsh_max_vertices
    ):
        steps += 1
    # the coarse mesh must still resolve the domain (a few cells across)
    while steps and spec.h * 2.0**steps > _diameter(spec) / 8:
        steps -= 1
    return steps


def _prepare(mesh: dolfinx.mesh.Mesh) -> None:
    """Create the edges and facet-cell connectivity used by refinement and boundary search."""
    tdim = mesh.topology.dim
    mesh.topology.create_entities(1)
    mesh.topology.create_connectivity(tdim - 1, tdim)


def refine_uniformly(mesh: dolfinx.mesh.Mesh) -> dolfinx.mesh.Mesh:
    """Refine once uniformly ("red"): every edge is bisected, each triangle split into four.

    The four children are similar to their parent, so the mesh size halves exactly and the
    meshes are nested: the P1 space of ``mesh`` is a subspace of the refined one. (Plaza
    refinement, ``dolfinx.mesh.refine``, also bisects every edge but cuts along a median,
    so its children are not similar and h does not halve.) The children stay on their
    parent's rank, without ghost cells (nothing is repartitioned); the refined mesh is a 2D
    mesh (``geometry.dim == 2``).

    Args:
        mesh: Triangle mesh.

    Returns:
        The refined mesh, with edges and facet-cell connectivity created.
    """
    fine = _red_refinement(mesh)
    _prepare(fine)
    return fine


def _red_refinement(mesh: dolfinx.mesh.Mesh, curve: DomainSpec | None = None) -> dolfinx.mesh.Mesh:
    """DOLFINx's uniform refinement with a 2D geometry; ``curve``: a disk or ellipse whose
    boundary the new boundary nodes are moved onto (radially from its centre).

    DOLFINx 0.11's ``uniform_refine`` returns a geometry with three coordinates per node: the
    refined topology gets a new 2D geometry on the same nodes (no ``create_mesh``, whose cell
    reordering alone took 2.9 s of 7.3 s for 1.28 M cells, measured).
    """
    mesh.topology.create_entities(1)
    fine = dolfinx.mesh.uniform_refine(mesh)
    geometry = fine.geometry
    x = np.ascontiguousarray(geometry.x[:, :2])
    if curve is not None and curve.kind in ("disk", "ellipse"):
        _onto_curve(fine, x, curve)
    planar = dolfinx.cpp.mesh.Geometry_float64(
        geometry.index_map(), geometry.dofmaps[0], geometry._cpp_object.cmaps[0], x,
        geometry.input_global_indices,
    )  # fmt: skip
    return dolfinx.mesh.Mesh(
        dolfinx.cpp.mesh.Mesh_float64(mesh.comm, fine.topology._cpp_object, planar),
        ufl.Mesh(mesh.ufl_domain().ufl_coordinate_element()),
    )


def _onto_curve(mesh: dolfinx.mesh.Mesh, x: np.ndarray, spec: DomainSpec) -> None:
    """Move the nodes ``x`` of ``mesh``'s boundary facets that are off the curve of the disk
    or ellipse ``spec`` radially onto it, in place (a chord's midpoint is ``O(h²)`` inside;
    the nodes already on the curve, to 1e-12, are left bitwise as they are).

    Each rank moves the nodes of its own boundary facets: a new boundary node is the midpoint
    of a boundary edge, and all the cells through it are children of the one cell that had
    that edge, on one rank (``uniform_refine`` keeps children on their parent's rank).
    """
    facets = boundary_facets(mesh)
    nodes = np.unique(dolfinx.mesh.entities_to_geometry(mesh, mesh.topology.dim - 1, facets))
    c = np.asarray(spec.center, dtype=float)
    a, b = (spec.radius, spec.radius) if spec.kind == "disk" else spec.semi_axes
    d = x[nodes] - c
    s = np.hypot(d[:, 0] / a, d[:, 1] / b)
    off = np.abs(s - 1.0) > 1e-12
    x[nodes[off]] = c + d[off] / s[off, None]


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
