"""Tests of the domains and their meshes: areas, mesh sizes, nested refinement, errors, .msh files.

Only global (allreduced) quantities are asserted, so the ``mpi`` tests hold on any number of
ranks (``mpiexec -n 2 python -m pytest -m mpi``).
"""

import math
import re

# isort: split
from mpi4py import MPI

import dolfinx
import dolfinx.geometry
import dolfinx.mesh
import gmsh
import numpy as np
import pytest

from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.hierarchy import coarser_meshes
from shellobstacle.mesh.measures import (
    boundary_facets,
    domain_area,
    mesh_size,
    mesh_size_min,
    num_cells_global,
)
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.mesh.refinement import refine_uniformly

COMM = MPI.COMM_WORLD
L_SHAPE = ((0.0, 0.0), (1.0, 0.0), (1.0, 0.5), (0.5, 0.5), (0.5, 1.0), (0.0, 1.0))


def _chord_deficit(curvature: float, length: float, h: float) -> float:
    """Upper bound of the area lost by an inscribed polygon with chords no longer than h.

    A chord of length s cutting a boundary arc of curvature ≤ κ removes a segment of area
    ≤ κ s³ / 12 (1 + O(κ s)); summed over the arcs (Σ s ≤ length) this is κ h² length / 12.
    A 10% margin covers the O(κ h) terms for the κ h ≤ 0.7 used here.
    """
    return 1.1 * curvature * h**2 * length / 12.0


def _num_boundary_facets_global(mesh) -> int:
    owned = mesh.topology.index_map(mesh.topology.dim - 1).size_local
    return COMM.allreduce(int(np.sum(boundary_facets(mesh) < owned)), op=MPI.SUM)


def _extent(mesh) -> np.ndarray:
    """Global max |x|, max |y| of the mesh nodes."""
    local = np.abs(mesh.geometry.x[:, :2]).max(axis=0, initial=0.0)
    return np.array([COMM.allreduce(float(v), op=MPI.MAX) for v in local])


@pytest.mark.mpi
def test_disk_area_mesh_size_and_nested_refinement():
    r, h = 0.5, 0.1
    mesh = create_mesh(DomainSpec("disk", h, radius=r, center=(0.2, -0.1)))
    assert mesh.geometry.dim == 2 and mesh.topology.dim == 2
    assert mesh.ufl_domain().geometric_dimension == 2
    H = mesh_size(mesh)
    assert 0.8 * h <= H <= 2.0 * h
    area = domain_area(mesh)
    # inscribed polygon (boundary nodes on the circle): 0 < πr² - area ≤ π h²/6 for H ≤ h
    assert 0.0 < math.pi * r**2 - area <= _chord_deficit(1 / r, 2 * math.pi * r, H)

    fine = refine_uniformly(mesh)
    assert fine.geometry.dim == 2 and fine.ufl_domain().geometric_dimension == 2
    assert mesh_size(fine) == pytest.approx(H / 2, rel=1e-12)
    assert mesh_size_min(fine) == pytest.approx(mesh_size_min(mesh) / 2, rel=1e-12)
    assert num_cells_global(fine) == 4 * num_cells_global(mesh)
    assert _num_boundary_facets_global(fine) == 2 * _num_boundary_facets_global(mesh)
    # midpoints of boundary chords stay on the chords: nested meshes, same polygon
    assert domain_area(fine) == pytest.approx(area, rel=1e-12)
    # every uniform refinement remembers its coarser meshes (multigrid's levels), the
    # experiments' nested meshes too, not only create_mesh's
    assert coarser_meshes(refine_uniformly(fine)) == [mesh, fine]
    assert coarser_meshes(mesh) == []

    twice = create_mesh(DomainSpec("disk", h, radius=r, center=(0.2, -0.1), refinements=2))
    assert num_cells_global(twice) == 16 * num_cells_global(mesh)
    assert mesh_size(twice) == pytest.approx(H / 4, rel=1e-12)


@pytest.mark.mpi
def test_a_ghosted_refinement_keeps_children_on_their_parents_rank():
    """Koiter's meshes: the refined mesh has facet-sharing ghost cells and remembers the
    coarse mesh, whose owned cells hold every owned fine cell (multigrid's levels
    interpolate rank by rank), and the ghosts are exactly the neighbours across ranks."""
    spec = DomainSpec("disk", 0.1, radius=0.5, refinements=2)
    fine = create_mesh(spec, ghosted=True)
    levels = coarser_meshes(fine)
    assert len(levels) == 2
    tdim = 2
    for coarse, child in ((levels[0], levels[1]), (levels[1], fine)):
        assert num_cells_global(child) == 4 * num_cells_global(coarse)
        owned = child.topology.index_map(tdim).size_local
        mid = dolfinx.mesh.compute_midpoints(child, tdim, np.arange(owned, dtype=np.int32))
        parents = coarse.topology.index_map(tdim).size_local
        tree = dolfinx.geometry.bb_tree(coarse, tdim, entities=np.arange(parents, dtype=np.int32))
        hits = dolfinx.geometry.compute_colliding_cells(
            coarse, dolfinx.geometry.compute_collisions_points(tree, mid), mid
        )
        assert np.all(np.diff(hits.offsets) > 0)  # each owned child in an owned parent
        if COMM.size > 1:
            # every facet of an owned cell has both its cells here but on ∂ω: the ghosts
            child.topology.create_connectivity(tdim, tdim - 1)
            child.topology.create_connectivity(tdim - 1, tdim)
            c2f, f2c = (
                child.topology.connectivity(tdim, tdim - 1),
                child.topology.connectivity(tdim - 1, tdim),
            )
            facets = np.unique(c2f.array.reshape(-1, 3)[:owned])
            interior = np.setdiff1d(facets, boundary_facets(child))
            assert np.all(np.diff(f2c.offsets)[interior] == 2)
            ghosts = child.topology.index_map(tdim).num_ghosts
            assert COMM.allreduce(ghosts) > 0


def test_disk_area_converges_quadratically():
    errors = [math.pi / 4 - domain_area(create_mesh(DomainSpec("disk", h))) for h in (0.1, 0.05)]
    assert 3.0 < errors[0] / errors[1] < 5.5


def test_rectangle_structured():
    (x0, y0), (x1, y1) = corners = ((-1.0, 0.5), (2.0, 1.5))
    h = 0.22
    mesh = create_mesh(DomainSpec("rectangle", h, corners=corners))
    nx, ny = math.ceil(3.0 / h), math.ceil(1.0 / h)
    assert num_cells_global(mesh) == 2 * nx * ny
    assert domain_area(mesh) == pytest.approx((x1 - x0) * (y1 - y0), rel=1e-12)
    assert mesh_size(mesh) == pytest.approx(math.hypot(3.0 / nx, 1.0 / ny), rel=1e-12)
    assert _num_boundary_facets_global(mesh) == 2 * (nx + ny)


@pytest.mark.parametrize("orientation", [1, -1])
def test_l_shaped_polygon_area_exact(orientation):
    h = 0.05
    mesh = create_mesh(DomainSpec("polygon", h, vertices=L_SHAPE[::orientation]))
    assert domain_area(mesh) == pytest.approx(0.75, rel=1e-12)
    assert 0.8 * h <= mesh_size(mesh) <= 2.0 * h


@pytest.mark.parametrize("semi_axes", [(0.6, 0.3), (0.3, 0.6)])
def test_ellipse_area_and_orientation(semi_axes):
    a, b = semi_axes
    mesh = create_mesh(DomainSpec("ellipse", 0.05, semi_axes=semi_axes))
    H = mesh_size(mesh)
    curvature, perimeter = max(a, b) / min(a, b) ** 2, 2 * math.pi * max(a, b)
    assert 0.0 < math.pi * a * b - domain_area(mesh) <= _chord_deficit(curvature, perimeter, H)
    # the major vertices are nodes; the minor ones lie within a chord's sagitta of nodes
    assert _extent(mesh) == pytest.approx([a, b], rel=1e-2)
    assert _extent(mesh).argmax() == int(b > a)


def test_central_refinement():
    h, central_h, rho = 0.05, 0.005, 0.05
    spec = DomainSpec("disk", h, center=(0.1, 0.0), central_h=central_h, central_radius=rho)
    mesh = create_mesh(spec)
    assert mesh_size_min(mesh) < 0.2 * h
    assert mesh_size(mesh) <= 2.0 * h
    # every cell whose midpoint lies in the central zone is of size ~ central_h
    tdim = mesh.topology.dim
    owned = np.arange(mesh.topology.index_map(tdim).size_local, dtype=np.int32)
    dofs = mesh.geometry.dofmaps[0][owned]
    mid = mesh.geometry.x[dofs, :2].mean(axis=1)
    inside = np.linalg.norm(mid - np.array(spec.center), axis=1) < rho
    local = mesh.h(tdim, owned[inside]).max(initial=0.0)
    assert COMM.allreduce(float(local), op=MPI.MAX) <= 2.0 * central_h
    assert COMM.allreduce(int(inside.sum()), op=MPI.SUM) > math.pi * rho**2 / central_h**2
    assert domain_area(mesh) == pytest.approx(math.pi / 4, rel=1e-2)


def test_edge_grading():
    """Cells within edge_width of γ have about edge_h; the interior keeps h."""
    h, edge_h, width = 0.08, 0.01, 0.04
    mesh = create_mesh(DomainSpec("disk", h, radius=0.5, edge_h=edge_h, edge_width=width))
    tdim = mesh.topology.dim
    owned = np.arange(mesh.topology.index_map(tdim).size_local, dtype=np.int32)
    dofs = mesh.geometry.dofmaps[0][owned]
    to_edge = 0.5 - np.linalg.norm(mesh.geometry.x[dofs, :2].mean(axis=1), axis=1)
    band = mesh.h(tdim, owned[to_edge < width]).max(initial=0.0)
    assert COMM.allreduce(float(band), op=MPI.MAX) <= 2.0 * edge_h
    assert mesh_size(mesh) > 4 * edge_h
    assert domain_area(mesh) == pytest.approx(math.pi / 4, rel=1e-3)


def _spec(*args, **kwargs):
    """The arguments of a DomainSpec, made inside the test."""
    return args, kwargs


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (_spec("square", 0.1), "domain.kind = 'square' is not one of 'disk', 'ellipse'"),
        (_spec("disk", 0.0), "domain.h must be > 0, got 0.0"),
        (_spec("disk", -0.1), "domain.h must be > 0, got -0.1"),
        (_spec("disk", None), "[domain] needs 'h' (target mesh size) for kind = 'disk'"),
        (_spec("disk", 1.5, radius=0.5), "exceeds the domain's diameter"),
        (_spec("polygon", 0.1), "polygon needs vertices"),
        (_spec("polygon", 0.1, vertices=((0, 0), (1, 0))), "at least 3 vertices"),
        (_spec("polygon", 0.1, vertices=((0, 0), (2, 2), (2, 0), (0, 1))), "must be simple"),
        (_spec("polygon", 0.1, vertices=((0, 0), (2, 0), (1, 0), (1, 1))), "must be simple"),
        (_spec("ellipse", 0.1), "ellipse needs semi_axes"),
        (_spec("rectangle", 0.1), "rectangle needs corners"),
        (_spec("file"), "needs path"),
        (_spec("disk", 0.1, central_h=0.01), "must be given together"),
        (_spec("disk", 0.1, edge_h=0.01), "edge_h and edge_width must be given together"),
        (_spec("disk", 0.1, edge_h=0.2, edge_width=0.1), "need 0 < edge_h <= h"),
        (_spec("disk", 0.1, refinements=-1), "domain.refinements must be in 0..8"),
    ],
)
def test_bad_specs_raise(kwargs, message):
    """A spec is validated when it is made (the Python API), with the config's messages."""
    with pytest.raises(ValueError, match=re.escape(message)):
        DomainSpec(*kwargs[0], **kwargs[1])


@pytest.mark.mpi
def test_missing_file_raises_on_all_ranks(tmp_path):
    path = COMM.bcast(str(tmp_path / "nowhere.msh"), root=0)
    with pytest.raises(ValueError, match=r"nowhere\.msh' does not exist"):
        create_mesh(DomainSpec("file", path=path))


def _write_rectangle_msh(path: str, physical: bool = True, **options: float) -> None:
    """Rank 0 writes the rectangle [0, 2] x [0, 1] meshed by gmsh to ``path``."""
    if COMM.rank == 0:
        gmsh.initialize(readConfigFiles=False, interruptible=False)
        gmsh.option.setNumber("General.Terminal", 0)
        for key, value in {"Mesh.MeshSizeMax": 0.2, **options}.items():
            gmsh.option.setNumber(key, value)
        gmsh.model.add("writer")
        surface = gmsh.model.occ.addRectangle(0, 0, 0, 2, 1)
        gmsh.model.occ.synchronize()
        if physical:
            gmsh.model.addPhysicalGroup(2, [surface], 7, name="plate")
        gmsh.model.mesh.generate(2)
        gmsh.write(path)
        gmsh.finalize()
    COMM.barrier()


@pytest.mark.mpi
@pytest.mark.parametrize("physical", [True, False])
def test_msh_file_roundtrip(tmp_path, physical):
    path = COMM.bcast(str(tmp_path / "plate.msh"), root=0)
    _write_rectangle_msh(path, physical=physical)
    mesh = create_mesh(DomainSpec("file", path=path, refinements=1))
    assert mesh.geometry.dim == 2 and mesh.geometry.x.shape[1] == 3
    assert domain_area(mesh) == pytest.approx(2.0, rel=1e-12)
    assert 0.05 < mesh_size(mesh) < 0.2
    assert _extent(mesh) == pytest.approx([2.0, 1.0], rel=1e-12)


def _write_two_surfaces_msh(path: str, groups: list[list[int]], save_all: bool) -> int:
    """Rank 0 writes the rectangle [0, 2] x [0, 1] (surface 1), a disk beside it (surface 2)
    and a lone point (a node of no triangle), with 2D physical ``groups`` of surfaces; return
    (on every rank) how many nodes the triangles of the groups (of all surfaces if none) use."""
    used = 0
    if COMM.rank == 0:
        gmsh.initialize(readConfigFiles=False, interruptible=False)
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.2)
        gmsh.option.setNumber("Mesh.SaveAll", int(save_all))
        gmsh.model.add("writer")
        gmsh.model.occ.addRectangle(0, 0, 0, 2, 1)
        gmsh.model.occ.addDisk(4, 0, 0, 0.5, 0.5)
        gmsh.model.occ.addPoint(9, 9, 0)
        gmsh.model.occ.synchronize()
        for group in groups:
            gmsh.model.addPhysicalGroup(2, group)
        gmsh.model.mesh.generate(2)
        marked = sorted({s for group in groups for s in group}) or [1, 2]
        used = len({int(n) for s in marked for n in gmsh.model.mesh.getElements(2, s)[2][0]})
        gmsh.write(path)
        gmsh.finalize()
    return COMM.bcast(used, root=0)


@pytest.mark.mpi
@pytest.mark.parametrize(
    ("groups", "save_all", "area"),
    [
        ([], False, None),  # unmarked: every surface; the lone point's node is in the file
        ([[1]], True, 2.0),  # the disk's triangles and nodes are in the file, unmarked
        ([[1], [1]], False, 2.0),  # the rectangle in two groups
    ],
    ids=["unmarked", "one-of-two-marked", "marked-twice"],
)
def test_msh_file_mesh_is_the_marked_triangles(tmp_path, groups, save_all, area):
    path = COMM.bcast(str(tmp_path / "two.msh"), root=0)
    used = _write_two_surfaces_msh(path, groups, save_all)
    mesh = create_mesh(DomainSpec("file", path=path))
    assert mesh.topology.index_map(0).size_global == used
    if area is not None:
        assert domain_area(mesh) == pytest.approx(area, rel=1e-12)
    else:  # the rectangle and the disk's inscribed polygon
        assert 2.0 < domain_area(mesh) < 2.0 + math.pi / 4


@pytest.mark.parametrize(
    ("options", "found"),
    [({"Mesh.RecombineAll": 1}, "Quadrilateral"), ({"Mesh.ElementOrder": 2}, "Triangle 6")],
)
def test_msh_file_not_linear_triangles(tmp_path, options, found):
    path = COMM.bcast(str(tmp_path / "plate.msh"), root=0)
    _write_rectangle_msh(path, **options)
    with pytest.raises(ValueError, match=f"not made of linear triangles.*{found}"):
        create_mesh(DomainSpec("file", path=path))


def test_silent_and_leaves_a_users_gmsh_session_alone(capfd):
    create_mesh(DomainSpec("disk", 0.2))
    assert not gmsh.isInitialized()
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("mine")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 3.0)
        create_mesh(DomainSpec("polygon", 0.2, vertices=L_SHAPE))
        assert gmsh.isInitialized()
        assert gmsh.model.getCurrent() == "mine"
        assert gmsh.option.getNumber("Mesh.MeshSizeMax") == 3.0
    finally:
        gmsh.finalize()
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def _boundary_points(mesh) -> np.ndarray:
    import dolfinx

    nodes = np.unique(dolfinx.mesh.entities_to_geometry(mesh, 1, boundary_facets(mesh)).ravel())
    return mesh.geometry.x[nodes, :2]


@pytest.mark.mpi
@pytest.mark.parametrize(
    "spec",
    [
        DomainSpec(kind="disk", h=0.02, radius=0.5, center=(0.1, -0.2)),
        DomainSpec(kind="ellipse", h=0.02, semi_axes=(0.6, 0.3)),
        DomainSpec(kind="polygon", h=0.02, vertices=L_SHAPE),
    ],
    ids=["disk", "ellipse", "polygon"],
)
def test_large_meshes_are_refined_coarse_gmsh_meshes(spec: DomainSpec):
    """Above gmsh_max_vertices: gmsh at 2^k h, k uniform refinements, boundary on the curve."""
    import dataclasses

    direct = create_mesh(dataclasses.replace(spec, gmsh_max_vertices=0))
    n_direct = direct.topology.index_map(0).size_global
    refined = create_mesh(dataclasses.replace(spec, gmsh_max_vertices=n_direct // 10))
    n_refined = refined.topology.index_map(0).size_global
    # k = 2 refinements of a mesh of size 4h: about as many vertices and the same h
    assert 0.8 < n_refined / n_direct < 1.25
    assert 0.75 < mesh_size(refined) / mesh_size(direct) < 1.33
    # every boundary vertex lies on the boundary curve (chord midpoints were moved onto it)
    x = _boundary_points(refined)
    if spec.kind == "disk":
        off = np.abs(np.linalg.norm(x - np.array(spec.center), axis=1) - spec.radius)
    elif spec.kind == "ellipse":
        a, b = spec.semi_axes
        off = np.abs(np.hypot(x[:, 0] / a, x[:, 1] / b) - 1.0)
    else:  # polygon: new vertices at edge midpoints are on the edges already
        off = np.zeros(0)
    assert COMM.allreduce(float(off.max(initial=0.0)), op=MPI.MAX) < 1e-14
    assert domain_area(refined) == pytest.approx(domain_area(direct), rel=2e-4)


def _global_cells(mesh) -> np.ndarray:
    """Every cell as its three node coordinates (sorted), gathered from all ranks, sorted."""
    n = mesh.topology.index_map(2).size_local
    x = mesh.geometry.x[mesh.geometry.dofmaps[0][:n], :2]  # (cells, 3 nodes, 2)
    return _sorted_cells(np.concatenate(COMM.allgather(x)))


def _sorted_cells(x: np.ndarray) -> np.ndarray:
    """Cells ``(m, 3, 2)`` with their nodes and then the cells in lexicographic order."""
    x = np.take_along_axis(x, np.lexsort((x[:, :, 1], x[:, :, 0]), axis=1)[:, :, None], axis=1)
    flat = x.reshape(len(x), 6)
    return flat[np.lexsort(flat.T[::-1])]


def _red_refinement_of_arrays(x: np.ndarray, cells: np.ndarray, spec: DomainSpec):
    """Reference: one red refinement of a triangle list (edge midpoints, four children per
    cell), the midpoints of boundary edges moved radially onto the disk's or ellipse's curve."""
    pairs = np.sort(cells[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, inverse, count = np.unique(pairs, axis=0, return_inverse=True, return_counts=True)
    mid = 0.5 * (x[edges[:, 0]] + x[edges[:, 1]])
    if spec.kind in ("disk", "ellipse"):
        on_boundary = count == 1
        c = np.asarray(spec.center)
        a, b = (spec.radius, spec.radius) if spec.kind == "disk" else spec.semi_axes
        d = mid[on_boundary] - c
        mid[on_boundary] = c + d / np.hypot(d[:, 0] / a, d[:, 1] / b)[:, None]
    m = len(x) + inverse.reshape(-1, 3)  # midpoints of the edges 01, 12, 20
    v0, v1, v2 = cells.T
    children = [(v0, m[:, 0], m[:, 2]), (m[:, 0], v1, m[:, 1]), (m[:, 2], m[:, 1], v2)]
    fine = np.vstack([np.column_stack(c) for c in children] + [m])
    return np.vstack([x, mid]), fine


@pytest.mark.mpi
@pytest.mark.parametrize(
    "spec",
    [
        DomainSpec(kind="disk", h=0.03, radius=0.5, center=(0.1, -0.2)),
        DomainSpec(kind="ellipse", h=0.03, semi_axes=(0.6, 0.3), center=(0.05, 0.0)),
        DomainSpec(kind="polygon", h=0.03, vertices=L_SHAPE),
    ],
    ids=["disk", "ellipse", "polygon"],
)
def test_large_mesh_is_the_coarse_gmsh_mesh_refined_twice(spec: DomainSpec):
    """gmsh at 4h, distributed and refined twice in parallel = the same gmsh triangles refined
    twice as arrays on one rank, new boundary nodes moved radially onto the curve: the same
    cells, node for node."""
    import dataclasses

    import dolfinx.io.gmsh

    from shellobstacle.mesh import meshing as domains

    coarse_spec = dataclasses.replace(spec, h=4 * spec.h, gmsh_max_vertices=0)
    with domains._gmsh_model("reference", domains._gmsh_options(coarse_spec)) as model:
        domains._build_model(model, coarse_spec)
        x = dolfinx.io.gmsh.extract_geometry(model)[:, :2]
        cells = dolfinx.io.gmsh.extract_topology_and_markers(model)[0][2]["topology"]
        cells = cells.astype(np.int64)
    for _ in range(2):
        x, cells = _red_refinement_of_arrays(x, cells, spec)
    expected = _sorted_cells(x[cells])
    refined = create_mesh(dataclasses.replace(spec, gmsh_max_vertices=2 * len(x) // 16))  # k = 2
    got = _global_cells(refined)
    assert got.shape == expected.shape == (16 * num_cells_global(create_mesh(coarse_spec)), 6)
    assert np.abs(got - expected).max() < 1e-15


def test_gmsh_max_vertices_must_not_be_negative():
    with pytest.raises(ValueError, match="gmsh_max_vertices must be >= 0"):
        create_mesh(DomainSpec(kind="disk", h=0.1, gmsh_max_vertices=-1))


@pytest.mark.mpi
def test_a_mesh_too_large_for_the_machine_is_refused_on_every_rank(monkeypatch) -> None:
    """require_fits raises the same one-line ResourceError on every rank (the ranks on this
    machine need their share of the run's memory); what fits passes everywhere."""
    from shellobstacle.mesh import memory, resources

    monkeypatch.setattr(memory, "machine_memory", lambda: 2.0**30)
    spec = DomainSpec("disk", 0.002)  # about 2.3e5 vertices, 7e5 dofs: 2.2 GiB
    with pytest.raises(resources.ResourceError) as caught:
        resources.require_fits(spec)
    messages = COMM.allgather(str(caught.value))
    assert len(set(messages)) == 1 and "of its 1 GiB" in messages[0]
    assert "\n" not in messages[0]
    assert resources.require_fits(DomainSpec("disk", 0.1)) is not None
