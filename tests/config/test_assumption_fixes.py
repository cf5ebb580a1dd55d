"""A failed assumption names its fix, and a bad ``--set`` is blamed on the command line."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import assert_user_error, run

EXAMPLES = Path(__file__).parents[2] / "examples"
PAPER = str(EXAMPLES / "paper.toml")
BALL = str(EXAMPLES / "cap_on_ball.toml")
COARSE = ["--set", "domain.h=0.05"]
EXPRESSION = ["--set", 'obstacle.kind="expression"']


def _row(out: str, name: str) -> str:
    """The table's row of the assumption ``name``."""
    return next(line for line in out.splitlines() if line.startswith(name))


@pytest.mark.parametrize("g", ["log(x3 - 1)", "exp(10000*x3)"])
def test_a_g_not_finite_on_the_reference_shell_says_so(capsys, g: str) -> None:
    """NaN (``log`` of a negative number) or infinite (an overflow where the cap is high; its
    minimum is finite) at the reference shell: the row fails as not finite, and the fix names
    ``obstacle.g``."""
    code, out, err = run(capsys, "check", PAPER, *COARSE, *EXPRESSION, "--set", f'obstacle.g="{g}"')
    assert code == 2, err
    assert "FAIL (g(θ) finite)" in _row(out, "admissible reference"), out
    assert "no finite value or gradient" in out and "change obstacle.g" in out, out


def test_a_membrane_on_a_surface_that_is_not_elliptic_names_koiters_model(capsys) -> None:
    sets = ["--set", "domain.h=0.1", "--set", 'model.kind="membrane"']
    code, out, err = run(capsys, "check", str(EXAMPLES / "cylinder_koiter.toml"), *sets)
    assert code == 2 and "FAIL" in _row(out, "elliptic"), err
    assert "elliptic: the membrane model needs an elliptic surface" in out
    assert 'set model.kind = "koiter"' in out, out


@pytest.mark.parametrize(
    ("sets", "fix"),
    [
        # the cap (top at 0.15) wholly inside the ball of radius 2 about the origin
        (["obstacle.center=[0, 0, 0]", "obstacle.radius=2"], "obstacle.side = 'inside'"),
        # the example's ball below the cap, asked to hold the shell inside it
        (['obstacle.side="inside"'], "obstacle.side = 'outside'"),
    ],
)
def test_a_shell_on_the_wrong_side_of_a_ball_names_the_side(capsys, sets, fix) -> None:
    args = [a for s in sets for a in ("--set", s)]
    code, out, err = run(capsys, "check", BALL, *COARSE, *args)
    assert code == 2 and "FAIL" in _row(out, "admissible reference"), err
    assert "admissible reference: the reference shell lies wholly" in out and fix in out, out


@pytest.mark.parametrize(
    ("config", "bad", "needle"),
    [
        ("paraboloid.toml", 'surface.kind="expression"', "needs 'theta'"),
        ("paraboloid.toml", 'domain.kind="file"', "needs path"),
        ("paraboloid.toml", 'domain.kind="ellipse"', "semi_axes"),
        ("paper.toml", 'surface.kind="ellipsoid_cap"', "needs 'semi_axes'"),
    ],
)
def test_a_set_that_changes_a_kind_without_its_keys_is_blamed(capsys, config, bad, needle):
    """The file is fine for its own kind: the ``--set`` that changed the kind is at fault."""
    code, _, err = run(capsys, "check", str(EXAMPLES / config), "--set", bad)
    assert_user_error(code, err, needle)
    assert err.startswith(f"shellobstacle: error: --set {bad}: "), err


def test_a_files_own_mistake_is_not_blamed_on_an_unrelated_set(capsys, tmp_path) -> None:
    """A key of the file at fault while a ``--set`` gave another key of the section."""
    config = tmp_path / "bad.toml"
    config.write_text(Path(PAPER).read_text().replace("radius = 0.5", "radius = -0.5"))
    code, _, err = run(capsys, "check", str(config), "--set", 'domain.kind="disk"')
    assert_user_error(code, err, "radius")
    assert err.startswith(f"shellobstacle: error: {config}: "), err
