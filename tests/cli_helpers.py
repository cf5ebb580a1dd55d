"""Helpers shared by the command-line tests: running ``main`` and asserting a user error."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from mpi4py import MPI

import pytest

from shellobstacle.cli.main import main

COMM = MPI.COMM_WORLD


def run(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    """``main(args)``: exit code, stdout, stderr."""
    capsys.readouterr()
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def run_on_all_ranks(args: list[str]) -> int:
    """``main(args)`` on every rank; returns once rank 0 has written its files."""
    code = main(args)
    COMM.barrier()
    return code


def assert_user_error(code: int, err: str, *needles: str) -> None:
    """Exit code 2, one ``shellobstacle: error:`` line naming every needle, no traceback."""
    assert code == 2, err
    assert "Traceback" not in err, err
    assert err.startswith("shellobstacle: error: "), err
    assert len(err.strip().splitlines()) == 1, err
    for needle in needles:
        assert needle in err, f"{needle!r} not in {err!r}"


def shared_folder(tmp_path: Path) -> Iterator[Path]:
    """A folder that every MPI rank sees (rank 0's temporary folder), removed afterwards."""
    path = Path(tempfile.mkdtemp(dir=tmp_path)) if COMM.rank == 0 else None
    path = COMM.bcast(path, root=0)
    yield path
    COMM.barrier()
    if COMM.rank == 0:
        shutil.rmtree(path, ignore_errors=True)


def mpiexec() -> str | None:
    """The mpiexec that ``./run test`` uses (``MPIEXEC``, else the one beside this Python, else
    the one on PATH), or None."""
    beside = Path(sys.executable).parent / "mpiexec"
    if os.environ.get("MPIEXEC"):
        return os.environ["MPIEXEC"]
    return str(beside) if beside.exists() else shutil.which("mpiexec")
