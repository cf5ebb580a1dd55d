"""Rigid obstacles other than the paper's plane (docs/model.md, Curved obstacles): a plane
written as a formula is the plane, a large ball tends to the plane at the rate 1/R, the lower
face touches about ε earlier, the penalty tends to the exact VI on a ball at the rate κ, and
the exact solvers meet the curved constraint at the nodes."""

from __future__ import annotations

# isort: split
from mpi4py import MPI

import numpy as np
import pytest
from conftest import PENALTY, VERTEX, ball, global_max_abs, owned_zeta, solve_on
from conftest import make_paper_shell as paper_shell

from shellobstacle.obstacle import Sphere, from_spec
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post.contact import Postprocessor
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import Obstacle

COMM = MPI.COMM_WORLD
#: the paper's load widened to |y| < 0.15: five vertices of a 6 × 6 square touch (h ≈ 0.12)
WIDE_LOAD = "Piecewise((-(2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.15), (0, True))"


@pytest.mark.parametrize("method", list(METHODS))
def test_a_plane_written_as_a_formula_is_the_plane(method: str) -> None:
    """Every method, on a 6 × 6 square (the nodal ones with the nodes' constraint)."""
    expression = Obstacle(kind="expression", g="x3")
    assert from_spec(expression).affine
    penalty, disc = (PENALTY, None) if METHODS[method].penalized else (None, VERTEX)
    kw = {"penalty": penalty, "discretization": disc, "n": 6, "load": WIDE_LOAD}
    r_plane, c_plane = solve_on(Obstacle(), method, **kw)
    r_expr, c_expr = solve_on(expression, method, **kw)
    assert not r_expr.problem.linearized
    assert global_max_abs(owned_zeta(r_expr) - owned_zeta(r_plane)) <= 1e-14
    assert c_expr["contact_area"] == pytest.approx(c_plane["contact_area"], rel=1e-12)
    assert c_plane["contact_area"] > 0


def test_a_large_ball_tends_to_the_plane_at_the_rate_one_over_r() -> None:
    """Within the contact region (radius ρ) the ball's surface is ``ρ²/(2R)`` below the plane,
    so ζ differs from the plane's by ``O(1/R)``: each tenfold R divides the difference by 10."""
    zeta_plane = owned_zeta(solve_on(Obstacle())[0])
    errors = []
    for radius in (10.0, 100.0, 1000.0):
        r, contact = solve_on(ball(radius))
        assert r.problem.linearized and r.extra["linearizations"] >= 2
        assert contact["contact_area"] > 0
        errors.append(global_max_abs(owned_zeta(r) - zeta_plane))
    rates = np.log10(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(rates - 1.0) < 0.02), (errors, rates)


def test_a_ball_too_large_for_the_stopping_test_settles_at_round_off() -> None:
    """``|x − c| − R`` with ``R = 10⁵`` is evaluated to about 1e-11 of ``R``, which the
    penalty amplifies: the curved residual stays above
    :data:`~shellobstacle.solvers.linearization.RESIDUAL_RTOL`, and the passes stop once ζ has
    settled in two passes and the residual no longer falls (no failure after 30 passes); ζ
    is the plane's to ``O(1/R)``."""
    from shellobstacle.solvers.linearization import DZETA_RTOL, RESIDUAL_RTOL

    zeta_plane = owned_zeta(solve_on(Obstacle(), n=12)[0])
    r, _ = solve_on(ball(1e5), n=12)
    passes = r.extra["linearization"]
    dzeta, residual = passes["dzeta"], passes["residual"]
    assert residual[-1] > RESIDUAL_RTOL and residual[-1] >= residual[-2]
    assert max(dzeta[-2:]) <= DZETA_RTOL
    assert r.extra["linearizations"] <= 4
    assert global_max_abs(owned_zeta(r) - zeta_plane) < 1e-7


def test_the_lower_face_touches_about_epsilon_earlier() -> None:
    """The lower face θ − ε a_3 must stay above the plane: ζ_3 stops ε·(a_3·q) ≈ ε (a_3 ≈ e_3
    at the cap's top) higher."""
    epsilon = paper_shell().material.epsilon
    middle = Postprocessor(solve_on(Obstacle())[0].problem).zeta3_range()[0]
    r, _ = solve_on(Obstacle(contact_face="lower"))
    lower = Postprocessor(r.problem).zeta3_range()[0]
    assert lower - middle == pytest.approx(epsilon, rel=0.1)


def test_the_penalty_tends_to_the_exact_vi_on_a_ball_at_the_rate_kappa() -> None:
    """With the vertex penalty (the nodes' constraint, as the exact solver's), the penalized
    solution on a ball of radius 2 differs from active-set's by O(κ)."""
    exact, exact_contact = solve_on(ball(2.0), "active-set", penalty=None, discretization=VERTEX)
    assert exact_contact["max_violation"] <= 1e-14  # the curved gap at the nodes, not its chord
    z = owned_zeta(exact)
    errors = [
        global_max_abs(
            owned_zeta(solve_on(ball(2.0), penalty=PenaltySpec(kappa=k), discretization=VERTEX)[0])
            - z
        )
        for k in (1e-3, 1e-4, 1e-5)
    ]
    rates = np.log10(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(rates - 1.0) < 0.05), (errors, rates)


def test_curved_gaps_at_points_agree_with_their_linearization() -> None:
    """``at_points`` linearized at η is exact at η, and its derivative is the gradient's."""
    sphere = Sphere((0.0, 0.0, -2.0), 2.0)
    surface = paper_shell().surface
    y = np.array([[0.0, 0.0], [0.1, -0.05], [0.2, 0.1]])
    eta = np.array([[0.0, 0.0, -0.1], [0.01, 0.02, -0.05], [0.0, 0.0, 0.0]])
    lin = sphere.at_points(surface, y, eta)
    exact = sphere.gap(surface.geometry_numpy(y), [eta[:, i] for i in range(3)])
    assert np.allclose(lin.gap(eta), exact, rtol=0, atol=1e-15)
    d = 1e-6 * np.array([0.0, 0.0, 1.0])
    moved = sphere.gap(surface.geometry_numpy(y), [(eta + d)[:, i] for i in range(3)])
    assert np.allclose((moved - exact) / 1e-6, lin.c[:, 2], rtol=0, atol=1e-6)


def test_inside_and_outside_decide_convexity() -> None:
    assert from_spec(ball(2.0, "inside")).convex and not from_spec(ball(2.0)).convex
    assert from_spec(Obstacle()).convex and from_spec(Obstacle(kind="expression", g="x3")).convex


@pytest.mark.mpi
@pytest.mark.parametrize("method", ["newton", "active-set"])
def test_a_ball_on_two_ranks_equals_serial(method: str) -> None:
    penalty, disc = (PENALTY, None) if method == "newton" else (None, VERTEX)
    results = [solve_on(ball(2.0), method, comm, penalty, disc) for comm in (COMM, MPI.COMM_SELF)]
    (par, c_par), (ser, c_ser) = results
    assert par.extra["linearizations"] == ser.extra["linearizations"]
    for key in ("contact_area", "max_violation", "num_contact_nodes"):
        assert c_par[key] == pytest.approx(c_ser[key], rel=1e-9, abs=1e-15), key
    z_par, z_ser = (Postprocessor(r.problem).zeta3_range()[0] for r in (par, ser))
    assert z_par == pytest.approx(z_ser, rel=1e-9)
