"""What the command line refuses or reports: a user error is exit code 2 and one line naming
the argument, never a traceback; a solver that fails and a bug exit 1.

``--set``: malformed, naming itself rather than the file, replacing κ's form, reaching into a
table, changing a kind without its keys; a number as an option's value; a missing config
file; an output folder that holds results; Newton's failure; an internal error.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from cli_helpers import EXAMPLES, SMALL, assert_user_error, run, serial, write_config

from shellobstacle.cli.main import main
from shellobstacle.config.loader import load_config

pytestmark = serial

PAPER = str(EXAMPLES / "paper.toml")

# --------------------------------------------------------------------------- --set


def test_malformed_set_option(capsys) -> None:
    code, _, err = run(capsys, "check", str(SMALL), "--set", "domainh0.1")
    assert_user_error(code, err, "--set 'domainh0.1'", "expected section.key=value")


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("domain.hh=0.1", "did you mean 'h'"),
        ("material.epsilon=-1", "epsilon must be > 0"),
        ("penalty.kappa=0", "--set penalty.kappa=0: penalty.kappa must be > 0"),
        ('load.p=["0", "0", "import os"]', "load.p[3]"),
        ("obstacle.q=[0, 0, 0]", "nonzero normal"),
        ("surface.kind=sphere", "did you mean 'spherical_cap'"),
    ],
)
def test_config_errors_exit_2_with_a_message(
    override: str, message: str, capsys: pytest.CaptureFixture
) -> None:
    """User errors give exit code 2 and one clear line, no traceback."""
    assert main(["check", str(SMALL), "--set", override]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err


def test_degree_3_through_set(capsys) -> None:
    """The same errors come from ``--set`` overrides, naming the ``--set``, not the file."""
    code, _, err = run(capsys, "check", str(SMALL), "--set", "discretization.degree=3")
    assert_user_error(
        code, err, "--set discretization.degree=3: discretization.degree must be 1 or 2"
    )
    assert "small.toml" not in err


def test_set_kappa_replaces_the_files_exponent(capsys) -> None:
    paper = EXAMPLES / "paper.toml"
    assert "exponent" in tomllib.loads(paper.read_text())["penalty"]
    cfg = load_config(paper, ["penalty.kappa=1e-3"])
    assert (cfg.penalty.kappa, cfg.penalty.exponent) == (1e-3, None)
    assert cfg.resolved["penalty"].get("exponent") is None


def test_set_exponent_replaces_the_files_kappa(tmp_path) -> None:
    path = write_config(tmp_path, {"penalty": {"kappa": 1e-6}})
    cfg = load_config(path, ["penalty.exponent=1.5"])
    assert (cfg.penalty.kappa, cfg.penalty.exponent) == (None, 1.5)


def test_set_both_kappa_and_exponent_names_both(capsys) -> None:
    args = ("--set", "penalty.kappa=1e-3", "--set", "penalty.exponent=1.5")
    code, _, err = run(capsys, "check", str(SMALL), *args)
    assert_user_error(
        code,
        err,
        "--set penalty.kappa=1e-3, --set penalty.exponent=1.5: give either penalty.kappa or "
        "penalty.exponent, not both",
    )


def test_set_reaches_into_a_table() -> None:
    cfg = load_config(EXAMPLES / "paraboloid.toml", ["load.parameters.ell=3"])
    assert cfg.shell.load.parameters["ell"] == 3.0
    cfg = load_config(SMALL, ["load.parameters.ell=3"])  # a table the file does not have
    assert cfg.shell.load.parameters == {"ell": 3.0}


@pytest.mark.parametrize(
    ("item", "needles"),
    [
        ("load.foo=1", ("--set load.foo=1: unknown key 'foo' in [load]",)),
        ("material.mu=abc", ("--set material.mu=abc: material.mu must be a number",)),
        ("penalty.exponent=0", ("--set penalty.exponent=0: penalty.exponent must be in (0, 20]",)),
        ("load.parameters.ell=big", ("--set load.parameters.ell=big: load.parameters.ell",)),
        ("load.p.x=1", ("--set load.p.x=1: load.p is not a table",)),
        ("materail.mu=1", ("--set materail.mu=1: unknown section [materail]",)),
    ],
)
def test_set_errors_name_the_set(capsys, item: str, needles: tuple[str, ...]) -> None:
    code, _, err = run(capsys, "check", str(SMALL), "--set", item)
    assert_user_error(code, err, *needles)
    assert "small.toml" not in err


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


def test_huge_integer_is_a_user_error(capsys) -> None:
    code, _, err = run(capsys, "check", str(SMALL), "--set", "material.epsilon=1" + "0" * 400)
    assert_user_error(code, err, "material.epsilon")


# --------------------------------------------------------------------------- arguments


def test_missing_config_file(capsys: pytest.CaptureFixture) -> None:
    """A config path that does not exist is named in the error."""
    assert main(["solve", "no-such-file.toml"]) == 2
    assert "no-such-file.toml" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["koiter-limit", "--epsilons", "-1e-2"], "--epsilons"),
        (["koiter-limit", "--epsilons", "-1e-2,1e-3"], "--epsilons"),
        (["koiter-limit", "--edge-h", "-.5"], "--edge-h"),
        (["penalty", "--start", "-0.5"], "--start"),
        (["load", "--values", "-1,2", "--parameter", "nope"], "nope"),
    ],
)
def test_negative_number_as_an_option_value(capsys, tmp_path, monkeypatch, args, needle) -> None:
    """``--epsilons -1e-2`` reaches the option's check (before: argparse's usage, 14 lines)."""
    monkeypatch.chdir(tmp_path)
    batch, *options = args
    code, _, err = run(capsys, "experiment", batch, str(SMALL), *options)
    assert_user_error(code, err, needle)
    assert not any(tmp_path.iterdir()), "a refused command made a folder"


# --------------------------------------------------------------------------- results, solver, bugs


def test_output_folder_with_results(capsys, tmp_path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    code, _, err = run(capsys, "solve", str(write_config(tmp_path)), "-o", str(out), "-q")
    assert_user_error(code, err, str(out), "already holds results", "--overwrite")
    assert (out / "summary.json").read_text() == "{}"


def test_solver_failure_exits_1_without_traceback(capsys, tmp_path) -> None:
    changes = {
        "penalty.continuation": False,
        "solver": {"max_iterations": 1},
        "output": {"paraview": False, "figures": False},
    }
    out = tmp_path / "out"
    code, _, err = run(capsys, "solve", str(write_config(tmp_path, changes)), "-o", str(out))
    assert code == 1
    assert "Traceback" not in err
    assert "FAILED: Newton did not converge" in err
    assert "no convergence in 1 Newton iterations" in err
    assert (out / "summary.json").is_file()


def test_internal_error_exits_1_with_traceback(capsys, monkeypatch) -> None:
    """A bug (any other exception) prints the traceback and asks for a report."""
    import shellobstacle.api

    def broken(_domain):
        raise RuntimeError("simulated bug in make_mesh")

    monkeypatch.setattr(shellobstacle.api, "make_mesh", broken)
    code, _, err = run(capsys, "check", str(SMALL))
    assert code == 1
    assert "Traceback (most recent call last)" in err
    assert "RuntimeError: simulated bug in make_mesh" in err
    assert "internal error (a bug): please report it" in err
