"""The command line: solve, check, the methods' reports, result folders (its errors:
test_command_line_errors.py)."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from mpi4py import MPI

import pytest
from cli_helpers import SMALL, run, write_config

from shellobstacle.cli.main import main
from shellobstacle.io.records import process_environment

#: for the tests whose subject is not the 3D picture (tests/post/test_pictures.py)
NO_PICTURES = ["--set", "output.pictures=false"]
pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")


def test_solve_writes_a_complete_result_folder(tmp_path: Path) -> None:
    """``solve`` writes config, summary, checks, ParaView files and the cross-section figure."""
    out = tmp_path / "run"
    assert main(["solve", str(SMALL), "-o", str(out), "-q", "--set", "domain.h=0.05"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in (
        "converged",
        "iterations",
        "dofs",
        "h",
        "kappa",
        "energy",
        "zeta3_min",
        "zeta3_max",
        "contact_area",
        "contact_area_projected",
        "max_violation",
        "timings",
        "versions",
    ):
        assert key in summary, key
    assert summary["converged"] is True
    assert summary["contact_area"] > 0
    assert summary["contact_area_projected"] <= summary["contact_area"]
    assert summary["kappa"] == pytest.approx(summary["h"] ** 2.0)
    assert summary["versions"]["dolfinx"].startswith("0.11")
    assert summary["versions"]["environment"] == process_environment()
    resolved = tomllib.loads((out / "config.toml").read_text())
    assert resolved["domain"]["h"] == 0.05
    assert resolved["discretization"]["transverse"] == "clamped"
    assert (out / "cross_section.png").stat().st_size > 10_000
    assert (out / "surface.bp").is_dir()
    assert "pass" in (out / "checks.txt").read_text()
    assert "Newton steps" in (out / "log.txt").read_text()


def test_default_folder_is_new_each_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without -o, each run gets its own folder named after the config."""
    monkeypatch.chdir(tmp_path)
    args = ["solve", str(SMALL), "-q", "--set", "domain.h=0.08", "--set", "output.paraview=false"]
    args += NO_PICTURES
    assert main(args) == 0
    assert main(args) == 0
    assert (tmp_path / "small-solve" / "summary.json").is_file()
    assert (tmp_path / "small-solve-2" / "summary.json").is_file()


def test_check_prints_the_assumption_table(capsys: pytest.CaptureFixture) -> None:
    """``check`` prints every assumption with its extreme value and passes on the paper's data."""
    assert main(["check", str(SMALL)]) == 0
    out = capsys.readouterr().out
    for name in (
        "immersion",
        "elliptic",
        "inside half-space",
        "normal towards obstacle",
        "thin shell",
    ):
        assert name in out
    assert "FAIL" not in out


def test_check_and_solve_refuse_a_shell_through_the_plane(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """An offset above the apex puts the shell through the plane: check fails, solve refuses."""
    bad = ["--set", "surface.offset=1.2"]
    assert main(["check", str(SMALL), *bad]) == 2
    assert "FAIL" in capsys.readouterr().out
    assert main(["solve", str(SMALL), "-o", str(tmp_path / "x"), "-q", *bad]) == 2
    err = capsys.readouterr().err
    assert "inside half-space" in err and "θ·q" in err


def test_force_proceeds_and_records_the_warning(tmp_path: Path) -> None:
    """--force solves anyway (here: a saddle surface) and records the failed check."""
    out = tmp_path / "forced"
    args = [
        "solve",
        str(SMALL),
        "-o",
        str(out),
        "-q",
        "--force",
        "--set",
        "surface.kind=expression",
        "--set",
        'surface.theta=["y1", "y2", "0.3 + 0.5*(y1**2 - y2**2)"]',
        "--set",
        "domain.h=0.08",
        "--set",
        "output.paraview=false",
        *NO_PICTURES,
    ]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    elliptic = next(c for c in summary["checks"] if c["name"] == "elliptic")
    assert not elliptic["passed"] and elliptic["value"] < 0
    assert any("elliptic" in w for w in summary["warnings"])


def test_version(capsys: pytest.CaptureFixture) -> None:
    """``--version`` prints the package version, then Python's and the key dependencies'."""
    import dolfinx
    import numpy

    import shellobstacle

    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    first, second = capsys.readouterr().out.splitlines()
    assert first == f"shellobstacle {shellobstacle.__version__}"
    assert f"dolfinx {dolfinx.__version__}, " in second
    assert f"numpy {numpy.__version__}, " in second


def test_solver_failure_writes_the_last_iterate(tmp_path: Path) -> None:
    """A Newton failure exits 1 and leaves a summary saying what failed."""
    out = tmp_path / "fail"
    args = [
        "solve",
        str(SMALL),
        "-o",
        str(out),
        "-q",
        "--set",
        "penalty.continuation=false",
        "--set",
        "solver.max_iterations=1",
        "--set",
        "output.paraview=false",
        *NO_PICTURES,
    ]
    assert main(args) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] is False
    assert "did not converge" in summary["error"]
    assert len(summary["residual_history"]) == 2


def test_active_set_method_reports_kkt(tmp_path: Path) -> None:
    """``solver.method = active-set`` solves κ = 0 and records the KKT residuals."""
    out = tmp_path / "exact"
    args = [
        "solve",
        str(SMALL),
        "-o",
        str(out),
        "-q",
        "--set",
        "solver.method=active-set",
        "--set",
        "discretization.penalty_quadrature=vertex",
        *NO_PICTURES,
    ]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "active-set" and summary["kappa"] == 0.0
    kkt = summary["continuation"][0]["kkt_relative"]
    assert max(kkt.values()) < 1e-10
    assert summary["max_violation"] < 1e-12
    assert summary["contact_area"] > 0


def test_brezis_sibony_method_cap_is_reported(tmp_path: Path) -> None:
    """Brezis–Sibony stopped by its cap exits 1 with converged = false, not a traceback."""
    out = tmp_path / "bs"
    args = [
        "solve",
        str(SMALL),
        "-o",
        str(out),
        "-q",
        "--set",
        "solver.method=brezis-sibony",
        "--set",
        "domain.h=0.1",
        "--set",
        "solver.bs_max_iterations=50",
        "--set",
        "output.paraview=false",
        *NO_PICTURES,
    ]
    assert main(args) == 1
    summary = json.loads((out / "summary.json").read_text())
    step = summary["continuation"][0]
    assert summary["converged"] is False and step["iterations"] == 50
    assert 0 < step["contraction_factor"] < 1


def test_an_experiment_whose_solver_fails_says_so_in_one_line(tmp_path: Path, capsys) -> None:
    """Newton's non-convergence inside a sweep is a solver failure (exit 1, one line with the
    remedy and where the finished steps are), not an internal error."""
    out = tmp_path / "sweep"
    args = ["experiment", "penalty", str(SMALL), "-q", "-o", str(out)]
    args += ["--set", "domain.h=0.1", "--set", "solver.max_iterations=1", "--q-max", "1"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith("shellobstacle: solver failure: Newton did not converge"), err
    assert "raise solver.max_iterations" in err and f"{out}/steps/" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "solver failure: Newton did not converge" in (out / "log.txt").read_text()


def test_a_misspelled_petsc_option_is_a_warning_on_stderr_and_in_the_log(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The warning of an option no PETSc object read (a misspelling) is reported where the
    run's other lines are, once, besides summary.json's ``warnings``."""
    out = tmp_path / "run"
    args = ["solve", str(SMALL), "-o", str(out), "--set", "domain.h=0.1"]
    args += ["--set", "output.figures=false", "--set", "solver.petsc_options.ksp_tpye=cg"]
    capsys.readouterr()
    assert main(args) == 0
    err = capsys.readouterr().err
    warning = "warning: solver.petsc_options.ksp_tpye: no PETSc object of newton read it"
    assert err.count(warning) == 1, err
    assert (out / "log.txt").read_text().count(warning) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert [w for w in summary["warnings"] if "ksp_tpye" in w]
    load = tmp_path / "load"  # an experiment's log too
    paraboloid = SMALL.parent / "paraboloid.toml"
    args = ["experiment", "load", str(paraboloid), "--values", "0,40", "-o", str(load), "-q"]
    args += ["--set", "domain.h=0.1", "--set", "solver.petsc_options.ksp_tpye=cg", *NO_PICTURES]
    assert main(args) == 0
    assert (load / "log.txt").read_text().count(warning) == 1


def test_the_first_line_with_h_names_the_target_too(tmp_path: Path) -> None:
    """The mesh obtained (h, its largest cell diameter) beside the size asked for, in the
    first line that reports h: for solve and for an experiment."""
    import re

    out = tmp_path / "run"
    args = ["solve", str(SMALL), "-o", str(out), "-q", "--set", "domain.h=0.1"]
    assert main([*args, "--set", "output.figures=false"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    with_h = [line for line in (out / "log.txt").read_text().splitlines() if "h = " in line]
    assert f"h = {summary['h']:.4g} (target 0.1)" in with_h[0], with_h
    load = tmp_path / "load"
    paraboloid = SMALL.parent / "paraboloid.toml"
    args = ["experiment", "load", str(paraboloid), "--values", "0", "-o", str(load), "-q"]
    args += ["--set", "domain.h=0.1", *NO_PICTURES]
    assert main(args) == 0
    with_h = [line for line in (load / "log.txt").read_text().splitlines() if "h = " in line]
    assert re.search(r"h = [0-9.]+ \(target 0\.1\), \d+ cells", with_h[0]), with_h


def test_zero_load_solves_to_zero(capsys, tmp_path) -> None:
    changes = {"load.p": ["0", "0", "0"], "output": {"paraview": False, "figures": False}}
    out = tmp_path / "out"
    code, _, err = run(capsys, "solve", str(write_config(tmp_path, changes)), "-o", str(out))
    assert code == 0, err
    assert "Traceback" not in err


def test_brezis_sibony_log_states_one_kappa(tmp_path) -> None:
    out = tmp_path / "bs"
    sets = ["solver.method=brezis-sibony", "output.paraview=false", "output.figures=false"]
    args = ["solve", str(write_config(tmp_path)), "-o", str(out), "-q"]
    assert main(args + [a for s in sets for a in ("--set", s)]) == 0
    log = (out / "log.txt").read_text()
    assert "solving for 1 value of κ" in log and "by Brezis–Sibony" in log
    assert "value(s) of κ" not in log
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["continuation"]) == 1


def test_active_set_with_the_defaults(tmp_path) -> None:
    """No discretization.penalty_quadrature needed: the exact solver's constraint is nodal."""
    out = tmp_path / "exact"
    sets = ["solver.method=active-set", "output.paraview=false", "output.figures=false"]
    args = ["solve", str(write_config(tmp_path)), "-o", str(out), "-q"]
    assert main(args + [a for s in sets for a in ("--set", s)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "active-set" and summary["kappa"] == 0.0
    assert max(summary["continuation"][0]["kkt_relative"].values()) < 1e-10
    resolved = tomllib.loads((out / "config.toml").read_text())
    assert resolved["discretization"]["penalty_quadrature"] == "vertex"
