"""Contact is measured where the constraint acts, with the nodal figure beside it
(docs/model.md §7): the penalty's Gauss points for the Gauss penalty (P1 and P2), the nodes
for the vertex penalty and the exact solvers; the P1 vertices or P2 nodes for the nodal
figure, which the paper's batch 3 reports.

A ball of radius 0.07 (about two cells of a 12 × 12 square) under the paper's cap is touched
between the vertices: the P1 solution's vertices all stay off it while the Gauss points, where
the penalty acts, penetrate it. Its contact must not be reported as none.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

# isort: split
from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.la
import numpy as np
import pytest
import ufl
from conftest import displace_through_plane, square
from conftest import make_paper_shell as paper_shell

from shellobstacle.api import solve_problem
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post.contact import Postprocessor, contact_text
from shellobstacle.post.points import NodePoints, QuadraturePoints
from shellobstacle.spec import Discretization, Obstacle

COMM = MPI.COMM_WORLD
SMALL = Path(__file__).parents[2] / "examples" / "small.toml"
#: the ball whose top touches the plane x3 = 0 at the origin, two cells wide on square(12)
SMALL_BALL = Obstacle(kind="sphere", center=(0.0, 0.0, -0.07), radius=0.07)
PRIMARY = ("contact_area", "contact_area_projected", "max_violation", "min_gap")
NODAL = ("contact_area_nodal", "contact_area_nodal_projected", "max_violation_nodal")


def _solve(obstacle: Obstacle):
    """The paper's cap on ``obstacle`` over a 12 × 12 square: P1, Gauss penalty, κ = h^1.5."""
    shell = dataclasses.replace(paper_shell(), obstacle=obstacle)
    r = solve_problem(shell, square(COMM, 12), PenaltySpec(exponent=1.5), Discretization(degree=1))
    assert r.converged, r.error
    return r


@pytest.fixture(scope="module")
def small_ball():
    r = _solve(SMALL_BALL)
    post = Postprocessor(r.problem, r.constraint)
    return {"contact": post.contact(), "validity": r.validity, "scale": post.gap_scale}


@pytest.mark.mpi
@pytest.mark.parametrize(
    "degree, rule, constraint, acting, nodal",
    [
        (1, "gauss", "penalty", "quadrature points", "vertices"),
        (1, "vertex", "penalty", "vertices", "vertices"),
        (1, "vertex", "nodes", "vertices", "vertices"),
        (2, "gauss", "penalty", "quadrature points", "nodes"),
        (2, "gauss", "nodes", "nodes", "nodes"),
    ],
)
def test_contact_is_measured_where_the_constraint_acts_and_at_the_nodes(
    degree: int, rule: str, constraint: str, acting: str, nodal: str
) -> None:
    """Each figure is its points' measure: the penalty's Gauss points for the Gauss penalty
    (P1 too), the vertices for the vertex penalty (P1 only), the nodes for the exact solvers;
    the nodal figure at the P1 vertices or the P2 nodes, the same as the first where the
    constraint acts there."""
    disc = Discretization(degree=degree, penalty_quadrature=rule)
    problem = PenalizedProblem(paper_shell(), square(COMM, 6), disc)
    displace_through_plane(problem)
    post = Postprocessor(problem, constraint)
    c = post.contact()
    assert (c["contact_points"], c["nodal_points"]) == (acting, nodal)
    points = QuadraturePoints if acting == "quadrature points" else NodePoints
    expected = points(problem).measure(post.tolerance())
    assert c["contact_area"] == pytest.approx(expected.area, rel=1e-14)
    assert c["num_contact_points"] == expected.count > 0
    assert c["max_violation"] == pytest.approx(expected.max_violation, rel=1e-14)
    nodes = NodePoints(problem).measure(post.tolerance())
    assert c["contact_area_nodal"] == pytest.approx(nodes.area, rel=1e-14)
    assert c["num_contact_nodes"] == nodes.count > 0
    assert c["max_violation_nodal"] == pytest.approx(nodes.max_violation, rel=1e-14)
    if acting == nodal:
        assert [c[k] for k in NODAL] == [c[k] for k in PRIMARY[:3]]


@pytest.mark.mpi
def test_a_small_ball_touched_between_the_vertices_is_contact(small_ball) -> None:
    """The vertices stay off the ball (nodal area 0, no nodal violation), while the Gauss
    points, where the penalty acts, penetrate it: the primary figures report that contact."""
    c = small_ball["contact"]
    assert c["contact_points"] == "quadrature points"
    assert c["contact_area"] > 0 and c["contact_area_projected"] > 0
    assert c["num_contact_points"] > 0
    assert c["max_violation"] > 0 and c["min_gap"] == -c["max_violation"]
    assert c["nodal_points"] == "vertices"
    assert c["contact_area_nodal"] == 0 and c["contact_area_nodal_projected"] == 0
    assert c["num_contact_nodes"] == 0
    assert c["max_violation_nodal"] == 0 and c["min_gap_nodal"] > 0
    assert contact_text(c).endswith("at the penalty's Gauss points (nodal 0 at the vertices)")


@pytest.mark.mpi
def test_validity_measures_the_penetration_where_the_constraint_acts(small_ball) -> None:
    """The penetration is the larger violation of the two figures: the Gauss points' here,
    not the vertices' zero."""
    c, validity = small_ball["contact"], small_ball["validity"]
    assert validity.penetration == pytest.approx(c["max_violation"] / small_ball["scale"])
    assert validity.penetration > 0


def _vertex_gap_and_masses(problem: PenalizedProblem) -> tuple[np.ndarray, np.ndarray]:
    """``g(ζ)`` at the owned vertices (the obstacle's NumPy gap) and their lumped masses
    ``∫ φ_i √a dy`` (vertex rule)."""
    P1 = dolfinx.fem.functionspace(problem.mesh, ("Lagrange", 1))
    n = P1.dofmap.index_map.size_local
    y = P1.tabulate_dof_coordinates()[:n]
    zeta = problem.zeta.x.array.reshape(-1, 3)[:n]  # P1: the same vertices, blocked
    g = problem.obstacle.at_points(problem.shell.surface, y).gap(zeta)
    dxv = ufl.Measure(
        "dx", domain=problem.mesh, metadata={"quadrature_rule": "vertex", "quadrature_degree": 1}
    )
    form = dolfinx.fem.form(ufl.TestFunction(P1) * problem.G.sqrt_a * dxv)
    mass = dolfinx.fem.assemble_vector(form)
    mass.scatter_reverse(dolfinx.la.InsertMode.add)
    return g, mass.array[:n]


@pytest.mark.mpi
def test_the_planes_nodal_figures_are_the_vertices_lumped_masses() -> None:
    """Batch 3's figure on the paper's plane: the lumped masses ``∫ φ_i √a dy`` of the
    vertices with ``g ≤ tol``, their count and largest violation; the Gauss points' figure is
    another number beside it."""
    r = _solve(Obstacle())
    post = Postprocessor(r.problem, r.constraint)
    c = post.contact()
    g, mass = _vertex_gap_and_masses(r.problem)
    touching = g <= post.tolerance()
    area = COMM.allreduce(float(mass[touching].sum()), op=MPI.SUM)
    assert c["contact_area_nodal"] == pytest.approx(area, rel=1e-13) and area > 0
    assert c["num_contact_nodes"] == COMM.allreduce(int(touching.sum()), op=MPI.SUM)
    lowest = COMM.allreduce(float(g.min()), op=MPI.MIN)
    assert c["max_violation_nodal"] == pytest.approx(-lowest, rel=1e-10)
    assert c["contact_points"] == "quadrature points" and c["contact_area"] > 0
    assert c["contact_area"] != c["contact_area_nodal"]


@pytest.mark.skipif(COMM.size > 1, reason="CLI test runs serially")
def test_the_command_line_names_both_figures(tmp_path: Path) -> None:
    """``solve``'s last line and ``summary.json`` report the Gauss points' contact and the
    vertices' beside it, named."""
    from shellobstacle.cli.main import main

    out = tmp_path / "ball"
    ball = [
        'obstacle.kind="sphere"',
        "obstacle.center=[0.0, 0.0, -0.07]",
        "obstacle.radius=0.07",
        "output.pictures=false",
        "output.paraview=false",
    ]
    sets = [arg for s in ball for arg in ("--set", s)]
    assert main(["solve", str(SMALL), "-o", str(out), "-q", *sets]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["contact_area"] > 0 and summary["contact_area_nodal"] == 0
    assert summary["validity"]["penetration"] > 0
    done = [line for line in (out / "log.txt").read_text().splitlines() if "done: κ" in line]
    assert len(done) == 1
    assert f"contact area {summary['contact_area']:.5g}, projected" in done[0]
    assert "at the penalty's Gauss points (nodal 0, projected 0, at the vertices)" in done[0]
