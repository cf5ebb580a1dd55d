"""Koiter's nonlinear model selected by ``[model] kinematics = "nonlinear"`` and solved
against its obstacle (docs/model.md §11.3): the load stepped at the first κ, the κ ladder
continued at load 1.

- through the command line, an obstacle out of reach: ζ is the nonlinear problem's without
  obstacle (NonlinearKoiterProblem + LoadStepping directly), the load path is in the summary,
  and no 'beyond linear kinematics' warning;
- at a ten-thousandth of the load, in contact, the nonlinear answer is the linear one to 1e-3;
- at 1.5 thicknesses of linear deflection, pressed onto a plane: contact, but less of it and a
  smaller deflection than the linear model's (the membrane stiffening);
- membrane, the hybrid bending form and multigrid refused in one line; the linear model's
  warning names the remedy.

The issue's clamped plate (disk of radius 0.5, ε = 0.005, ν = 0.3, h = 0.1); its load is a
parameter ``P`` (a Constant: every load compiles the same kernels, at -O0).
"""

from __future__ import annotations

import json

from mpi4py import MPI

import numpy as np
import pytest
from cli_helpers import run

from shellobstacle.api import solve
from shellobstacle.config.loader import ConfigError, to_toml
from shellobstacle.geometry.surface import Surface
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.models.nonlinear_koiter import FAST_COMPILE, NonlinearKoiterProblem
from shellobstacle.post.validity import Validity
from shellobstacle.solvers.nonlinear.load_stepping import LoadStepping
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

#: the issue's plate load (linear deflection 1.49 thicknesses)
P = -3.628e-6
#: its linear Koiter deflection at h = 0.1 (of the order of the closed form's 0.01486)
W_LINEAR = 0.0149


def plate(p: float, c: float, kinematics: str = "nonlinear") -> dict:
    """The plate's configuration, load ``p``, the plane ``x_3 = c`` below it."""
    return {
        "surface": {"kind": "expression", "theta": ["y1", "y2", "0"]},
        "domain": {"kind": "disk", "radius": 0.5, "h": 0.1},
        "material": {"epsilon": 0.005, "lambda": 1.5, "mu": 1.0},
        "load": {"p": ["0", "0", "P"], "parameters": {"P": p}},
        "model": {"kind": "koiter", "kinematics": kinematics},
        "discretization": {"bending": "c0ip"},
        "obstacle": {"kind": "plane", "q": [0, 0, 1], "c": c},
        "penalty": {"exponent": 2.0},
    }


def test_the_command_line_solves_the_nonlinear_plate_as_the_problem_does(capsys, tmp_path):
    """An obstacle out of reach: the CLI's ζ_3 is load stepping's on the plate without
    obstacle, the load path is recorded step by step, and nothing is 'beyond linear'."""
    config = tmp_path / "plate.toml"
    config.write_text(to_toml(plate(P, -1.0)))
    code, _, err = run(capsys, "solve", str(config), "-o", str(tmp_path / "out"), "-q")
    assert code == 0, err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["converged"] and summary["contact_area"] == 0.0
    path = summary["load_path"]["steps"]
    assert path[0]["load_factor"] == 0.0 and path[-1]["load_factor"] == 1.0
    assert not [w for w in summary["warnings"] if w.startswith("beyond linear")]

    shell = Shell(
        Surface.from_strings(["y1", "y2", "0"]), Material(0.005, 1.5, 1.0),
        Load(("0", "0", "P"), {"P": P}), Obstacle(), "koiter",
    )  # fmt: skip
    mesh = create_mesh(DomainSpec(kind="disk", h=0.1, radius=0.5), MPI.COMM_WORLD, ghosted=True)
    problem = NonlinearKoiterProblem(
        shell, mesh, Discretization(degree=2, bending="c0ip"), jit_options=FAST_COMPILE
    )
    LoadStepping(problem).solve(1.0)
    w = problem.zeta.x.array.reshape(-1, 3)[:, 2].min()
    assert summary["zeta3_min"] == pytest.approx(w, rel=1e-8)
    assert 0.5 * W_LINEAR < -w < 0.8 * W_LINEAR  # a third smaller than linear (issue 57)


def test_at_a_tiny_load_in_contact_the_nonlinear_answer_is_the_linear_one() -> None:
    """Load × 1e-4 onto a plane at half the linear deflection: the two answers agree to 1e-3
    (their difference is O(load) relative), with contact in both."""
    p, c = 1e-4 * P, -0.5e-4 * W_LINEAR
    nonlinear = solve(plate(p, c))
    linear = solve(plate(p, c, "linear"))
    assert nonlinear.converged and linear.converged
    assert linear.contact.area > 0 and nonlinear.contact.area > 0
    zn, zl = nonlinear.problem.zeta.x.array, linear.problem.zeta.x.array
    assert np.linalg.norm(zn - zl) <= 1e-3 * np.linalg.norm(zl)
    assert nonlinear.contact.area == pytest.approx(linear.contact.area, rel=1e-3)


def test_pressed_onto_a_plane_at_large_deflection_the_nonlinear_plate_touches_less() -> None:
    """The full load onto the plane at 0.6 of the linear deflection (below the nonlinear
    plate's free deflection): both touch it, the nonlinear plate on a smaller area and
    with a smaller deflection (the penetration too), stiffened by the membrane strain."""
    c = -0.6 * W_LINEAR
    nonlinear = solve(plate(P, c))
    linear = solve(plate(P, c, "linear"))
    assert nonlinear.converged and linear.converged
    assert 0 < nonlinear.contact.area < linear.contact.area
    wn, wl = (r.problem.zeta.x.array.reshape(-1, 3)[:, 2] for r in (nonlinear, linear))
    assert wn.min() > wl.min() and np.mean(wn) > np.mean(wl)  # less deflection, in the mean


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        (
            {"model": {"kind": "membrane", "kinematics": "nonlinear"}, "discretization": {}},
            "Koiter",
        ),
        ({"discretization": {"bending": "hybrid"}}, "c0ip"),
        ({"solver": {"linear_solver": "multigrid"}}, "direct"),
        ({"solver": {"method": "active-set"}, "penalty": {}}, "newton"),
    ],
)
def test_what_the_nonlinear_kinematics_cannot_take_is_refused_in_one_line(change, needle):
    """The membrane (no bending stiffness in compression), the hybrid bending form, multigrid
    and a method other than Newton's: one line naming the fix, before any mesh."""
    with pytest.raises(ConfigError) as err:
        solve({**plate(P, -1.0), **change})
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_the_linear_models_warning_names_the_remedy() -> None:
    """Beyond linear kinematics: Koiter's warning names the nonlinear kinematics, the
    membrane's to reduce the load."""
    koiter = Validity(0.0, 0.01, 1.0, None, nonlinearity=0.7).warnings()
    membrane = Validity(0.0, 0.01, 1.0, None, nonlinearity=0.7, model="membrane").warnings()
    (koiter,) = [w for w in koiter if w.startswith("beyond linear kinematics")]
    (membrane,) = [w for w in membrane if w.startswith("beyond linear kinematics")]
    assert koiter.endswith('set [model] kinematics = "nonlinear"')
    assert membrane.endswith("reduce the load (the membrane has linear kinematics only)")
