"""The ParaView files, read back: every ``.bp`` a solve writes holds the solution.

Each VTX folder is read with the ADIOS2 Python bindings (the ``test`` extra; in a process of
their own, see :data:`READER`), block by block (one block per writing rank, its owned and ghost
nodes), and its points are matched by their
coordinates to the solution gathered from every rank: ζ at the nodes, ``U = ζ_i a^i`` and
``g = (θ + U)·q`` evaluated again with the NumPy geometry (not the UFL expressions the writer
uses), the contact flags ``g ≤`` the contact tolerance and the exact solver's contact pressure.
The cells must tile ω once. Serially and, ``mpi``-marked, from 2 ranks (``./run test``).

The problem is the paper's cap pushed onto the plane on the square [-0.25, 0.25]²: P1 with
Newton at κ = 1e-3 (vertex penalty), P1 with the exact active-set solver (which adds the
contact pressure), and P2 with Newton (which adds ``parameter_domain_p2.bp``).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.mesh
import numpy as np
import pytest
from conftest import cap_on_square

from shellobstacle.io.paraview import write_paraview
from shellobstacle.post.contact import Postprocessor
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.solvers.vi.active_set import ActiveSetSolver

COMM = MPI.COMM_WORLD
HALF, N = 0.25, 12
CASES = ("p1-newton", "p1-active-set", "p2-newton")
ATOL = 1e-13  # the writer's U and g come from UFL expressions, the test's from NumPy


def _key(y: np.ndarray) -> list[tuple[float, float]]:
    """Coordinates (y1, y2) as dictionary keys (rounded far below the mesh size)."""
    return [(round(float(a), 12), round(float(b), 12)) for a, b in np.asarray(y)[:, :2]]


def _gather_nodal(f: dolfinx.fem.Function) -> dict[tuple[float, float], np.ndarray]:
    """``f`` at the coordinates of its owned dofs, from every rank (the same on all)."""
    space = f.function_space
    n = space.dofmap.index_map.size_local
    bs = space.dofmap.index_map_bs
    y = space.tabulate_dof_coordinates()[:n]
    values = f.x.array.reshape(-1, bs)[:n].copy()
    parts = COMM.allgather((y, values))
    return {k: v for y, vals in parts for k, v in zip(_key(y), vals, strict=True)}


#: reads a one-step VTX folder (argv[1]) into an .npz (argv[2]), block by block; it runs in a
#: process of its own because the ``adios2`` wheel's libraries have the sonames of the ones in
#: the DOLFINx wheel (``libadios2_core.so.2.12``): loaded first, they break DOLFINx's import
READER = """
import sys
import adios2
import numpy as np

out = {}
with adios2.FileReader(sys.argv[1]) as f:
    out["steps"] = np.array(f.num_steps())
    names = sorted(f.available_variables())
    out["names"] = np.array(names)
    blocks = len(f.all_blocks_info("geometry")[0])
    out["blocks"] = np.array(blocks)
    for b in range(blocks):
        for name in names:
            if name in ("NumberOfNodes", "NumberOfEntities", "step"):
                continue
            out[f"{name}/{b}"] = f.read(name, block_id=b)
    out["NumberOfNodes"] = np.atleast_1d(f.read("NumberOfNodes"))
    out["NumberOfEntities"] = np.atleast_1d(f.read("NumberOfEntities"))
with open(sys.argv[2], "wb") as target:
    np.savez(target, **out)
"""


def _read(path: Path) -> dict[str, np.ndarray]:
    """Every variable of a one-step VTX folder: the points' arrays restricted to the owned
    points of each block (ghost type 0), the cells as the ``vtkOriginalPointIds`` of their
    vertices."""
    assert path.is_dir(), f"{path} was not written"
    dump = path.with_name(path.name + ".npz")
    subprocess.run([sys.executable, "-c", READER, str(path), str(dump)], check=True, timeout=120)
    with np.load(dump) as npz:
        raw = {k: npz[k] for k in npz.files}
    dump.unlink()
    assert int(raw["steps"]) == 1
    blocks = int(raw["blocks"])
    assert len(raw["NumberOfNodes"]) == len(raw["NumberOfEntities"]) == blocks
    structural = {"NumberOfNodes", "NumberOfEntities", "connectivity", "types", "step"}
    point_names = set(raw["names"].tolist()) - structural
    out: dict[str, list[np.ndarray]] = {}
    cells: list[np.ndarray] = []
    for b in range(blocks):
        ghost = raw[f"vtkGhostType/{b}"].ravel()
        assert len(ghost) == raw["NumberOfNodes"][b]
        ids = raw[f"vtkOriginalPointIds/{b}"].ravel()
        owned = ghost == 0
        for name in point_names:
            out.setdefault(name, []).append(raw[f"{name}/{b}"].reshape(len(ghost), -1)[owned])
        connectivity = raw[f"connectivity/{b}"].reshape(raw["NumberOfEntities"][b], -1)
        assert np.all(connectivity[:, 0] == connectivity.shape[1] - 1)  # nodes per cell
        assert connectivity.shape[1] - 1 in (3, 6)  # P1 or P2 triangles
        assert np.all(raw[f"types/{b}"] == 69)  # VTK_LAGRANGE_TRIANGLE
        cells.append(ids[connectivity[:, 1:4]])  # the vertices come first
    result = {name: np.concatenate(parts) for name, parts in out.items()}
    result["cells"] = np.concatenate(cells)
    result["blocks"] = np.array(blocks)
    return result


@pytest.fixture(scope="module", params=CASES)
def written(request, tmp_path_factory) -> dict:
    """One solve per case, written with :func:`write_paraview` as ``solve`` writes it."""
    case = request.param
    problem = cap_on_square(HALF, N, degree=2 if case.startswith("p2") else 1)
    extra = []
    if case.endswith("active-set"):
        result = ActiveSetSolver(problem).solve()
        assert result.converged
        pressure = result.contact_pressure.copy()
        pressure.name = "contact_pressure"
        extra.append(pressure)
    else:
        assert NewtonSolver(problem).solve().converged
    post = Postprocessor(problem)
    folder = Path(COMM.bcast(str(tmp_path_factory.mktemp(case)), root=0))
    paths = write_paraview(problem, post, folder, extra)
    return {
        "case": case,
        "problem": problem,
        "post": post,
        "folder": folder,
        "paths": paths,
        "zeta": _gather_nodal(problem.zeta),
        "pressure": _gather_nodal(extra[0]) if extra else None,
        "tol": post.tolerance(),
        "contact_nodes": post.contact()["num_contact_nodes"],
        "indicator": _gather_nodal(post.indicator()),
    }


def _expected(written: dict, y: np.ndarray) -> dict[str, np.ndarray]:
    """ζ, θ, U = ζ_i a^i and g = (θ + U)·q at the points ``y`` of ω, from the gathered ζ."""
    problem = written["problem"]
    zeta = np.array([written["zeta"][k] for k in _key(y)])
    G = problem.shell.surface.geometry_numpy(y)
    theta = np.column_stack([np.broadcast_to(t, len(y)) for t in G.theta])
    U = np.column_stack([np.broadcast_to(u, len(y)) for u in G.cartesian(list(zeta.T))])
    gap = (theta + U) @ np.asarray(problem.q)
    return {"zeta": zeta, "theta": theta, "U": U, "gap": gap}


@pytest.mark.mpi
def test_a_solve_writes_these_folders(written) -> None:
    names = [p.name for p in written["paths"]]
    expected = ["parameter_domain.bp", "surface.bp", "deformed_surface.bp"]
    if written["case"].startswith("p2"):
        expected.insert(1, "parameter_domain_p2.bp")
    assert names == expected
    on_disk = sorted(p.name for p in written["folder"].iterdir())
    assert on_disk == sorted(expected)  # no temporary folder left


def _check_vertices(written: dict, data: dict, y: np.ndarray) -> None:
    """The vertex fields of a P1 file against the solution at the vertices ``y``."""
    problem, post = written["problem"], written["post"]
    n_vertices = post.P1.dofmap.index_map.size_global  # (rank 0 only: nothing collective)
    assert len(y) == n_vertices  # every vertex once over the blocks
    assert len(set(_key(y))) == n_vertices
    exp = _expected(written, y)
    assert data["U"].shape == (n_vertices, 3) and data["gap"].shape == (n_vertices, 1)
    assert np.allclose(data["U"], exp["U"], rtol=0, atol=ATOL)
    assert np.allclose(data["gap"].ravel(), exp["gap"], rtol=0, atol=ATOL)
    contact = data["contact"].ravel()
    assert np.array_equal(contact, np.array([written["indicator"][k] for k in _key(y)]).ravel())
    if problem.disc.degree == 1:  # measured at the vertices: 1 on the contact vertices
        assert set(np.unique(contact)) <= {0.0, 1.0}
        assert np.array_equal(contact == 1.0, exp["gap"] <= written["tol"])
        assert int(contact.sum()) == written["contact_nodes"] > 0
    else:  # at the Gauss points, lumped onto the vertices
        assert np.all((contact >= 0.0) & (contact <= 1.0)) and contact.max() == 1.0
        assert written["contact_nodes"] > 0
    if "zeta" in data:  # copied for P1; the P2 field interpolated at the vertices
        if problem.disc.degree == 1:
            assert np.array_equal(data["zeta"], exp["zeta"])
        assert np.allclose(data["zeta"], exp["zeta"], rtol=0, atol=ATOL)
    if written["pressure"] is not None:
        pressure = data["contact_pressure"].ravel()
        expected = np.array([written["pressure"][k] for k in _key(y)]).ravel()
        assert np.array_equal(pressure, expected)
        assert pressure.max() > 0.0 and np.all(contact[pressure > 0.0] == 1.0)
    else:
        assert "contact_pressure" not in data
    # the cells: every triangle of ω once (no rank writes its ghost cells), tiling it
    assert len(data["cells"]) == 2 * N * N
    assert len({tuple(sorted(c)) for c in data["cells"].tolist()}) == 2 * N * N


def _tiles(points_by_id: dict[int, np.ndarray], cells: np.ndarray) -> float:
    """The summed areas (in the (y1, y2) plane) of the cells."""
    a, b, c = (np.array([points_by_id[i] for i in cells[:, k]]) for k in range(3))
    u, v = b - a, c - a
    return float(np.sum(0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])))


@pytest.mark.mpi
def test_parameter_domain_holds_the_solution_at_the_vertices(written) -> None:
    if COMM.rank != 0:
        return
    data = _read(written["folder"] / "parameter_domain.bp")
    assert int(data["blocks"]) == COMM.size
    y = data["geometry"]
    assert np.all(y[:, 2] == 0.0)  # the flat parameter domain
    _check_vertices(written, data, y)
    exp = _expected(written, y)
    assert np.allclose(data["position"], exp["theta"], rtol=0, atol=ATOL)
    assert np.allclose(data["deformed_position"], exp["theta"] + exp["U"], rtol=0, atol=ATOL)
    ids = data["vtkOriginalPointIds"].ravel()
    assert _tiles(dict(zip(ids.tolist(), y[:, :2], strict=True)), data["cells"]) == (
        pytest.approx((2 * HALF) ** 2, rel=1e-12)
    )


@pytest.mark.mpi
def test_the_surfaces_are_theta_and_theta_plus_u(written) -> None:
    """surface.bp: nodes at θ(y) with ζ, U, g, contact; deformed_surface.bp: the same nodes
    (the same original ids) moved to θ + U, with U, g and contact."""
    if COMM.rank != 0:
        return
    surface = _read(written["folder"] / "surface.bp")
    deformed = _read(written["folder"] / "deformed_surface.bp")
    # θ = (y1, y2, f(y)) for the spherical cap: y is read off the reference surface
    y = surface["geometry"][:, :2]
    exp = _expected(written, y)
    assert np.allclose(surface["geometry"], exp["theta"], rtol=0, atol=ATOL)
    _check_vertices(written, surface, y)
    assert "position" not in surface and "zeta" not in deformed
    # the same points in the same blocks, moved by U
    assert np.array_equal(deformed["vtkOriginalPointIds"], surface["vtkOriginalPointIds"])
    assert np.array_equal(deformed["cells"], surface["cells"])
    assert np.allclose(deformed["geometry"], exp["theta"] + exp["U"], rtol=0, atol=ATOL)
    no_pressure = dict(written, pressure=None)
    _check_vertices(no_pressure, deformed, y)
    ids = surface["vtkOriginalPointIds"].ravel()
    assert _tiles(dict(zip(ids.tolist(), y, strict=True)), surface["cells"]) == pytest.approx(
        (2 * HALF) ** 2, rel=1e-12
    )


@pytest.mark.mpi
def test_the_p2_file_holds_zeta_at_every_p2_node(written) -> None:
    if not written["case"].startswith("p2"):
        assert not (written["folder"] / "parameter_domain_p2.bp").exists()
        return
    if COMM.rank != 0:
        return
    data = _read(written["folder"] / "parameter_domain_p2.bp")
    y = data["geometry"]
    n_dofs = len(written["zeta"])  # vertices and edge midpoints
    assert y.shape == (n_dofs, 3) and np.all(y[:, 2] == 0.0)
    assert set(_key(y)) == set(written["zeta"])
    exp = _expected(written, y)
    assert np.array_equal(data["zeta"], exp["zeta"])
    assert np.allclose(data["U"], exp["U"], rtol=0, atol=ATOL)
    assert np.allclose(data["position"], exp["theta"], rtol=0, atol=ATOL)
    assert np.allclose(data["deformed_position"], exp["theta"] + exp["U"], rtol=0, atol=ATOL)
    assert set(data) >= {"zeta", "U", "position", "deformed_position"}
    assert "gap" not in data  # the vertex fields are in parameter_domain.bp
    assert len(data["cells"]) == 2 * N * N  # each cell once
