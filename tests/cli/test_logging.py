"""Progress through :mod:`logging`: the library logs to the ``shellobstacle`` logger and prints
nothing itself; the command line prints the records once (rank 0), ``-q`` keeps only errors on
the terminal and ``-v`` adds the Newton iterations."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

from mpi4py import MPI

import pytest
from cli_helpers import SMALL, run_on_all_ranks, serial

from shellobstacle.api import solve
from shellobstacle.config.loader import load_config

QUICK = ["--set", "domain.h=0.1", "--set", "output.figures=false"]


@pytest.mark.mpi
def test_a_library_solve_logs_its_progress_to_the_shellobstacle_logger(caplog) -> None:
    """A solve through the API: the mesh obtained, the method's start and each κ are records
    of the ``shellobstacle`` loggers (one per module), which pytest's handler sees."""
    cfg = load_config(SMALL, ["domain.h=0.1"])
    with caplog.at_level(logging.INFO, logger="shellobstacle"):
        result = solve(cfg)
    assert result.converged
    messages = caplog.messages
    assert any(m.startswith("meshed the disk: h = ") for m in messages), messages
    assert any("dofs; solving for" in m for m in messages), messages
    kappas = [m for m in messages if m.startswith("κ ")]
    assert len(kappas) == len(result.steps) and "Newton steps" in kappas[-1], messages
    assert all(r.name.startswith("shellobstacle.") for r in caplog.records)
    assert {r.name for r in caplog.records} >= {
        "shellobstacle.api",
        "shellobstacle.solvers.methods.newton",
        "shellobstacle.solvers.newton.continuation",
    }
    assert not any(r.levelno == logging.DEBUG for r in caplog.records)  # (INFO asked)


@pytest.mark.mpi
def test_newton_iterations_are_debug_records(caplog) -> None:
    cfg = load_config(SMALL, ["domain.h=0.1"])
    with caplog.at_level(logging.DEBUG, logger="shellobstacle"):
        solve(cfg)
    debug = [r.getMessage() for r in caplog.records if r.levelno == logging.DEBUG]
    assert any(m.startswith("    Newton 1: relative residual ") for m in debug), debug
    assert any(m.startswith("    Newton: ") and "step lengths" in m for m in debug), debug


@serial
def test_the_library_configures_no_output() -> None:
    """In a fresh process: importing and solving adds no handler to the root logger and prints
    nothing, also not a warning record (the package's ``NullHandler`` keeps Python's
    last-resort handler, which prints warnings to stderr, out of it)."""
    code = f"""
import logging
import shellobstacle
from shellobstacle.api import solve
from shellobstacle.config.loader import load_config
solve(load_config({str(SMALL)!r}, ["domain.h=0.1"]))
logging.getLogger("shellobstacle.api").warning("nobody asked for this line")
assert logging.getLogger().handlers == [], logging.getLogger().handlers
"""
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == "" and done.stderr == ""


@pytest.mark.mpi
def test_the_command_line_prints_each_line_once_on_rank_0(shared_dir: Path, capfd) -> None:
    """``solve`` (on 2 ranks under ``mpiexec -n 2 pytest``): rank 0 prints every line once,
    the lines of log.txt; the other ranks print nothing. The handler goes with the command."""
    out = shared_dir / "run"
    assert run_on_all_ranks(["solve", str(SMALL), "-o", str(out), *QUICK]) == 0
    err = capfd.readouterr().err
    if MPI.COMM_WORLD.rank == 0:
        lines = err.splitlines()
        assert lines == (out / "log.txt").read_text().splitlines()
        assert len(lines) == len(set(lines))
        assert sum("meshed the disk" in line for line in lines) == 1
        assert any("] κ 1/" in line for line in lines) and "] done: κ" in lines[-1]
    else:
        assert err == ""
    package = logging.getLogger("shellobstacle")
    assert [type(h) for h in package.handlers] == [logging.NullHandler]
    assert package.level == logging.NOTSET


@serial
def test_quiet_keeps_the_log_file_and_verbose_adds_the_newton_iterations(tmp_path, capfd) -> None:
    """``-q``: nothing on stderr, every line in log.txt; ``-v``: the Newton iterations (debug
    records) on stderr and in log.txt."""
    assert run_on_all_ranks(["solve", str(SMALL), "-q", "-o", str(tmp_path / "q"), *QUICK]) == 0
    assert capfd.readouterr().err == ""
    quiet = (tmp_path / "q" / "log.txt").read_text()
    assert "meshed the disk" in quiet and "done: κ" in quiet and "Newton 1:" not in quiet
    assert run_on_all_ranks(["solve", str(SMALL), "-v", "-o", str(tmp_path / "v"), *QUICK]) == 0
    err = capfd.readouterr().err
    log = (tmp_path / "v" / "log.txt").read_text()
    for text in (err, log):
        assert "    Newton 1: relative residual " in text and "step lengths" in text
