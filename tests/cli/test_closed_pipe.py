"""A reader that goes away (``shellobstacle config-reference | head -1``) ends the command
quietly: exit status 141 (128 + SIGPIPE, as a shell reports such a command), no PETSc error
dump, no traceback; a run whose stderr is closed goes on and writes its results.

The pipe's reading end is closed before the command starts, so every write into it fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from mpi4py import MPI

import pytest

from shellobstacle.cli.main import EXIT_CLOSED_PIPE

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="runs its own processes")
SMALL = str(Path(__file__).parents[2] / "examples" / "small.toml")


def _closed_pipe() -> int:
    """The writing end of a pipe whose reader has gone."""
    read, write = os.pipe()
    os.close(read)
    return write


def _run(args: list[str], closed: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """``shellobstacle args`` with its stdout or stderr (``closed``) into a closed pipe."""
    pipe = _closed_pipe()
    streams = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, closed: pipe}
    try:
        return subprocess.run(
            [sys.executable, "-m", "shellobstacle", *args],
            **streams,
            text=True,
            timeout=300,
            cwd=cwd,
        )
    finally:
        os.close(pipe)


@pytest.mark.parametrize(
    "args",
    [
        ["config-reference"],
        ["doctor"],
        ["--version"],
        ["--help"],
        ["check", SMALL, "--set", "domain.h=0.1"],
    ],
    ids=["config-reference", "doctor", "version", "help", "check"],
)
def test_a_closed_stdout_ends_the_command_quietly(args: list[str]) -> None:
    result = _run(args, "stdout")
    assert result.returncode in (0, EXIT_CLOSED_PIPE), result.stderr
    if args != ["--help"]:  # (argparse prints its help and ignores the failed write)
        assert result.returncode == EXIT_CLOSED_PIPE, result.stderr
    assert result.stderr == ""


def test_a_run_with_a_closed_stderr_writes_its_results(tmp_path: Path) -> None:
    """The progress lines cannot be shown: the run goes on, its log.txt has every line."""
    out = tmp_path / "run"
    args = ["solve", SMALL, "-o", str(out), "--set", "domain.h=0.1"]
    result = _run([*args, "--set", "output.figures=false"], "stderr")
    assert result.returncode == 0
    assert json.loads((out / "summary.json").read_text())["converged"]
    assert (out / "log.txt").read_text().splitlines()[-1].split("] ")[1].startswith("done: ")
