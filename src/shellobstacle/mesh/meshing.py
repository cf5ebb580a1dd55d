"""Triangle meshes of the parameter domain ω (:class:`~shellobstacle.mesh.domains.DomainSpec`).

Curved and polygonal domains are meshed by gmsh on rank 0 only and distributed over the
communicator by :func:`dolfinx.io.gmsh.model_to_mesh`; a large mesh is gmsh's mesh at a
coarser size, distributed, then refined uniformly in parallel (new boundary nodes moved onto
the curve, :mod:`shellobstacle.mesh.refinement`). Rectangles get a structured DOLFINx mesh. All
meshes are affine (linear) triangles with geometric dimension 2.
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
from shellobstacle.mesh.facet_tags import read_segments, remember
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


def _check_file(model, path: str, segments: dict[int, np.ndarray]) -> str:
    """Merge a .msh file into ``model``, its physical curves into ``segments``
    (:mod:`~shellobstacle.mesh.facet_tags`); return an error message ("" if it is usable)."""
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
    segments.update(read_segments(model))
    _only_the_domain(model)
    return ""


def _only_the_domain(model) -> None:
    """Reduce a read model to what :func:`dolfinx.io.gmsh.model_to_mesh` makes the mesh of:
    the triangles of the 2D physical groups (of every surface if there is none) in one
    physical group, and only the nodes they use, numbered 1..n.

    (``model_to_mesh`` distributes every node of the model, and DOLFINx 0.11 aborts the MPI
    job on a node that no cell uses, such as a circle's centre in a file saved without
    physical groups; it also wants each triangle in exactly one physical group.)
    """
    groups = model.getPhysicalGroups(2)
    surfaces = sorted({int(e) for _, g in groups for e in model.getEntitiesForPhysicalGroup(2, g)})
    surfaces = surfaces or sorted(tag for _, tag in model.getEntities(2))
    for dim, tag in model.getEntities(2):
        if tag not in surfaces:
            model.mesh.removeElements(dim, tag)
    for dim, tag in model.getEntities(1) + model.getEntities(0):
        model.mesh.removeElements(dim, tag)
    model.mesh.reclassifyNodes()  # drops the nodes of no element
    model.removePhysicalGroups()
    model.addPhysicalGroup(2, surfaces, name="domain")
    tags = np.sort(model.mesh.getNodes()[0])
    if len(tags) and tags[-1] != len(tags):  # model_to_mesh wants the node tags 1..n
        model.mesh.renumberNodes(tags, np.arange(1, len(tags) + 1, dtype=tags.dtype))


def _partitioner():
    """Cell partitioner with one layer of facet-sharing ghost cells (as DOLFINx's built-ins)."""
    return dolfinx.mesh.create_cell_partitioner(dolfinx.mesh.GhostMode.shared_facet, 2)


def _coarsened(spec: DomainSpec, steps: int) -> DomainSpec:
    """``spec`` with every mesh size ``2^steps`` times larger."""
    if not steps:
        return spec
    grow = 2.0**steps
    return dataclasses.replace(
        spec,
        h=spec.h * grow,
        central_h=spec.central_h and spec.central_h * grow,
        edge_h=spec.edge_h and spec.edge_h * grow,
    )


def _tagged_triangles(model) -> int:
    """The number of triangles in the 2D physical groups (the cells of the mesh)."""
    groups = model.getPhysicalGroups(2)
    entities = {int(e) for _, g in groups for e in model.getEntitiesForPhysicalGroup(2, g)}
    return sum(len(tags) for e in entities for tags in model.mesh.getElements(2, e)[1])


def _fill_model(model, spec: DomainSpec, steps: int, segments: dict[int, np.ndarray]) -> str:
    """Mesh ``spec`` at ``2^steps`` times its sizes (or read its file, its physical curves
    into ``segments``) into ``model``; return an error message ("" if the model holds a mesh
    for :func:`dolfinx.io.gmsh.model_to_mesh`)."""
    try:
        if spec.kind == "file":
            error = _check_file(model, str(spec.path), segments)
            if error:
                return error
        else:
            _build_model(model, _coarsened(spec, steps))
        if not _tagged_triangles(model):
            return f"gmsh made no triangles for {spec}"
    except Exception as exc:  # let the other ranks fail too instead of hanging
        return f"gmsh failed for {spec}: {exc}"
    return ""


def _gmsh_on_rank0(
    spec: DomainSpec, comm: MPI.Comm, steps: int, stack: contextlib.ExitStack
) -> tuple[object | None, dict[int, np.ndarray]]:
    """The gmsh model of ``spec`` on rank 0 (None on the other ranks), open until ``stack``
    closes, and a file's tagged boundary segments (on every rank).

    Raises:
        ValueError: On every rank, if gmsh fails or the file is unusable.
    """
    model, error, segments = None, "", {}
    if comm.rank == 0:
        options = _gmsh_options(_coarsened(spec, steps))
        model = stack.enter_context(_gmsh_model("shellobstacle-domain", options))
        error = _fill_model(model, spec, steps, segments)
    error, segments = comm.bcast((error, segments), root=0)
    if error:
        raise ValueError(error)
    return model, segments


def _gmsh_mesh(
    spec: DomainSpec, comm: MPI.Comm, steps: int = 0, ghosted: bool = False
) -> dolfinx.mesh.Mesh:
    """Build (or read) the gmsh mesh on rank 0, distribute it
    (:func:`dolfinx.io.gmsh.model_to_mesh`), refine it ``steps`` times."""
    with contextlib.ExitStack() as stack:
        with phase("gmsh"):
            model, segments = _gmsh_on_rank0(spec, comm, steps, stack)
        with phase("distributing the mesh"):
            mesh = dolfinx.io.gmsh.model_to_mesh(model, comm, 0, 2, _partitioner()).mesh
    if segments:
        remember(mesh, segments)
    for k in range(steps):
        with phase(f"refining {k + 1}/{steps}"):
            mesh = red_refinement(mesh, spec, ghosted)  # (it remembers mesh)
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
        The (distributed) mesh, with ``spec.refinements`` uniform refinements applied; it
        remembers the meshes it was refined from
        (:func:`~shellobstacle.mesh.hierarchy.coarser_meshes`).

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
            mesh = refine_uniformly(mesh, ghosted)  # (it remembers mesh)
    prepare(mesh)
    return mesh
