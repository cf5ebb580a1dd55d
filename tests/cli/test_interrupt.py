"""Ctrl-C inside a long call into C (shellobstacle.cli.interrupt): the watcher stops the process
when Python cannot run its handler, and leaves it alone when Python handled the interrupt.

The long call is gmsh meshing a disk finely (minutes, in C, gmsh's own SIGINT handling off as
in :mod:`shellobstacle.mesh.meshing`). The timeouts only bound a failing test.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from mpi4py import MPI

import pytest
from cli_helpers import mpiexec

from shellobstacle.io.folders import has_step_records

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="runs its own processes")
SMALL = Path(__file__).parents[2] / "examples" / "small.toml"

PRELUDE = textwrap.dedent(
    """
    import sys, time
    from shellobstacle.cli import interrupt
    assert interrupt.install(grace=1.0)
    print("ready", flush=True)
    """
)

LONG_C_CALL = textwrap.dedent(
    """
    import gmsh
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", 0.0003)
    gmsh.model.occ.addDisk(0, 0, 0, 1, 1)
    gmsh.model.occ.synchronize()
    gmsh.model.mesh.generate(2)
    print("meshed", flush=True)
    """
)

HANDLED = textwrap.dedent(
    """
    try:
        for _ in range(600):  # Python work with the library's meeting points between its steps
            time.sleep(0.1)
            interrupt.agree()
    except KeyboardInterrupt:
        interrupt.acknowledge()
        time.sleep(3)  # longer than the grace: cleaning up is allowed
        print("cleaned up", flush=True)
        sys.exit(130)
    """
)


def _interrupt(code: str) -> subprocess.CompletedProcess:
    """Run ``code`` after the prelude, send SIGINT once it is ready, return the result."""
    proc = subprocess.Popen(
        [sys.executable, "-c", PRELUDE + code],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert proc.stdout.readline().strip() == "ready"
    import time

    time.sleep(1.0)  # inside the long call
    proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the process was not stopped")
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def test_a_long_call_into_c_is_stopped() -> None:
    """Exit status 130 from the watcher's signal (no SIGTERM, which PETSc would catch)."""
    result = _interrupt(LONG_C_CALL)
    assert result.returncode == 130, result
    assert "meshed" not in result.stdout
    assert result.stderr.splitlines() == [
        "shellobstacle: interrupted (still inside a library call 1 s after Ctrl-C); stopping it"
    ]


#: Python code between the library's meeting points, as a callback that C++ (nanobind) calls
BETWEEN_MEETING_POINTS = textwrap.dedent(
    """
    try:
        time.sleep(60)
    except KeyboardInterrupt:
        print("raised between meeting points", flush=True)
    """
)


def test_ctrl_c_is_not_raised_between_meeting_points() -> None:
    """A ``KeyboardInterrupt`` raised at any bytecode could land in a Python function that C++
    called, which then aborts the process (``std::terminate``): Ctrl-C waits for the next
    meeting point, or the watcher stops the process after the grace."""
    result = _interrupt(BETWEEN_MEETING_POINTS)
    assert result.returncode == 130, result
    assert "raised" not in result.stdout
    assert result.stderr.splitlines() == [
        "shellobstacle: interrupted (still inside a library call 1 s after Ctrl-C); stopping it"
    ]


def test_a_handled_interrupt_is_left_alone() -> None:
    result = _interrupt(HANDLED)
    assert result.returncode == 130, result
    assert "cleaned up" in result.stdout
    assert "stopping it" not in result.stderr


def test_the_library_installs_nothing() -> None:
    """Importing shellobstacle and running cli.main leave SIGINT's wakeup fd unset."""
    code = (
        "import signal, shellobstacle\n"
        "from shellobstacle.cli.main import main\n"
        "main(['config-reference'])\n"
        "assert signal.set_wakeup_fd(-1) == -1\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=120)


@pytest.mark.skipif(mpiexec() is None, reason="no mpiexec")
def test_ctrl_c_under_mpiexec_stops_every_rank_cleanly(tmp_path: Path) -> None:
    """SIGINT to mpiexec (which passes it on to every rank, as Ctrl-C in a terminal) during a
    sweep: exit 130, one line, no rank killed; --resume then completes the sweep."""
    out = tmp_path / "b1"
    command = [mpiexec(), "-n", "2", sys.executable, "-m", "shellobstacle", "experiment"]
    command += ["penalty", str(SMALL), "-q", "--set", "domain.h=0.015", "-o", str(out)]
    command += ["--set", "output.pictures=false"]  # the stop and the resume are under test
    proc = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        while not has_step_records(out):  # a step is finished: the sweep is under way
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, stderr
    assert "PETSC ERROR" not in stdout + stderr and "BAD TERMINATION" not in stdout
    assert stderr.splitlines() == [
        f"shellobstacle: interrupted; the finished steps are recorded in {out}/steps/: continue "
        f"with the same command and --resume -o {out}"
    ]
    resumed = subprocess.run([*command, "--resume"], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "Resumed: " in (out / "report.md").read_text()


def _wait_until_mapped(proc: subprocess.Popen, library: str, timeout: float = 60.0) -> None:
    """Wait until ``proc`` has loaded ``library`` (a name in /proc/<pid>/maps)."""
    maps = Path(f"/proc/{proc.pid}/maps")
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        assert proc.poll() is None, "the command ended before loading " + library
        try:
            if library in maps.read_text():
                return
        except OSError:
            pass
        time.sleep(0.005)
    raise AssertionError(f"{library} not loaded in {timeout} s")


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="runs its own processes")
@pytest.mark.parametrize("library", ["_multiarray_umath", "libpetsc"])
def test_ctrl_c_while_the_command_starts_is_one_line(tmp_path: Path, library: str) -> None:
    """SIGINT as soon as ``library`` is loaded, while the modules load (before the command
    line handles Ctrl-C itself): one line and no traceback. The exit status is 130, or death
    by SIGINT (which a shell reports as 130) when the signal lands in MPI's own start-up.

    The moment is an event, not a delay: a fixed delay lands in the interpreter's own start-up
    (its site module) on a loaded machine, where no Python code can handle a signal."""
    command = [sys.executable, "-m", "shellobstacle", "solve", str(SMALL), "-q"]
    command += ["-o", str(tmp_path / "run"), "--set", "domain.h=0.05"]
    proc = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    _wait_until_mapped(proc, library)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode in (130, -signal.SIGINT), err
    assert "Traceback" not in err and len(err.strip().splitlines()) <= 1, err


#: the command line, announcing each MUMPS factorization of the Jacobian on stdout and its end,
#: with a watcher of half a second (a factorization at h = 0.003 takes seconds)
FACTORIZING = textwrap.dedent(
    """
    import os, sys
    from mpi4py import MPI
    from shellobstacle.cli import interrupt
    from shellobstacle.solvers.linear.direct import DirectStrategy

    factorize = DirectStrategy._factorize

    def announced(self):
        os.write(1, b"factorizing\\n")
        factorize(self)
        os.write(1, b"factorized\\n")

    DirectStrategy._factorize = announced
    if sys.argv.pop(1) == "watcher":
        assert interrupt.install(grace=0.5, comm=MPI.COMM_WORLD)
    else:  # Python's own handling at the library's meeting points, without the watcher
        import signal
        from shellobstacle.progress import set_meeting_point

        signal.signal(signal.SIGINT, interrupt._mark)
        interrupt._comm = MPI.COMM_WORLD if MPI.COMM_WORLD.size > 1 else None
        interrupt._deferred = True
        set_meeting_point(interrupt.agree)
    from shellobstacle.__main__ import main
    sys.exit(main())
    """
)


def _interrupt_a_factorization(out: Path, ranks: int, watcher: str) -> tuple[int, str, str]:
    """SIGINT (to ``mpiexec`` on 2 ranks) while MUMPS factorizes a Jacobian."""
    command = [sys.executable, "-c", FACTORIZING, watcher, "solve", str(SMALL), "-q"]
    command += ["-o", str(out), "--set", "domain.h=0.003", "--set", "solver.linear_solver=direct"]
    command += ["--set", "solver.contact_zone=false", "--set", "output.pictures=false"]
    if ranks > 1:
        command = [mpiexec(), "-n", str(ranks), *command]
    proc = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        assert proc.stdout.readline() == "factorizing\n", proc.communicate()
        time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, stdout, stderr


@pytest.mark.parametrize("ranks", [1, 2])
def test_ctrl_c_during_a_factorization_is_one_line_and_exit_130(tmp_path: Path, ranks: int) -> None:
    """SIGINT (to ``mpiexec`` on 2 ranks) while MUMPS factorizes, a call into C longer than the
    grace: the watcher stops every rank inside the factorization with exit status 130 and one
    line, without PETSc's error dump for a SIGTERM or ``mpiexec``'s "bad termination"; a new
    run into the folder is not blocked by the stopped one."""
    if ranks > 1 and mpiexec() is None:
        pytest.skip("no mpiexec")
    out = tmp_path / "run"
    returncode, stdout, stderr = _interrupt_a_factorization(out, ranks, "watcher")
    assert returncode == 130, stderr
    assert "factorized" not in stdout  # stopped inside MUMPS
    assert "PETSC ERROR" not in stdout + stderr and "BAD TERMINATION" not in stdout
    assert stderr.splitlines() == [
        "shellobstacle: interrupted (still inside a library call 0.5 s after Ctrl-C); stopping it"
    ]
    again = [sys.executable, "-m", "shellobstacle", "solve", str(SMALL), "-q", "-o", str(out)]
    again += ["--set", "domain.h=0.1", "--set", "output.pictures=false"]
    rerun = subprocess.run(again, capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr


def test_without_the_watcher_a_factorization_runs_to_its_end(tmp_path: Path) -> None:
    """Why the watcher exists: Python's own handling (``KeyboardInterrupt`` at the library's
    meeting points) stops the same run only after MUMPS has returned (docs/perf/interrupt.md:
    at h = 0.0016 half a minute and more against the watcher's 2.5 s)."""
    returncode, stdout, stderr = _interrupt_a_factorization(tmp_path / "run", 1, "none")
    assert returncode == 130, stderr
    assert "factorized" in stdout
    assert stderr.splitlines() == ["shellobstacle: interrupted"]


#: the command line, announcing on stdout when the cross-section is drawn, which is then
#: slowed down so that Ctrl-C lands while the outputs are written
DRAWING = textwrap.dedent(
    """
    import os, sys, time
    from mpi4py import MPI
    from shellobstacle.cli import interrupt
    from shellobstacle.post import plotting

    plot = plotting.plot_cross_section

    def announced(*args, **kwargs):
        os.write(1, b"drawing\\n")
        time.sleep(1.0)
        return plot(*args, **kwargs)

    plotting.plot_cross_section = announced
    assert interrupt.install(grace=30.0, comm=MPI.COMM_WORLD)
    from shellobstacle.__main__ import main
    sys.exit(main())
    """
)


def test_ctrl_c_while_the_figures_are_drawn_keeps_the_summary(tmp_path: Path) -> None:
    """SIGINT while a solve draws its figures: exit 130, and the folder holds the solution's
    summary.json, which says that its outputs were interrupted and lists those written
    (the ParaView files, the cross-section), so that nothing in the folder is unaccounted for."""
    import json

    out = tmp_path / "run"
    command = [sys.executable, "-c", DRAWING, "solve", str(SMALL), "-q", "-o", str(out)]
    command += ["--set", "domain.h=0.1"]
    proc = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        assert proc.stdout.readline() == "drawing\n", proc.communicate()
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, stderr
    assert stderr.splitlines() == [
        f"shellobstacle: interrupted while writing the outputs; {out}/summary.json records the "
        "solution and the files written (outputs_complete: false)"
    ]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outputs_complete"] is False
    assert summary["interrupted"].startswith("while writing the outputs")
    written = sorted(p.name for p in out.iterdir())
    assert "cross_section.png" in written and "shell_3d.png" not in written
    assert sorted(summary["files"]) == [n for n in written if n.endswith((".bp", ".png"))]
    assert (out / "log.txt").read_text().splitlines()[-1].endswith("interrupted")
