"""Every ``examples/*.toml`` loads, passes ``check`` at its own size and solves on a coarse mesh.

The solves use ``--set domain.h=0.08`` to stay fast (a few seconds each); the ellipsoid and
paraboloid examples must reach the plane (contact area > 0) even there.
"""

from __future__ import annotations

import json
from pathlib import Path

from mpi4py import MPI

import pytest

from shellobstacle.cli.main import main
from shellobstacle.config.loader import load_config

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")

EXAMPLES = sorted((Path(__file__).parents[2] / "examples").glob("*.toml"))
WITH_CONTACT = {"ellipsoid.toml", "paraboloid.toml", "cylinder_koiter.toml"}
#: coarse, yet fine enough for every example's solution to be inside the model's validity (at
#: 0.08 the paraboloid's bump load, 3 cells across, penetrates the plane by 11 % of its height)
COARSE = "domain.h=0.06"
#: the roller (radius 0.3) spans 3.6 of the coarse mesh's cells, too few (post/resolution);
#: at the example's own h = 0.02 there is no warning
COARSE_WARNINGS = {"koiter_panel_on_roller.toml": "the mesh does not resolve the obstacle"}


def _ids(path: Path) -> str:
    return path.stem


def test_the_examples_are_there() -> None:
    names = {p.name for p in EXAMPLES}
    assert WITH_CONTACT | {"paper.toml", "small.toml"} <= names


@pytest.mark.parametrize("path", EXAMPLES, ids=_ids)
def test_example_loads(path: Path) -> None:
    cfg = load_config(path)
    assert cfg.source == str(path)
    assert cfg.shell.surface.description
    assert cfg.penalty.kappa is not None or cfg.penalty.exponent is not None


@pytest.mark.parametrize("path", EXAMPLES, ids=_ids)
def test_example_passes_check(path: Path, capsys: pytest.CaptureFixture) -> None:
    """All assumptions hold at the example's own mesh size (Koiter's model does not need the
    Gaussian curvature to be positive)."""
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "FAIL" not in out
    koiter = load_config(path).shell.model == "koiter"
    assert out.count("pass") == (4 if koiter else 5), out
    assert out.count("not required: Koiter's model") == (1 if koiter else 0), out


@pytest.mark.parametrize("path", EXAMPLES, ids=_ids)
def test_example_solves(path: Path, tmp_path: Path) -> None:
    """The example solves on a coarse mesh; the new examples touch the plane."""
    out = tmp_path / "run"
    assert main(["solve", str(path), "-o", str(out), "-q", "--set", COARSE]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] is True
    assert summary["error"] is None
    assert all(c["passed"] for c in summary["checks"])
    assert summary["validity"]["valid"] is True
    # beyond linear kinematics is a warning, not a violation (post/validity.py)
    kinematics = [w for w in summary["warnings"] if w.startswith("beyond linear kinematics")]
    assert summary["validity"]["beyond_linear_kinematics"] is (len(kinematics) == 1)
    others = [w for w in summary["warnings"] if w not in kinematics]
    expected = COARSE_WARNINGS.get(path.name)
    if expected is None:
        assert others == []
    else:
        assert len(others) == 1 and others[0].startswith(expected)
    assert (out / "cross_section.png").is_file() and (out / "surface.bp").is_dir()
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no temporaries
    if path.name in WITH_CONTACT:
        assert summary["contact_area"] > 0
        assert 0 < summary["contact_area_projected"] <= summary["contact_area"]
        # the apex has been pushed down to the plane: ζ_3 reaches about −(apex height)
        assert summary["zeta3_min"] < -0.1


def test_overwrite_replaces_every_output(tmp_path: Path) -> None:
    """A second run with --overwrite replaces the figure and the .bp folders in place."""
    path = next(p for p in EXAMPLES if p.name == "paraboloid.toml")
    out = tmp_path / "run"
    args = ["solve", str(path), "-o", str(out), "-q", "--set", COARSE]
    assert main(args) == 0
    first = json.loads((out / "summary.json").read_text())
    png = (out / "cross_section.png").read_bytes()
    bp = {p.name: p.read_bytes() for p in (out / "surface.bp").iterdir()}
    assert main([*args, "--overwrite", "--set", "load.parameters={ ell = 80.0 }"]) == 0
    second = json.loads((out / "summary.json").read_text())
    assert second["energy"] < first["energy"] < 0  # twice the load: lower energy
    assert (out / "cross_section.png").read_bytes() != png
    assert {p.name: p.read_bytes() for p in (out / "surface.bp").iterdir()} != bp
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]
