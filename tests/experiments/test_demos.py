"""The demos under ``demos/`` run as they are and show what their text says."""

from __future__ import annotations

import re
import runpy
from pathlib import Path

from mpi4py import MPI

import matplotlib
import pytest

matplotlib.use("Agg")  # the demos' figures are drawn off screen: plt.show() returns at once
import matplotlib.pyplot as plt

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="the demos run serially")

DEMOS = Path(__file__).parents[2] / "demos"


def run(name: str, capsys: pytest.CaptureFixture[str]) -> tuple[dict, str]:
    namespace = runpy.run_path(str(DEMOS / name), run_name="__main__")
    plt.close("all")
    return namespace, capsys.readouterr().out


def test_every_demo_is_tested() -> None:
    assert {p.name for p in DEMOS.glob("*.py")} == {
        "paper_problem.py",
        "own_shell.py",
        "kappa_sweep.py",
        "koiter_cylinder.py",
        "rigid_obstacles.py",
    }


def test_paper_problem(capsys: pytest.CaptureFixture[str]) -> None:
    ns, out = run("paper_problem.py", capsys)
    assert all(check.passed for check in ns["result"].checks)
    assert ns["result"].converged
    assert ns["summary"]["contact_area"] > 0
    assert re.search(r"contact_area\s+\d\.\d{4}e-0\d", out)


def test_own_shell_reaches_the_plane(capsys: pytest.CaptureFixture[str]) -> None:
    ns, out = run("own_shell.py", capsys)
    assert ns["result"].converged
    assert ns["summary"]["contact_area"] > 0
    assert "converged True" in out


def test_kappa_sweep_error_is_first_order_in_kappa(capsys: pytest.CaptureFixture[str]) -> None:
    """On a fixed mesh, with the vertex constraint, ζ_κ − ζ^h falls like κ once the active set
    is the exact one (a quadratic program; the demo's text), faster than Theorem 7.1's √κ."""
    ns, out = run("kappa_sweep.py", capsys)
    assert len(ns["rates"]) == 3
    assert all(0.9 <= r <= 1.1 for r in ns["rates"]), ns["rates"]
    assert "observed orders in κ" in out


def test_koiter_cylinder_thin_panel_touches_thick_one_does_not(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The panel starts 0.1 above the plane: the thin one is stopped there (ζ_3 ≥ −0.1 up to
    the penalty's penetration, contact on part of the loaded disk), the thick one, eight times
    stiffer in bending, stays off the plane."""
    ns, out = run("koiter_cylinder.py", capsys)
    thin, thick = ns["thin"], ns["thick"]
    assert 0 < thin["contact_area"] < 3.15 * 0.15**2
    assert -0.1 - 1e-3 < thin["zeta3_min"] < -0.099
    assert thick["contact_area"] == 0
    assert -0.099 < thick["zeta3_min"] < 0
    assert "ε = 0.01: contact area" in out


def test_rigid_obstacles(capsys: pytest.CaptureFixture[str]) -> None:
    """What the demo's text says: the formula is the plane, the ball of radius 10 is within
    1e-4 of the plane, the lower face stops ε higher."""
    ns, out = run("rigid_obstacles.py", capsys)
    rows = ns["rows"]
    plane, formula = rows["plane x3 = 0"], rows["g = x3 (a formula)"]
    assert "linearizations" not in formula[0].extra and formula[1:] == plane[1:]
    assert abs(rows["ball R = 10"][2] - plane[2]) < 1e-4
    assert rows["ball R = 10"][0].extra["linearizations"] >= 2
    assert rows["plane, lower face"][2] - plane[2] == pytest.approx(1e-3, rel=0.05)
    assert all(r[0].converged for r in rows.values()) and "ball R = 0.5" in out
