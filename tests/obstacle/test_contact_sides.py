"""Local solutions on obstacles whose admissible set is not convex (docs/model.md, Curved
obstacles): the summary says so, the command line too, and the contact points are counted
on the near side of the obstacle (the one the undeformed shell faces) and on the far side."""

from __future__ import annotations

import json
from pathlib import Path

# isort: split
from mpi4py import MPI

import numpy as np
import pytest
from conftest import VERTEX, ball, solve_on
from conftest import make_paper_shell as paper_shell

from shellobstacle.obstacle import Sphere
from shellobstacle.post.sides import facing
from shellobstacle.spec import Obstacle

COMM = MPI.COMM_WORLD
EXAMPLES = Path(__file__).parents[2] / "examples"


@pytest.mark.mpi
@pytest.mark.parametrize("method", ["newton", "active-set"])
def test_a_ball_from_outside_is_a_local_solution_with_its_contact_on_the_near_side(
    method: str,
) -> None:
    """The paper's cap on the ball of radius 2: one local solution of several, all its contact
    points (the summary's contact set) on the near side, serially and on 2 ranks."""
    nodal = method == "active-set"
    kw = {"penalty": None, "discretization": VERTEX} if nodal else {}
    r, contact = solve_on(ball(2.0), method, **kw)
    assert r.extra["local_solution"] is True
    assert "is not convex" in r.extra["local_solution_reason"]
    sides = r.extra["contact_sides"]
    assert sides["near_points"] == contact["num_contact_points"] > 0
    assert sides["near_area"] == pytest.approx(contact["contact_area"], rel=1e-12)
    assert sides["far_points"] == 0 and sides["far_area"] == 0.0
    assert sides["points"] == contact["contact_points"]


@pytest.mark.parametrize(
    "obstacle",
    [
        Obstacle(),
        Obstacle(kind="sphere", center=(0.0, 0.0, 10.0), radius=10.0, side="inside"),
    ],
    ids=["plane", "inside a ball"],
)
def test_a_convex_admissible_set_records_no_local_solution(obstacle: Obstacle) -> None:
    r, contact = solve_on(obstacle)
    assert contact["contact_area"] > 0
    assert "local_solution" not in r.extra and "contact_sides" not in r.extra


def test_a_curved_g_of_unknown_convexity_is_a_local_solution() -> None:
    """A user's curved ``g`` (a paraboloid's graph, ``obstacle.convex`` None)."""
    r, _ = solve_on(Obstacle(kind="expression", g="x3 + x1**2 + x2**2"))
    assert r.extra["local_solution"] is True
    assert "not known to be convex" in r.extra["local_solution_reason"]
    assert r.extra["contact_sides"]["near_points"] > 0


def test_a_contact_face_past_the_balls_centre_is_on_the_far_side() -> None:
    """At the cap's apex (θ₃ = 0.15, above the ball of radius 0.1 centred at the origin,
    ``∇g(θ) = e₃``) a face pushed 0.05 down lies on the ball's top: the near side; pushed
    0.25 down, on its bottom, and pushed 0.1 sideways and 0.17 down, below its equator: the
    far side."""
    sphere = Sphere((0.0, 0.0, 0.0), 0.1)
    y = np.zeros((3, 2))
    zeta = np.array([[0.0, 0.0, -0.05], [0.0, 0.0, -0.25], [0.1, 0.0, -0.17]])
    # covariant components at the apex: a^i = e_i (the cap is flat there)
    assert list(facing(sphere, paper_shell().surface, y, zeta)) == [True, False, False]


@pytest.mark.skipif(COMM.size > 1, reason="CLI tests run serially")
def test_the_command_line_says_the_answer_is_a_local_solution(tmp_path: Path) -> None:
    from shellobstacle.cli.main import main

    out = tmp_path / "run"
    args = ["solve", str(EXAMPLES / "cap_on_ball.toml"), "-o", str(out), "-q"]
    assert main([*args, "--set", "domain.h=0.05", "--set", "output.pictures=false"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["local_solution"] is True and summary["contact_sides"]["near_points"] > 0
    lines = (out / "log.txt").read_text().splitlines()
    local = [line for line in lines if "a local solution: the admissible set" in line]
    assert len(local) == 1 and "near side" in local[0] and "far side 0" in local[0]
