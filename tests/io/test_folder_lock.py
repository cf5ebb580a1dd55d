"""One run at a time per result folder (shellobstacle.io.lock), with real processes.

A first run (a separate process, serial or under ``mpiexec -n 2``) prepares ``-o OUT`` and then
waits before solving; every command run into OUT meanwhile is refused with exit 2 and one line
naming the folder and the first run's process; after ``kill -9`` of the first run, its lock
blocks nothing.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

from mpi4py import MPI

import pytest
from cli_helpers import assert_user_error, mpiexec, run

ROOT = Path(__file__).parents[2]
SMALL = str(ROOT / "examples" / "small.toml")
QUICK = ["-q", "--set", "domain.h=0.1", "--set", "output.figures=false"]
QUICK += ["--set", "output.paraview=false"]

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="runs its own processes")

#: a solve that waits (holding its folder) once the folder is prepared, until killed
PAUSED_SOLVE = textwrap.dedent(
    """
    import sys, time
    from mpi4py import MPI
    import shellobstacle.api as pipeline
    from shellobstacle.cli.main import main

    def paused(*args, **kwargs):
        MPI.COMM_WORLD.barrier()
        if MPI.COMM_WORLD.rank == 0:
            print("solving", flush=True)
        time.sleep(600)

    pipeline.solve = paused
    sys.exit(main(sys.argv[1:]))
    """
)


def start_paused(out: Path, ranks: int = 1) -> subprocess.Popen:
    """A solve into ``out`` that holds it (``ranks`` MPI ranks); returns once it solves."""
    command = [sys.executable, "-c", PAUSED_SOLVE, "solve", SMALL, *QUICK, "-o", str(out)]
    if ranks > 1:
        command = [mpiexec(), "-n", str(ranks), *command]
    proc = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    line = proc.stdout.readline()
    if line.strip() != "solving":
        proc.kill()
        pytest.fail(f"the first run did not start: {line}{proc.stderr.read()}")
    return proc


def kill(proc: subprocess.Popen, pid: int | None = None) -> None:
    """``kill -9`` the process (or, under mpiexec, its rank ``pid``) and wait for its end."""
    os.kill(pid or proc.pid, signal.SIGKILL)
    try:
        proc.wait(timeout=60)  # (mpiexec ends the other rank and itself)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def first_pid(proc: subprocess.Popen) -> int:
    """The pid of the first run's rank 0 as its lock file records it."""
    out = Path(proc.args[-1])
    return int(out.with_name(f".{out.name}.lock").read_text().split()[1])


def test_every_command_into_a_folder_in_use_is_refused_until_its_run_is_killed(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "out"
    first = start_paused(out)
    try:
        before = sorted(p.name for p in out.iterdir())
        log = (out / "log.txt").read_text()
        owner = (f"pid {first.pid} on {socket.gethostname()}", "solve", str(out))
        for command in (
            ["solve", SMALL, *QUICK],
            ["solve", SMALL, *QUICK, "--overwrite"],
            ["experiment", "penalty", SMALL, *QUICK],
            ["experiment", "penalty", SMALL, *QUICK, "--overwrite"],
            ["experiment", "penalty", SMALL, *QUICK, "--resume"],
            ["reproduce", "-q"],
            ["reproduce", "-q", "--resume"],
        ):
            code, _, err = run(capsys, *command, "-o", str(out))
            assert_user_error(code, err, f"output folder '{out}' is in use by another run", *owner)
        assert sorted(p.name for p in out.iterdir()) == before
        assert (out / "log.txt").read_text() == log
        assert not (tmp_path / ".out.partial").exists()
        # the executable itself: exit status 2, one line
        cli = [sys.executable, "-m", "shellobstacle", "solve", SMALL, *QUICK, "--overwrite"]
        second = subprocess.run([*cli, "-o", str(out)], capture_output=True, text=True)
        assert_user_error(second.returncode, second.stderr, "in use by another run", *owner)
    finally:
        kill(first)
    assert (tmp_path / ".out.lock").exists()  # left by the killed run, and blocks nothing
    code, _, err = run(capsys, "solve", SMALL, *QUICK, "-o", str(out))
    assert code == 0, err
    assert (out / "summary.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # the lock is gone


@pytest.mark.skipif(mpiexec() is None, reason="no mpiexec")
def test_a_run_on_two_ranks_holds_its_folder_and_is_refused_on_two_ranks(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Rank 0 takes the lock; the refusal is broadcast (every rank exits 2, one line)."""
    out = tmp_path / "out"
    first = start_paused(out, ranks=2)
    pid = first_pid(first)
    try:
        assert pid != first.pid
        code, _, err = run(capsys, "solve", SMALL, *QUICK, "-o", str(out), "--overwrite")
        assert_user_error(code, err, f"pid {pid} on {socket.gethostname()}", "solve")
        cli = [sys.executable, "-m", "shellobstacle", "solve", SMALL, *QUICK, "-o", str(out)]
        second = subprocess.run(
            [mpiexec(), "-n", "2", *cli], capture_output=True, text=True, timeout=300
        )
        assert_user_error(second.returncode, second.stderr, f"pid {pid}", "in use")
    finally:
        kill(first, pid)
    code, _, err = run(capsys, "solve", SMALL, *QUICK, "-o", str(out))
    assert code == 0, err
