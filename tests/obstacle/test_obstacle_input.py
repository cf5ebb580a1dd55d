"""Bad ``[obstacle]`` input: one line, exit 2, naming the key and the fix; an obstacle the
reference shell does not lie beside fails ``check`` with the fix named."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import assert_user_error, check_row, run

from shellobstacle.spec import Obstacle

EXAMPLES = Path(__file__).parents[2] / "examples"
BALL = str(EXAMPLES / "cap_on_ball.toml")
PAPER = str(EXAMPLES / "paper.toml")
COARSE = ["--set", "domain.h=0.05"]
EXPRESSION = ["--set", 'obstacle.kind="expression"']


def _cylinder(tmp_path: Path, axis: str) -> str:
    text = (
        Path(BALL)
        .read_text()
        .replace(
            'kind = "sphere"\ncenter = [0.0, 0.0, -2.0]',
            f'kind = "cylinder"\npoint = [0.0, 0.0, -2.0]\naxis = {axis}',
        )
    )
    path = tmp_path / "cylinder.toml"
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(
    ("config", "sets", "needles"),
    [
        (BALL, ["obstacle.radius=0"], ["obstacle.radius", "> 0"]),
        (BALL, ["obstacle.radius=-1"], ["obstacle.radius", "> 0"]),
        (BALL, ['obstacle.side="outsde"'], ["obstacle.side", "did you mean 'outside'"]),
        (BALL, ['obstacle.contact_face="lowr"'], ["obstacle.contact_face", "'lower'"]),
        (BALL, ["obstacle.c=0.1"], ["obstacle.c", "obstacle.kind = 'plane'"]),
        (BALL, ["obstacle.center=[0, 0]"], ["obstacle.center", "3 values"]),
        (PAPER, ['obstacle.kind="sphere"', "obstacle.radius=1"], ["obstacle.center"]),
        (PAPER, ['obstacle.kind="cube"'], ["obstacle.kind", "sphere"]),
    ],
)
def test_bad_obstacle_keys_exit_2(capsys, config: str, sets: list[str], needles: list[str]):
    args = [a for s in sets for a in ("--set", s)]
    code, _, err = run(capsys, "check", config, *COARSE, *args)
    assert_user_error(code, err.split("\n", err.count("warning:"))[-1], *needles)


def test_an_axis_of_zero_length_is_refused(capsys, tmp_path: Path) -> None:
    code, _, err = run(capsys, "check", _cylinder(tmp_path, "[0, 0, 0]"), *COARSE)
    assert_user_error(code, err, "obstacle.axis", "nonzero")


@pytest.mark.parametrize(
    ("g", "needles"),
    [
        ("Abs(x3)", ["obstacle.g", "differentiable"]),
        ("Max(x3, x1 - 1)", ["obstacle.g", "differentiable"]),
        ("x3 + y1", ["obstacle.g", "y1"]),
        ("x3 +", ["obstacle.g", "parse"]),
    ],
)
def test_a_bad_g_is_refused(capsys, g: str, needles: list[str]) -> None:
    code, _, err = run(capsys, "check", PAPER, *COARSE, *EXPRESSION, "--set", f'obstacle.g="{g}"')
    assert_user_error(code, err.strip().splitlines()[-1] + "\n", *needles)


@pytest.mark.parametrize("g", ["log(x3 - 1)", "x3 - 0.5"])
def test_a_g_not_finite_or_crossed_by_the_reference_shell_fails_the_check(capsys, g: str):
    """``log(x3 − 1)`` has no value where the shell is; the cap (top at 0.15) crosses
    ``x3 = 0.5``: the check names the failing row and exits 2."""
    code, out, err = run(capsys, "check", PAPER, *COARSE, *EXPRESSION, "--set", f'obstacle.g="{g}"')
    assert code == 2 and "admissible reference" in err, err
    assert "g(θ)" in out and "FAIL" in out.split("admissible reference")[1].splitlines()[0], out


def test_another_shapes_key_in_the_file_is_ignored_when_a_set_changes_the_shape(capsys):
    """The paper's file gives ``q``; ``--set obstacle.kind=...`` means the shape changed: the
    file's ``q`` is reported ignored (a warning), not refused."""
    code, out, err = run(capsys, "check", PAPER, *COARSE, *EXPRESSION, "--set", 'obstacle.g="x3"')
    assert code == 0, err
    assert "obstacle.q is ignored" in err and "convex admissible set" in out


def test_the_api_refuses_what_the_config_refuses() -> None:
    with pytest.raises(ValueError, match=r"obstacle\.radius"):
        Obstacle(kind="sphere", center=(0, 0, -1), radius=0.0)
    with pytest.raises(ValueError, match=r"needs obstacle\.g"):
        Obstacle(kind="expression")
    with pytest.raises(ValueError, match=r"obstacle\.axis"):
        Obstacle(kind="cylinder", point=(0, 0, 0), axis=(0, 0, 0), radius=1.0)


@pytest.mark.parametrize("g", ["log(x3 - 1)", "exp(10000*x3)"])
def test_a_g_not_finite_on_the_reference_shell_says_so(capsys, g: str) -> None:
    """NaN (``log`` of a negative number) or infinite (an overflow where the cap is high; its
    minimum is finite) at the reference shell: the row fails as not finite, and the fix names
    ``obstacle.g``."""
    code, out, err = run(capsys, "check", PAPER, *COARSE, *EXPRESSION, "--set", f'obstacle.g="{g}"')
    assert code == 2, err
    assert "FAIL (g(θ) finite)" in check_row(out, "admissible reference"), out
    assert "no finite value or gradient" in out and "change obstacle.g" in out, out


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
    assert code == 2 and "FAIL" in check_row(out, "admissible reference"), err
    assert "admissible reference: the reference shell lies wholly" in out and fix in out, out
