"""Triangle meshes of the parameter domain ω (:class:`~shellobstacle.mesh.domains.DomainSpec`).

Curved and polygonal domains are meshed by gmsh on rank 0 only and distributed over the
communicator by :func:`dolfinx.mesh.create_mesh`; a large mesh is gmsh's mesh at a coarser size,
distributed, then refined uniformly in parallel (new boundary nodes moved onto the curve,
:mod:`shellobstacle.mesh.refinement`). Rectangles get a structured DOLFINx mesh. All meshes are
affine (linear) triangles with geometric dimension 2.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
from collections.abc import Iterator

from mpi4py import MPI

import dolfinx
import dolfinx.io.gmsh
import dolfinx.mesh
import numpy as np

from shellobstacle.mesh.domains import DomainSpec, coarsening_steps, validate
from shellobstacle.mesh.refinement import prepare, red_refinement, refine_uniformly
from shellobstacle.progress import phase

__all__ = ["create_mesh"]

_TRIANGLE = 2  # gmsh element type of the 3-node triangle
_DOMAIN_TAG, _BOUNDARY_TAG = 1, 2  # physical groups: surface "domain", curves "boundary"


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
    fields = []
    field = model.mesh.field
    if spec.central_h is not None:
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
        fields.append(ball)
    if spec.edge_h is not None:
        distance = field.add("Distance")
        field.setNumbers(distance, "CurvesList", curves)
        field.setNumber(distance, "Sampling", 200)
        threshold = field.add("Threshold")
        for key, value in {
            "InField": distance,
            "SizeMin": spec.edge_h,
            "SizeMax": spec.h,
            "DistMin": spec.edge_width,
            "DistMax": spec.edge_width + 4.0 * (spec.h - spec.edge_h),  # slope ~ 1/4
        }.items():
            field.setNumber(threshold, key, value)
        fields.append(threshold)
    if len(fields) == 1:
        field.setAsBackgroundMesh(fields[0])
    elif fields:
        smallest = field.add("Min")
        field.setNumbers(smallest, "FieldsList", fields)
        field.setAsBackgroundMesh(smallest)
    model.mesh.generate(2)


def _gmsh_options(spec: DomainSpec) -> dict[str, float]:
    """Gmsh options: linear triangles, Frontal-Delaunay, sizes from h (and the size field)."""
    options = {"Mesh.Algorithm": 6, "Mesh.ElementOrder": 1, "Mesh.RecombineAll": 0}
    if spec.kind == "file":
        return options
    finest = min(v for v in (spec.h, spec.central_h, spec.edge_h) if v is not None)
    options |= {"Mesh.MeshSizeMin": finest, "Mesh.MeshSizeMax": spec.h}
    if spec.central_h is not None or spec.edge_h is not None:
        options |= {
            "Mesh.MeshSizeFromPoints": 0,
            "Mesh.MeshSizeFromCurvature": 0,
            "Mesh.MeshSizeExtendFromBoundary": 0,
        }
    return options


def _check_file(model, path: str) -> str:
    """Merge a .msh file into ``model``; return an error message ("" if it is usable)."""
    import gmsh

    fix = "set domain.path to a gmsh .msh file of linear triangles"
    if os.path.isdir(path):
        return f"mesh file {path!r} is a directory: {fix}"
    if not os.path.isfile(path):
        return f"mesh file {path!r} does not exist: {fix}"
    try:
        gmsh.merge(path)
    except Exception as exc:  # gmsh raises Exception with its own message
        return f"gmsh cannot read the mesh file {path!r} ({exc}): {fix}"
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
                spec,
                h=spec.h * grow,
                central_h=spec.central_h and spec.central_h * grow,
                edge_h=spec.edge_h and spec.edge_h * grow,
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


def _gmsh_mesh(
    spec: DomainSpec, comm: MPI.Comm, steps: int = 0, ghosted: bool = False
) -> dolfinx.mesh.Mesh:
    """Build (or read) the gmsh mesh on rank 0, distribute it, refine it ``steps`` times."""
    with phase("gmsh"):
        x, cells = _gmsh_arrays(spec, comm, steps)
    with phase("distributing the mesh"):
        domain = dolfinx.io.gmsh.ufl_mesh(_TRIANGLE, 2, dtype=np.float64)
        mesh = dolfinx.mesh.create_mesh(comm, cells, domain, x, _partitioner())
    for k in range(steps):
        with phase(f"refining {k + 1}/{steps}"):
            mesh = red_refinement(mesh, spec, ghosted)
    return mesh


def create_mesh(
    spec: DomainSpec, comm: MPI.Comm = MPI.COMM_WORLD, ghosted: bool = False
) -> dolfinx.mesh.Mesh:
    """Mesh the parameter domain described by ``spec`` with linear triangles.

    Args:
        spec: Domain and mesh description.
        comm: Communicator over which the mesh is distributed.
        ghosted: keep one layer of facet-sharing ghost cells through the refinements too
            (Koiter's interior-facet terms need them in parallel; the membrane does not).

    Returns:
        The (distributed) mesh, with ``spec.refinements`` uniform refinements applied.

    Raises:
        ValueError: If ``spec`` is inconsistent, or the mesh file is missing or unusable.
    """
    validate(spec)
    if spec.kind == "rectangle":
        (x0, y0), (x1, y1) = spec.corners
        n = [math.ceil((x1 - x0) / spec.h), math.ceil((y1 - y0) / spec.h)]
        mesh = dolfinx.mesh.create_rectangle(
            comm, [np.array([x0, y0]), np.array([x1, y1])], n,
            cell_type=dolfinx.mesh.CellType.triangle, diagonal=dolfinx.mesh.DiagonalType.right,
        )  # fmt: skip
    else:
        mesh = _gmsh_mesh(spec, comm, coarsening_steps(spec), ghosted)
    for k in range(spec.refinements):
        with phase(f"uniform refinement {k + 1}/{spec.refinements}"):
            mesh = refine_uniformly(mesh, ghosted)
    prepare(mesh)
    return mesh
