"""Conditions on parts of γ (shellobstacle.models.edges, docs/model.md §8.1), for Koiter's
linear model: closed-form plates and strips, symmetry, contact, and the refused inputs.

The plates are flat (θ_3 = 1, the obstacle x_3 ≥ 0 far below unless said), so the membrane
part decouples and ζ_3 solves Kirchhoff's plate equation ``D Δ²w = q`` with
``D = (ε³/3)(4λμ/(λ+2μ) + 4μ) = E t³/(12(1 − ν²))``, ``t = 2ε``, ``ν = λ/(2(λ+μ))``.
"""

from __future__ import annotations

import dataclasses

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
from cli_helpers import BASE, assert_user_error, run
from conftest import PENALTY, lu_solve

from shellobstacle.config.loader import parse_config
from shellobstacle.config.toml_io import to_toml
from shellobstacle.geometry.surface import Surface
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.spec import BENDING_FORMS, Discretization, Edge, Load, Material, Obstacle, Shell

COMM = MPI.COMM_WORLD
EPS, LAM, MU, Q = 0.01, 0.4, 0.3, 1e-6
D = EPS**3 / 3 * (4 * LAM * MU / (LAM + 2 * MU) + 4 * MU)
NU = LAM / (2 * (LAM + MU))
KOITER = Discretization(degree=2)


def plate(*edges: Edge, height: str = "1", load: float = Q, model: str = "koiter") -> Shell:
    """A plate θ = (y1, y2, height) under the pressure ``load`` along a_3."""
    plane = Surface.from_strings(["y1", "y2", height])
    material = Material(EPS, LAM, MU)
    return Shell(plane, material, Load(("0", "0", repr(load))), Obstacle(), model, edges)


def rectangle(corners, n, comm=COMM) -> dolfinx.mesh.Mesh:
    """A structured ghosted triangle mesh of a rectangle, ``n`` = (cells along y1, y2)."""
    return dolfinx.mesh.create_rectangle(comm, [np.array(c, float) for c in corners], n)


def deflection(shell: Shell, mesh, bending: str = "hybrid") -> tuple[np.ndarray, np.ndarray]:
    """The unconstrained solution ``K ζ = f``: the owned dof points and their ζ_3."""
    disc = dataclasses.replace(KOITER, bending=bending)
    problem = PenalizedProblem(shell, mesh, disc, kappa=None)
    x = lu_solve(problem.stiffness(), problem.load_vector())
    zeta = x.array_r.reshape(-1, 3)
    points = problem.V.tabulate_dof_coordinates()[: len(zeta)]
    return points, zeta[:, 2].copy()


def max_over_ranks(values: np.ndarray) -> float:
    return COMM.allreduce(float(np.abs(values).max(initial=0.0)), op=MPI.MAX)


# -- a simply supported circular plate ------------------------------------------------------
@pytest.mark.parametrize("bending", BENDING_FORMS)
def test_simply_supported_circular_plate_converges_to_the_closed_form(bending: str) -> None:
    """Disk of radius a, ζ = 0 on γ and the rotation free: ``w = q (a² − r²)((5+ν)/(1+ν) a² −
    r²) / (64 D)``, ``w₀ = (5+ν) q a⁴ / (64 (1+ν) D)`` (Timoshenko & Woinowsky-Krieger §62).
    The nodal error falls as h (fitted): the polygon's straight edges miss the curvature term
    ν ∂_ν w / a of the circle's M_νν = 0 (the clamped plate, where ∂_ν w = 0, converges as h²).
    Clamped, the deflection would be (1+ν)/(5+ν) of this one."""
    a = 0.5
    shell = plate(Edge("simply-supported", where="r > 0"))
    w0 = (5 + NU) * Q * a**4 / (64 * (1 + NU) * D)
    hs, errors = [0.1, 0.05, 0.025], []
    for h in hs:
        mesh = create_mesh(DomainSpec(kind="disk", radius=a, h=h), ghosted=True)
        x, w = deflection(shell, mesh, bending)
        r2 = x[:, 0] ** 2 + x[:, 1] ** 2
        exact = Q * (a**2 - r2) * ((5 + NU) / (1 + NU) * a**2 - r2) / (64 * D)
        errors.append(max_over_ranks(w - exact) / w0)
    rate = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert abs(rate - 1.0) < 0.1, (errors, rate)
    assert errors[-1] < 0.06, errors


# -- cantilever strips ----------------------------------------------------------------------
L = 1.0


def strip(sides: str, b: float) -> Shell:
    """The strip [0, L] × [0, b] clamped at y1 = 0, free at y1 = L, its sides ``sides``."""
    root, tip = Edge("clamped", where="y1 < 1e-9"), Edge("free", where=f"y1 > {L} - 1e-9")
    if sides == "free":
        return plate(root, Edge("free", where="y1 > 1e-9"))
    return plate(
        root, tip, Edge("symmetry", where="y2 < 1e-9"), Edge("symmetry", where=f"y2 > {b} - 1e-9")
    )


@pytest.mark.parametrize("bending", BENDING_FORMS)
def test_a_cantilever_strip_with_symmetric_sides_bends_cylindrically(bending: str) -> None:
    """Symmetry on both sides makes the strip a slice of an infinitely wide plate (the
    sides' ζ_2 = 0 and ∂_2 w = 0 are those of a plate periodic in y2): cylindrical bending,
    the exact plate solution ``w = q y1² (6L² − 4L y1 + y1²) / (24 D)``, tip ``q L⁴ / (8 D)``
    with D the plate's ``E t³/(12(1 − ν²))``. P2 represents w exactly but for the facet
    terms' consistency, so the nodal error is small on a coarse mesh."""
    x, w = deflection(strip("symmetry", 0.1), rectangle([(0, 0), (L, 0.1)], [40, 4]), bending)
    exact = Q * x[:, 0] ** 2 * (6 * L**2 - 4 * L * x[:, 0] + x[:, 0] ** 2) / (24 * D)
    tip = Q * L**4 / (8 * D)
    assert max_over_ranks(w - exact) / tip < 1e-3


def test_a_narrow_cantilever_strip_with_free_sides_tends_to_the_beam() -> None:
    """Free sides leave the anticlastic curvature free: as b/L → 0 the strip is a beam of
    bending stiffness ``E t³/12 = D (1 − ν²)`` per unit width, ``w_tip → q L⁴ / (8 D (1 −
    ν²))``; the clamped root, which holds the anticlastic curvature, stiffens it by O(b/L)
    (measured: 1.2 % at b/L = 0.1, 0.6 % at 0.05)."""
    beam = Q * L**4 / (8 * D * (1 - NU**2))
    deficits = []
    for b in (0.1, 0.05):
        mesh = rectangle([(0, 0), (L, b)], [40, max(2, round(b / 0.025))])
        x, w = deflection(strip("free", b), mesh)
        tip = COMM.allreduce(float(w[np.abs(x[:, 0] - L) < 1e-9].max(initial=-np.inf)), MPI.MAX)
        deficits.append(1 - tip / beam)
    assert 0 < deficits[0] < 0.015 and 0 < deficits[1] < 0.0075, deficits
    assert deficits[1] / deficits[0] == pytest.approx(0.5, abs=0.1), deficits


# -- symmetry -------------------------------------------------------------------------------
def navier_square(a: float, terms: int = 199) -> float:
    """Centre deflection of the simply supported square plate of side a under q (Navier's
    series, Timoshenko & Woinowsky-Krieger §30)."""
    m = np.arange(1, terms + 1, 2)
    M, N = np.meshgrid(m, m)
    signs = (-1.0) ** ((M + N) // 2 - 1)
    series = signs / (M * N * (M**2 + N**2) ** 2)
    return 16 * Q * a**4 / (np.pi**6 * D) * float(series.sum())


@pytest.mark.parametrize("bending", BENDING_FORMS)
def test_a_quarter_plate_with_two_symmetry_edges_is_the_full_plate(bending: str) -> None:
    """The simply supported square [−½, ½]² and its quarter [0, ½]² with symmetry on y1 = 0
    and y2 = 0 (the same cells there): equal centre deflections to 1e-3 (the structured mesh is not
    itself symmetric), Navier's to the discretization error."""
    supported = Edge("simply-supported", where="Max(abs(y1), abs(y2)) > 0.5 - 1e-9")
    full = rectangle([(-0.5, -0.5), (0.5, 0.5)], [32, 32])
    quarter = rectangle([(0, 0), (0.5, 0.5)], [16, 16])
    symmetry = (Edge("symmetry", where="y1 < 1e-9"), Edge("symmetry", where="y2 < 1e-9"))
    centres = []
    for mesh, edges in ((full, (supported,)), (quarter, (supported, *symmetry))):
        x, w = deflection(plate(*edges), mesh, bending)
        at = np.hypot(x[:, 0], x[:, 1]) < 1e-12
        centres.append(COMM.allreduce(float(w[at].sum()), MPI.SUM))
    exact = navier_square(1.0)
    assert centres[1] == pytest.approx(centres[0], rel=1e-3)
    assert centres[0] == pytest.approx(exact, rel=5e-3)  # P2 at h = 1/32: 0.1 % (c0ip), 0.4 %


# -- contact --------------------------------------------------------------------------------
def supported_plate_contact(comm) -> tuple[float, float, float]:
    """A simply supported square plate 0.01 above the plane x3 = 0, pressed onto it (its free
    deflection 0.024): min ζ_3, the contact area and the energy, solved by Newton's penalty
    continuation."""
    from shellobstacle.api import solve_problem

    supported = Edge("simply-supported", where="Max(abs(y1), abs(y2)) > 0.5 - 1e-9")
    shell = plate(supported, height="0.01", load=-6e-6)
    mesh = rectangle([(-0.5, -0.5), (0.5, 0.5)], [16, 16], comm)
    result = solve_problem(shell, mesh, PENALTY, KOITER)
    assert result.converged, result.error
    zeta = result.problem.zeta.x.array.reshape(-1, 3)[:, 2]
    low = comm.allreduce(float(zeta.min()), op=MPI.MIN)
    return low, result.contact.area, result.problem.energies()["energy"]


def test_a_plate_with_a_simply_supported_edge_comes_into_contact() -> None:
    """The plate reaches the plane (κ-penetration only) over a contact zone."""
    low, area, _ = supported_plate_contact(COMM)
    assert -0.01 - 1e-3 < low < -0.01 + 1e-4
    assert 0 < area < 1


@pytest.mark.mpi
def test_the_supported_plate_in_contact_is_the_same_on_two_ranks() -> None:
    if COMM.size == 1:
        pytest.skip("compares a distributed solve with a serial one")
    par, ser = supported_plate_contact(COMM), supported_plate_contact(MPI.COMM_SELF)
    np.testing.assert_allclose(par, ser, rtol=1e-8)


# -- gmsh physical tags ---------------------------------------------------------------------
def tagged_square(path) -> None:
    """The unit square in a .msh file, its sides the physical curves 1 (y1 = 0), 2 (y2 = 0),
    3 (y1 = 1) and 4 (y2 = 1)."""
    import gmsh

    gmsh.initialize(readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("square")
    corners = [gmsh.model.geo.addPoint(*p, 0, 0.2) for p in ((0, 0), (1, 0), (1, 1), (0, 1))]
    lines = [gmsh.model.geo.addLine(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    gmsh.model.geo.addPlaneSurface([gmsh.model.geo.addCurveLoop(lines)])
    gmsh.model.geo.synchronize()
    for tag, line in zip((2, 3, 4, 1), lines, strict=True):
        gmsh.model.addPhysicalGroup(1, [line], tag)
    gmsh.model.addPhysicalGroup(2, [1], 1)
    gmsh.model.mesh.generate(2)
    gmsh.write(str(path))
    gmsh.finalize()


@pytest.fixture
def square_file(tmp_path_factory) -> str:
    path = tmp_path_factory.getbasetemp() / "tagged_square.msh"
    if COMM.rank == 0 and not path.exists():
        tagged_square(path)
    COMM.barrier()
    return str(path)


def test_a_tag_selects_its_physical_curve_through_refinements(square_file: str) -> None:
    """``tag = 3`` selects the facets of the side y1 = 1 of the file, on its refined mesh too."""
    for refinements in (0, 1):
        spec = DomainSpec(kind="file", path=square_file, refinements=refinements)
        mesh = create_mesh(spec, ghosted=True)
        shell = plate(Edge("free", tag=3), Edge("simply-supported", tag=1))
        problem = PenalizedProblem(shell, mesh, KOITER, kappa=None)
        for condition, side in (("free", 0), ("simply-supported", 0), ("clamped", None)):
            facets = problem.parts.facets[condition]
            nodes = dolfinx.mesh.entities_to_geometry(mesh, 1, facets)
            y = mesh.geometry.x[nodes][:, :, :2]
            if condition == "free":
                assert np.allclose(y[..., 0], 1.0)
            elif condition == "simply-supported":
                assert np.allclose(y[..., side], 0.0)
            else:  # the two other sides
                assert np.all(np.isclose(y[..., 1], 0.0).all(1) | np.isclose(y[..., 1], 1.0).all(1))
            length = np.linalg.norm(y[:, 1] - y[:, 0], axis=1).sum()
            assert COMM.allreduce(length, MPI.SUM) == pytest.approx(2.0 if side is None else 1.0)


# -- refused input --------------------------------------------------------------------------
def refused(shell: Shell, mesh=None) -> str:
    mesh = mesh if mesh is not None else rectangle([(-0.5, -0.5), (0.5, 0.5)], [4, 4])
    with pytest.raises(ValueError) as err:
        PenalizedProblem(shell, mesh, KOITER, kappa=None)
    message = str(err.value)
    assert "\n" not in message
    return message


def test_a_part_that_selects_no_facet_is_refused() -> None:
    assert "selects no facet" in refused(plate(Edge("free", where="y1 > 5")))


def test_two_conditions_on_one_facet_are_refused() -> None:
    message = refused(plate(Edge("free", where="y1 > 0"), Edge("clamped", where="y2 > 0")))
    assert "both select the facet" in message and "one condition" in message


def test_an_unknown_condition_is_refused() -> None:
    with pytest.raises(ValueError, match=r"edge\.condition"):
        Edge("hinged", where="y1 > 0")


def test_an_unknown_condition_exits_2_through_the_cli(capsys, tmp_path) -> None:
    path = tmp_path / "c.toml"
    path.write_text(to_toml({**BASE, "edge": [{"condition": "hinged", "where": "y1 > 0"}]}))
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err, "edge.condition", "hinged", "simply-supported")


def test_a_tag_on_a_mesh_without_tags_is_refused() -> None:
    assert "no boundary tags" in refused(plate(Edge("free", tag=3)))


def test_a_membrane_with_a_condition_other_than_clamped_is_refused() -> None:
    with pytest.raises(ValueError, match="membrane model needs ζ_α = 0"):
        plate(Edge("simply-supported", where="y1 > 0"), model="membrane")


def test_a_koiter_shell_with_nothing_fixed_is_refused() -> None:
    message = refused(plate(Edge("free", where="y1 > -0.49"), Edge("symmetry", where="y1 < -0.49")))
    assert "rigid motions" in message and "'clamped' or 'simply-supported'" in message


def test_a_symmetry_part_off_a_line_is_refused() -> None:
    assert "not on a line" in refused(plate(Edge("symmetry", where="y1 + y2 > 0")))


def test_a_symmetry_line_about_which_theta_is_not_symmetric_is_refused() -> None:
    tilted = plate(Edge("symmetry", where="y1 < -0.49"), height="0.1 * y1")
    assert "θ is not symmetric about y1 = -0.5" in refused(tilted)
    symmetric = plate(Edge("symmetry", where="y1 < -0.49"), height="(y1 + 0.5)**2")
    PenalizedProblem(symmetric, rectangle([(-0.5, -0.5), (0.5, 0.5)], [4, 4]), KOITER, None)


def test_a_where_that_is_no_condition_is_refused() -> None:
    with pytest.raises(ValueError, match="must be a condition"):
        Edge("free", where="y1 + 1")


def test_the_config_reads_edges() -> None:
    data = {**BASE, "model": {"kind": "koiter"}}
    data["edge"] = [{"condition": "free", "where": "y1 > 0"}, {"condition": "clamped", "tag": 2}]
    config = parse_config(data)
    assert config.shell.edges == (Edge("free", where="y1 > 0"), Edge("clamped", tag=2))
    assert config.resolved["edge"] == data["edge"]
