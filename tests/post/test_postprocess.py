"""Post-processing: nodal gap, contact set and areas, norms, cross-sections, PNG and VTX output.

The contact problem is the paper's (docs/model.md §7: spherical cap R = 1 offset 0.85, ε = 0.001,
λ = 0.4, μ = 0.012, the load pushing the top of the cap onto the plane) on the square
[-0.25, 0.25]², with the nodal (vertex) penalty so that the vertex gap is what the penalty
controls. Only global quantities are asserted, so the ``mpi`` tests hold on any number of
ranks (``mpiexec -n 2 python -m pytest -m mpi tests/post/test_postprocess.py``).
"""

import itertools
import math
from pathlib import Path

# isort: split
from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.mesh
import numpy as np
import pytest
import ufl
from conftest import PAPER_LOAD, make_paper_shell, square

from shellobstacle.geometry.surface import dot
from shellobstacle.io.paraview import SurfaceMesh, write_paraview
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.norms import h1_norm, l2_norm, norms, vm_norm
from shellobstacle.post.plotting import plot_cross_section
from shellobstacle.post.sections import cross_section
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.spec import Discretization, Shell

COMM = MPI.COMM_WORLD
HALF = 0.25  # ω = [-HALF, HALF]²
N = 20  # cells per side
# the paper's load (docs/model.md §7) times a sign s: s = 1 pushes the cap down, s = -1 pulls it up
SIGNED_LOAD = f"s*{PAPER_LOAD}"
KAPPAS = (1e-2, 1e-3, 1e-4)


def _shell(load: str = SIGNED_LOAD, **parameters: float) -> Shell:
    return make_paper_shell(load, parameters=parameters)


def _shared_dir(tmp_path: Path) -> Path:
    """Rank 0's tmp_path on every rank (pytest gives each process its own)."""
    return Path(COMM.bcast(str(tmp_path), root=0))


@pytest.fixture(scope="module")
def paper():
    """The paper's problem pushed onto the plane, solved for κ = 1e-2, 1e-3, 1e-4 (continuation)."""
    disc = Discretization(degree=1, penalty_quadrature="vertex", quadrature_degree=4)
    problem = PenalizedProblem(_shell(s=1.0), square(COMM, N, HALF), disc)
    post = Postprocessor(problem)
    solver = NewtonSolver(problem)
    contacts = {}
    for kappa in KAPPAS:
        problem.set_kappa(kappa)
        solver.solve()
        contacts[kappa] = post.contact()
    return {
        "problem": problem,
        "post": post,
        "solver": solver,
        "contacts": contacts,
        "summary": post.summary(),
        "zeta": problem.zeta.x.array.copy(),
        "section": post.cross_section(n=201),
    }


def _restore(paper) -> PenalizedProblem:
    """Put the fixture's final solution (κ = 1e-4, pushed down) back into ``problem.zeta``."""
    problem = paper["problem"]
    problem.parameters["s"].value = 1.0
    problem.set_kappa(KAPPAS[-1])
    problem.zeta.x.array[:] = paper["zeta"]
    return problem


@pytest.mark.mpi
def test_contact_area_and_penalty_violation(paper):
    c = paper["contacts"][KAPPAS[-1]]
    surface_area, _ = paper["post"].total_mass()
    assert c["num_contact_nodes"] > 0
    assert 0.0 < c["contact_area_projected"] < c["contact_area"] < surface_area
    # the contact zone is about the loaded disk |y| < 0.06 (area 0.0113), within a cell layer
    assert 0.5 * math.pi * 0.06**2 < c["contact_area_projected"] < 2.0 * math.pi * 0.06**2
    # violation of the constraint ∝ κ: one decade of κ, one decade of violation
    for big, small in itertools.pairwise(KAPPAS):
        v_big, v_small = (paper["contacts"][k]["max_violation"] for k in (big, small))
        assert v_small > 0.0
        assert 5.0 < v_big / v_small < 20.0
    s = paper["summary"]
    assert s["contact_area"] == pytest.approx(c["contact_area"])
    assert s["zeta3_min"] < 0.0 < s["zeta3_max"]
    assert s["penalty_energy"] >= 0.0
    assert s["penalized_energy"] == pytest.approx(s["energy"] + s["penalty_energy"])


@pytest.mark.mpi
def test_indicator_matches_contact_nodes(paper):
    problem = _restore(paper)
    post = paper["post"]
    ind = post.indicator()
    n_owned = ind.function_space.dofmap.index_map.size_local
    count = COMM.allreduce(int(ind.x.array[:n_owned].sum()), op=MPI.SUM)
    assert count == post.contact()["num_contact_nodes"] > 0
    assert set(np.unique(ind.x.array)) <= {0.0, 1.0}
    # ζ_3 of the dofs, directly
    z3 = problem.zeta.x.array.reshape(-1, 3)[: problem.V.dofmap.index_map.size_local, 2]
    lo = COMM.allreduce(float(z3.min(initial=np.inf)), op=MPI.MIN)
    assert post.zeta3_range()[0] == lo


@pytest.mark.mpi
def test_no_contact_when_the_load_pulls_up(paper):
    problem, post, solver = paper["problem"], paper["post"], paper["solver"]
    try:
        problem.parameters["s"].value = -1.0
        problem.zeta.x.array[:] = 0.0
        problem.set_kappa(1e-4)
        solver.solve()
        c = post.contact()
        assert c["contact_area"] == 0.0 and c["contact_area_projected"] == 0.0
        assert c["num_contact_nodes"] == 0
        assert c["max_violation"] == 0.0 and c["min_gap"] > 0.0
        assert COMM.allreduce(float(post.indicator().x.array.sum()), op=MPI.SUM) == 0.0
        assert post.zeta3_range()[1] > 0.0
    finally:
        _restore(paper)


@pytest.mark.mpi
def test_lumped_masses_sum_to_the_areas(paper):
    problem, post = paper["problem"], paper["post"]
    surface_area, domain_area = post.total_mass()
    assert domain_area == pytest.approx((2 * HALF) ** 2, rel=1e-12)
    dx = ufl.Measure("dx", domain=problem.mesh, metadata={"quadrature_degree": 8})
    exact = COMM.allreduce(
        dolfinx.fem.assemble_scalar(dolfinx.fem.form(problem.G.sqrt_a * dx)), op=MPI.SUM
    )
    h = 2 * HALF / N
    assert surface_area == pytest.approx(exact, rel=h**2)  # vertex rule: O(h²)
    assert surface_area > domain_area


@pytest.mark.mpi
def test_nodal_gap_and_cartesian_displacement_are_exact_at_the_nodes():
    """For a known ζ (P2), g and U at the nodes equal the NumPy geometry's values."""
    disc = Discretization(degree=2, quadrature_degree=6)
    problem = PenalizedProblem(_shell(load="0"), square(COMM, 8, HALF), disc)
    post = Postprocessor(problem)

    def zeta_exact(x):
        return np.vstack([0.1 * x[0] * x[1], 0.2 * x[0] ** 2, -0.05 + 0.3 * x[1]])

    problem.zeta.interpolate(zeta_exact)
    surface, q = problem.shell.surface, problem.q

    gap = post.nodal_gap()
    assert gap.function_space.ufl_element().embedded_superdegree == 1
    y = gap.function_space.tabulate_dof_coordinates()
    G = surface.geometry_numpy(y)
    z = zeta_exact(y.T)
    expected = sum(np.broadcast_to(G.theta[k], len(y)) * q[k] for k in range(3))
    c = [dot(G.a_contra[j], q) for j in range(3)]  # c_j = a^j·q
    expected = expected + sum(z[j] * np.broadcast_to(c[j], len(y)) for j in range(3))
    assert np.allclose(gap.x.array, expected, rtol=0, atol=1e-13)

    U = post.cartesian_displacement()
    y = problem.V.tabulate_dof_coordinates()
    G = surface.geometry_numpy(y)
    expected_U = np.column_stack(G.cartesian(list(zeta_exact(y.T))))
    assert np.allclose(U.x.array.reshape(-1, 3), expected_U, rtol=0, atol=1e-13)


@pytest.mark.mpi
def test_norms_of_known_functions():
    mesh = dolfinx.mesh.create_unit_square(COMM, 8, 8)
    x = ufl.SpatialCoordinate(mesh)
    pi = math.pi
    e = ufl.as_vector([ufl.sin(pi * x[0]) * ufl.sin(pi * x[1]), x[0] * x[1], x[0] + x[1]])
    # ‖sin πx sin πy‖²_{H¹} = 1/4 + π²/2, ‖xy‖²_{H¹} = 1/9 + 2/3, ‖x + y‖²_{L²} = 7/6
    h1_sq = [0.25 + pi**2 / 2, 1 / 9 + 2 / 3, 7 / 6 + 2]
    l2_sq = [0.25, 1 / 9, 7 / 6]
    assert vm_norm(e, quadrature_degree=12) == pytest.approx(
        math.sqrt(h1_sq[0] + h1_sq[1] + l2_sq[2]), rel=1e-10
    )
    assert l2_norm(e, quadrature_degree=12) == pytest.approx(math.sqrt(sum(l2_sq)), rel=1e-10)
    assert h1_norm(e, quadrature_degree=12) == pytest.approx(math.sqrt(sum(h1_sq)), rel=1e-10)

    # a P2 Function represents the polynomial (x y, x², 1 + x) exactly: exact norms
    V = dolfinx.fem.functionspace(mesh, ("Lagrange", 2, (3,)))
    u = dolfinx.fem.Function(V)
    u.interpolate(lambda p: np.vstack([p[0] * p[1], p[0] ** 2, 1 + p[0]]))
    # ‖x²‖²_{H¹} = 1/5 + 4/3, ‖1 + x‖²_{L²} = 7/3
    assert vm_norm(u) == pytest.approx(math.sqrt(1 / 9 + 2 / 3 + 1 / 5 + 4 / 3 + 7 / 3), 1e-12)
    w = dolfinx.fem.Function(V)
    w.x.array[:] = 2.0 * u.x.array
    assert norms(w, u)["vm"] == pytest.approx(vm_norm(u), rel=1e-12)
    assert norms(u, u) == {"l2": 0.0, "h1": 0.0, "vm": 0.0}
    with pytest.raises(ValueError, match="3-vector"):
        vm_norm(x)


@pytest.mark.mpi
def test_cross_section_and_png(paper, tmp_path):
    sec = paper["section"]
    assert sec.s.size > 100 and sec.y.shape == (sec.s.size, 2)
    for arr in (sec.zeta, sec.reference, sec.deformed, sec.height_reference, sec.height_deformed):
        assert np.all(np.isfinite(arr))
    assert np.allclose(sec.y[:, 1], 0.0)
    assert np.all(np.diff(sec.s) > 0) and sec.s[0] >= -HALF and sec.s[-1] <= HALF
    assert np.all(sec.height_reference > 0.0)
    # the top of the cap reaches the plane (up to the penalty's and P1's small violations)
    assert -1e-3 < sec.height_deformed.min() < 1e-3 < sec.height_deformed.max()
    # every rank holds the same section
    assert COMM.allgather(float(sec.height_deformed.sum())) == [sec.height_deformed.sum()] * (
        COMM.size
    )
    # the section along y2 (the free function, building its own bounding-box tree)
    other = cross_section(_restore(paper), n=201, axis="y2")
    assert np.allclose(other.y[:, 0], 0.0) and np.all(np.isfinite(other.deformed))
    assert -1e-3 < other.height_deformed.min() < 1e-3

    path = _shared_dir(tmp_path) / "section.png"
    second = paper["post"].cross_section(n=201, at=0.02)
    out = plot_cross_section([("y2 = 0", sec), ("y2 = 0.02", second)], (0, 0, 1), path)
    COMM.barrier()
    assert out == path and path.exists() and path.stat().st_size > 10_000


@pytest.mark.mpi
@pytest.mark.parametrize("axis, at", [("y1", 0.0), ("y2", 0.0), ("y1", 0.0137), ("y2", -0.0913)])
def test_cross_section_with_the_line_tree_equals_the_whole_mesh_tree(paper, axis, at):
    """The tree of the cells that meet the line finds the same points and values as a tree of
    every cell (on lines through vertices and edges, y = 0, and off them)."""
    import dolfinx.geometry

    problem = _restore(paper)
    mesh = problem.mesh
    whole = dolfinx.geometry.bb_tree(mesh, mesh.topology.dim)
    expected = cross_section(problem, n=301, axis=axis, at=at, tree=whole)
    got = cross_section(problem, n=301, axis=axis, at=at)
    assert got.s.size == expected.s.size > 200
    assert np.array_equal(got.s, expected.s)
    assert np.allclose(got.zeta, expected.zeta, rtol=0, atol=1e-14)


@pytest.mark.mpi
def test_write_paraview(paper, tmp_path):
    problem = _restore(paper)
    folder = _shared_dir(tmp_path) / "vtx"
    paths = write_paraview(problem, paper["post"], folder)
    COMM.barrier()
    names = [p.name for p in paths]
    assert names == ["parameter_domain.bp", "surface.bp", "deformed_surface.bp"]
    for p in paths:
        assert p.is_dir() and any(p.iterdir())


@pytest.mark.mpi
def test_surface_mesh_carries_the_nodal_values(paper):
    """The 3D surface has θ at its nodes, and transferred P1 fields keep their vertex values."""
    problem = paper["problem"]
    mesh = problem.mesh
    y = mesh.geometry.x
    G = problem.shell.surface.geometry_numpy(y)
    theta = np.column_stack([np.broadcast_to(t, len(y)) for t in G.theta])
    surface = SurfaceMesh(mesh, theta)
    assert surface.mesh.geometry.dim == 3
    n2 = mesh.topology.index_map(2).size_local
    n3 = surface.mesh.topology.index_map(2).size_local
    assert COMM.allreduce(n3, op=MPI.SUM) == COMM.allreduce(n2, op=MPI.SUM)
    # P1 position field θ on the parameter mesh, transferred: equals the surface's coordinates
    W = dolfinx.fem.functionspace(mesh, ("Lagrange", 1, (3,)))
    position = dolfinx.fem.Function(W, name="position")
    position.x.array[:] = np.column_stack(
        [
            np.broadcast_to(t, (W.tabulate_dof_coordinates().shape[0],))
            for t in problem.shell.surface.geometry_numpy(W.tabulate_dof_coordinates()).theta
        ]
    ).ravel()
    moved = surface.transfer(position)
    coords = moved.function_space.tabulate_dof_coordinates()
    assert np.allclose(moved.x.array.reshape(-1, 3), coords, rtol=0, atol=1e-14)
    # surface area of the triangulated cap ≈ ∫ √a dy
    one = dolfinx.fem.Constant(surface.mesh, 1.0)
    area = COMM.allreduce(
        dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * ufl.dx(domain=surface.mesh))),
        op=MPI.SUM,
    )
    assert area == pytest.approx(paper["post"].total_mass()[0], rel=(2 * HALF / N) ** 2)


@pytest.mark.mpi
def test_a_moved_surface_mesh_is_the_surface_at_the_new_coordinates(paper):
    """SurfaceMesh.move (the deformed surface of write_paraview) puts every node where a
    surface built at the new coordinates has it."""
    mesh = paper["problem"].mesh
    y = mesh.geometry.x
    G = paper["problem"].shell.surface.geometry_numpy(y)
    theta = np.column_stack([np.broadcast_to(t, len(y)) for t in G.theta])
    shifted = theta + np.column_stack([np.sin(y[:, 0]), y[:, 1] ** 2, 0.1 + 0 * y[:, 0]])
    flat = y.copy()
    moved = SurfaceMesh(mesh, theta)
    moved.move(shifted)
    built = SurfaceMesh(mesh, shifted)
    for surface in (moved, built):
        assert np.array_equal(surface.mesh.geometry.x, shifted)
    # the surface shares the 2D mesh's cells and nodes, not its coordinates
    assert np.array_equal(mesh.geometry.x, flat)
    assert moved.mesh.topology.index_map(2).size_local == mesh.topology.index_map(2).size_local
