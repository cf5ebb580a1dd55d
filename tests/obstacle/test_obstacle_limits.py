"""Where a curved obstacle's description breaks down, said plainly: a constraint point at a
ball's centre or on a cylinder's axis (``∇g`` is ``0/0`` there) raises an error naming it, and a
ball whose radius spans too few cells near the contact is warned about with the cell size that
would resolve it (:mod:`shellobstacle.models.singular`, :mod:`shellobstacle.post.resolution`)."""

from __future__ import annotations

import dataclasses

# isort: split
from mpi4py import MPI

import numpy as np
import pytest
from conftest import make_paper_shell, square

from shellobstacle.api import solve_problem
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.models.singular import SingularGradientError
from shellobstacle.obstacle import Cylinder, ExpressionObstacle, Sphere
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post.points import NodePoints, QuadraturePoints
from shellobstacle.post.resolution import RESOLVE_CELLS, unresolved_obstacle
from shellobstacle.spec import Discretization, Obstacle

COMM = MPI.COMM_WORLD


def on_ball(radius: float, centre_height: float | None = None) -> object:
    """The paper's cap over the ball of ``radius`` whose top is the plane x3 = 0's origin."""
    centre = (0.0, 0.0, -radius if centre_height is None else centre_height)
    return dataclasses.replace(
        make_paper_shell(), obstacle=Obstacle(kind="sphere", center=centre, radius=radius)
    )


def test_a_point_at_the_balls_centre_is_an_error_that_names_it() -> None:
    """θ(0) + ζ̄₃ a³ at the ball's centre: ∇g is 0/0 there; linearizing there raises an error
    naming the centre and the point, while the reference shell (far from it) linearizes."""
    problem = PenalizedProblem(on_ball(0.04, centre_height=-0.05), square(n=8), Discretization())
    problem.linearize()  # the undeformed shell: 0.2 above the centre
    # θ₃(0) = 0.15 and a³ = e₃ at the origin: ζ₃ = −0.2 puts the origin at the centre
    problem.zeta.x.array.reshape(-1, 3)[:, 2] = -0.2
    with pytest.raises(SingularGradientError, match=r"ball's centre.*y = \(0, 0\).*deformed"):
        problem.linearize()


@pytest.mark.mpi
def test_a_point_on_the_cylinders_axis_is_an_error_on_every_rank() -> None:
    """The same for a cylinder whose axis (along y1, at height −0.05) the deformed shell's
    line y2 = 0 reaches; the error is raised on every rank, serially and on 2 ranks."""
    shell = dataclasses.replace(
        make_paper_shell(),
        obstacle=Obstacle(kind="cylinder", point=(0, 0, -0.05), axis=(1, 0, 0), radius=0.04),
    )
    problem = PenalizedProblem(shell, square(n=8), Discretization())
    problem.zeta.x.array.reshape(-1, 3)[:, 2] = -0.2
    with pytest.raises(SingularGradientError, match="cylinder's axis"):
        problem.linearize()


def test_the_curvature_radius_of_a_formula_is_its_level_surfaces() -> None:
    """A ball and a cylinder written as formulas have the radii of their level surfaces (the
    distance to the centre, to the axis); the shapes give their radius; a plane is flat."""
    x = np.array([[0.3, 0.0, 0.4], [0.0, 0.0, 2.0], [1.0, 2.0, 2.0]])
    ball = ExpressionObstacle("sqrt(x1**2 + x2**2 + x3**2) - 1")
    assert np.allclose(ball.curvature_radius(x), np.linalg.norm(x, axis=1), rtol=1e-12)
    cylinder = ExpressionObstacle("sqrt(x1**2 + x3**2) - 1")
    assert np.allclose(cylinder.curvature_radius(x), np.hypot(x[:, 0], x[:, 2]), rtol=1e-12)
    assert np.all(ExpressionObstacle("x3 + 0.5").curvature_radius(x) == np.inf)
    assert np.all(Sphere((0, 0, 0), 0.3).curvature_radius(x) == 0.3)
    assert np.all(Cylinder((0, 0, 0), (1, 0, 0), 0.2).curvature_radius(x) == 0.2)


@pytest.mark.mpi
def test_a_ball_of_few_cells_is_warned_about_and_a_resolved_one_is_not() -> None:
    """The ball of radius 0.07 under the paper's load on cells of 0.0295 (2.4 cells across):
    the penalty's Gauss points touch it and the warning names the radius, the cells it spans
    and the cell size 0.07/4 that would resolve it; on cells half as large (4.7 cells) and for
    the ball of radius 2, no warning. Serially and on 2 ranks (a global verdict)."""
    penalty = PenaltySpec(exponent=1.5)
    coarse = solve_problem(on_ball(0.07), square(n=24), penalty)
    points = QuadraturePoints(coarse.problem)
    warning = unresolved_obstacle(points, 1e-12)
    assert warning is not None
    assert "radius of curvature there, 0.07, spans 2.4 cells" in warning
    assert f"at most {0.07 / RESOLVE_CELLS:.3g}" in warning
    # the vertices do not touch: nothing to judge there
    assert unresolved_obstacle(NodePoints(coarse.problem), 1e-12) is None
    fine = solve_problem(on_ball(0.07), square(n=48), penalty)
    assert unresolved_obstacle(QuadraturePoints(fine.problem), 1e-12) is None
    large = solve_problem(on_ball(2.0), square(n=24), penalty)
    assert unresolved_obstacle(QuadraturePoints(large.problem), 1e-12) is None


def test_a_solve_that_reaches_the_centre_fails_with_the_error_as_its_message() -> None:
    """The passes (``solve_with``) end with a failed result naming the centre, not a NaN
    deep in a solver: a method whose answer puts the origin at the ball's centre."""
    from shellobstacle.solvers.linearization import solve_with
    from shellobstacle.solvers.result import MethodResult

    problem = PenalizedProblem(on_ball(0.04, centre_height=-0.05), square(n=8), Discretization())

    class ThroughTheCentre:
        def solve(self, problem, h, kappas, options) -> MethodResult:
            problem.zeta.x.array.reshape(-1, 3)[:, 2] = -0.2
            return MethodResult()

    problem.set_kappa(1e-3)
    result = solve_with(ThroughTheCentre(), problem, 0.1, [1e-3], None)
    assert not result.converged
    assert "ball's centre" in result.error and "deformed shell" in result.error
