"""Ctrl-C during a long call into C: a MUMPS factorization of the paper's problem (the direct
path at ``--h``) or, with ``--compile``, an FFCx compilation into an empty throwaway cache.
SIGINT goes to the command's process group (what a terminal's Ctrl-C does; ``mpiexec`` passes
it on to the ranks) ``--delay`` seconds after the first factorization starts. One JSON line:
seconds from SIGINT to the end, exit status, stderr, whether the factorization returned first,
whether a Python thread ran during it, the folder and a later run into it (or the cache's
broken entries and a later compilation).

``--mode``: ``watcher`` the command line as shipped (``shellobstacle.cli.interrupt``);
``meeting-points`` its Python half only (``KeyboardInterrupt`` at the library's meeting
points, no watcher); ``python`` Python's default handling; ``watcher-sigterm`` the watcher
without the C-level exit of ``shellobstacle.compat.exit_in_c`` (SIGTERM, then SIGKILL).
``--petsc-no-signal-handler`` sets PETSc's ``-no_signal_handler`` (``PETSC_OPTIONS``).

    .venv/bin/python benchmarks/interrupt.py --mode watcher --ranks 2 --h 0.0016
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SMALL = str(ROOT / "examples" / "small.toml")


def child(mode: str, grace: float) -> int:
    """The command line (``sys.argv``) with each factorization announced on stdout."""
    from shellobstacle.compat import bootstrap

    bootstrap()
    from mpi4py import MPI

    from shellobstacle.cli import interrupt
    from shellobstacle.progress import set_meeting_point
    from shellobstacle.solvers.linear.direct import DirectStrategy

    factorize, rank0 = DirectStrategy._factorize, MPI.COMM_WORLD.rank == 0

    def announced(self):
        if rank0:
            os.write(1, b"factorizing %.3f\n" % time.time())
        factorize(self)
        if rank0:
            os.write(1, b"factorized %.3f\n" % time.time())

    def heartbeat():  # does a Python thread run while MUMPS factorizes?
        with open(os.environ["HEARTBEAT"], "a") as f:
            while True:
                f.write(f"{time.time():.3f}\n")
                f.flush()
                time.sleep(0.25)

    DirectStrategy._factorize = announced
    if rank0:
        threading.Thread(target=heartbeat, daemon=True).start()
    if mode == "watcher-sigterm":
        interrupt.exit_on = lambda signum, status: False
    if mode.startswith("watcher"):
        assert interrupt.install(grace=grace, comm=MPI.COMM_WORLD)
    elif mode == "meeting-points":
        signal.signal(signal.SIGINT, interrupt._mark)
        interrupt._comm = MPI.COMM_WORLD if MPI.COMM_WORLD.size > 1 else None
        interrupt._deferred = True
        set_meeting_point(interrupt.agree)
    from shellobstacle.cli.main import main

    return main()


def measure(args: argparse.Namespace, work: Path) -> dict:
    out, beat = work / "run", work / "heartbeat"
    env = dict(os.environ, HEARTBEAT=str(beat), XDG_CACHE_HOME=str(work / "cache"))
    if not args.compile:
        env.pop("XDG_CACHE_HOME")  # the usual cache, whose forms are compiled
    if args.petsc_no_signal_handler:
        env["PETSC_OPTIONS"] = "-no_signal_handler"
    solve = ["solve", SMALL, "-q", "-o", str(out), "--set", "output.pictures=false"]
    h = "0.05" if args.compile else str(args.h)
    solve += ["--set", f"domain.h={h}", "--set", "solver.linear_solver=direct"]
    solve += ["--set", "solver.contact_zone=false"]
    command = [sys.executable, __file__, "--child", args.mode, str(args.grace), *solve]
    if args.ranks > 1:
        command = [str(Path(sys.executable).parent / "mpiexec"), "-n", str(args.ranks), *command]
    proc = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    cache = work / "cache" / "fenics"
    if args.compile:
        while not list(cache.glob("*.c")):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.01)
    else:
        line = proc.stdout.readline()
        assert line.startswith("factorizing"), (line, proc.communicate())
    time.sleep(args.delay)
    signalled = time.time()
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=600)
    record = {
        "mode": args.mode,
        "ranks": args.ranks,
        "petsc_no_signal_handler": args.petsc_no_signal_handler,
        "seconds_to_exit": round(time.time() - signalled, 2),
        "returncode": proc.returncode,
        "stderr": stderr.strip().splitlines(),
    }
    if args.compile:
        from shellobstacle.cli.jit_cache import broken_entries

        record["broken_entries"] = [e.why for e in broken_entries(cache, now=math.inf)]
    else:
        beats = [float(b) for b in beat.read_text().split()] if beat.exists() else []
        started = float(line.split()[1])
        record["h"] = args.h
        record["factorization_returned"] = "factorized" in stdout
        record["python_thread_ran"] = any(started + 0.5 < b < signalled for b in beats)
        record["folder"] = sorted(p.name for p in out.iterdir()) if out.exists() else []
    again = [sys.executable, "-m", "shellobstacle", *solve[:7], "--set", "domain.h=0.05"]
    rerun = subprocess.run(again, capture_output=True, text=True, env=env)
    record["next_run"] = rerun.returncode
    return record


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        mode, grace = sys.argv[2], float(sys.argv[3])
        del sys.argv[1:4]
        sys.exit(child(mode, grace))
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mode", default="watcher")
    parser.add_argument("--ranks", type=int, default=1)
    parser.add_argument("--h", type=float, default=0.0016)
    parser.add_argument("--grace", type=float, default=2.0)
    parser.add_argument("--delay", type=float, default=1.0)
    parser.add_argument("--compile", action="store_true")
    parser.add_argument("--petsc-no-signal-handler", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as work:
        print(json.dumps(measure(args, Path(work))), flush=True)


if __name__ == "__main__":
    main()
