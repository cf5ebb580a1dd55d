"""Ctrl-C honoured within :data:`GRACE` seconds, also inside a long call into C.

Python runs its SIGINT handler only between bytecodes: during a gmsh meshing, a mesh
refinement, an assembly or a MUMPS factorization of seconds to minutes, a ``KeyboardInterrupt``
waits for the call to return, and no Python thread runs meanwhile (petsc4py holds the GIL;
docs/perf/interrupt.md). The command line therefore starts a small watcher process next to
each MPI rank. Python's C-level signal handler writes every signal it catches to a pipe
(:func:`signal.set_wakeup_fd`: no Python code, no GIL); the watcher reads it. When the process
has not handled the interrupt (:func:`acknowledge`) within :data:`GRACE` seconds, or at a
second Ctrl-C, the watcher says so on stderr (one line, from rank 0) and sends :data:`STOP`,
which ends the process at once with status 130 (:mod:`shellobstacle.compat.exit_in_c`: no
PETSc error dump, no "bad termination" of ``mpiexec``). Where that handler cannot be installed,
or the process does not end, the watcher goes on with SIGTERM, then SIGKILL; the process has
ended when its end of the pipe closes.

Ctrl-C only marks the interrupt, and ``KeyboardInterrupt`` is raised at the next point of
:func:`agree` (the start and end of every phase and each Newton or Brezis–Sibony step,
:mod:`shellobstacle.progress`). Under MPI (``mpiexec`` passes Ctrl-C on to every rank) the
ranks raise it there together: a rank that stopped while another waits for it inside a
collective call leaves that one stuck until the watcher kills it. On one rank too: raised at
any bytecode, it can land in a Python function that C++ called (nanobind), which then ends the
process with ``std::terminate``.

Result folders stay consistent after such a stop: every file is written atomically, a staged
``--overwrite`` leaves the old folder untouched, and ``--resume`` continues from the recorded
steps; an interrupted FFCx compilation removes its own unfinished source
(:func:`shellobstacle.cli.jit_cache.guarded_compilations`). Only the command line installs the
watcher (:mod:`shellobstacle.__main__`); the library and :func:`shellobstacle.cli.main` leave
the process's signals alone.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

from shellobstacle.compat.exit_in_c import exit_on

__all__ = ["GRACE", "STOP", "acknowledge", "agree", "immediate", "install"]

#: Seconds a long call into C may keep running after Ctrl-C.
GRACE = 2.0
#: The signal with which the watcher stops a process still inside a call into C: it exits
#: with status 130 at once (:func:`shellobstacle.compat.exit_in_c.exit_on`); PETSc and MPI
#: leave it alone.
STOP = signal.SIGUSR2
#: the exit status of an interrupted run (128 + SIGINT, as a shell reports death by Ctrl-C)
INTERRUPTED = 130
_ack_fd: int | None = None
#: the communicator whose ranks stop together (None: one process), and whether Ctrl-C came
_comm: Any = None
_pending = False
#: whether Ctrl-C is deferred to :func:`agree` (after :func:`install`)
_deferred = False
#: the depth of :func:`immediate` blocks (Ctrl-C raised at once inside them)
_immediate = 0

# The watcher: argv = parent pid, grace, the acknowledgement's fd, the signal that makes the
# parent exit at once (0: none), whether to print (rank 0); fd 0 = the signals.
_WATCHER = r"""
import os, select, signal, sys, time
parent, grace, ack = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
first, loud = int(sys.argv[4]), sys.argv[5] == "1"
signals = 0
def ended(timeout):  # the process has closed its end of the signals' pipe: it has ended
    end = time.monotonic() + timeout
    while select.select([signals], [], [], max(end - time.monotonic(), 0.0))[0]:
        if not os.read(signals, 64):
            return True
    return False
def stop(why):
    if loud:
        try:
            os.write(2, ("shellobstacle: interrupted (" + why + "); stopping it\n").encode())
        except OSError:
            pass  # stderr's reader has gone (a pipe): the stop matters, not the line
    for sig in [first] * (first > 0) + [signal.SIGTERM, signal.SIGKILL]:
        try:
            os.kill(parent, sig)
        except ProcessLookupError:
            return
        if ended(1.0):
            return
deadline = None
while True:
    timeout = None if deadline is None else max(deadline - time.monotonic(), 0.0)
    ready, _, _ = select.select([signals, ack], [], [], timeout)
    if not ready:
        stop("still inside a library call %g s after Ctrl-C" % grace)
        break
    if signals in ready:  # before the acknowledgement that may have followed at once
        data = os.read(signals, 64)
        if not data:
            break  # the process has ended
        if signal.SIGINT in data:
            if deadline is not None:
                stop("a second Ctrl-C")
                break
            deadline = time.monotonic() + grace
    if ack in ready:
        if not os.read(ack, 64):
            break  # the process has ended
        deadline = None  # it handled the interrupt
"""


def install(grace: float = GRACE, comm: Any = None) -> bool:
    """Start the watcher of this process; False (and nothing changed) where it cannot run
    (not the main thread, no SIGINT handler of Python's, no ``fork``). Ctrl-C then takes effect
    at the next :func:`agree`, on all ranks of ``comm`` together."""
    global _ack_fd, _comm, _deferred
    if _ack_fd is not None:
        return True
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return False  # SIGINT ignored (a background job) or handled by someone else
    sig_r, sig_w = os.pipe()
    ack_r, ack_w = os.pipe()
    os.set_blocking(sig_w, False)
    first = int(STOP) if exit_on(STOP, INTERRUPTED) else 0
    loud = "1" if comm is None or comm.rank == 0 else "0"
    argv = [str(os.getpid()), str(grace), str(ack_r), str(first), loud]
    try:
        subprocess.Popen(
            [sys.executable, "-S", "-c", _WATCHER, *argv],
            stdin=sig_r,
            stdout=subprocess.DEVNULL,
            pass_fds=(ack_r,),
            close_fds=True,
            start_new_session=True,  # a terminal's Ctrl-C reaches the process, not the watcher
        )
    except OSError:
        for fd in (sig_r, sig_w, ack_r, ack_w):
            os.close(fd)
        return False
    os.close(sig_r)
    os.close(ack_r)
    from shellobstacle.progress import set_meeting_point

    signal.signal(signal.SIGINT, _mark)
    _comm = comm if comm is not None and comm.size > 1 else None
    _deferred = True
    set_meeting_point(agree)  # every phase and step of the library is such a point
    signal.set_wakeup_fd(sig_w, warn_on_full_buffer=False)
    _ack_fd = ack_w
    return True


def _mark(signum: int, frame: Any) -> None:
    """Ctrl-C: remembered until the next :func:`agree` (the watcher still times it), or
    raised at once inside :func:`immediate`."""
    global _pending
    if _immediate:
        raise KeyboardInterrupt
    _pending = True


@contextlib.contextmanager
def immediate() -> Iterator[None]:
    """Ctrl-C raises ``KeyboardInterrupt`` at once inside the block, on one process (Python
    code and subprocesses that no C++ calls back into: FFCx's compilation and its wait for
    another process's, which clean up after themselves); under MPI it stays deferred."""
    global _immediate, _pending
    if not _deferred or _comm is not None:
        yield
        return
    _immediate += 1
    try:
        if _pending:
            _pending = False
            raise KeyboardInterrupt
        yield
    finally:
        _immediate -= 1


def agree() -> None:
    """A point that every rank reaches together: if Ctrl-C reached any of them, raise
    ``KeyboardInterrupt`` on all. Nothing before :func:`install`."""
    global _pending
    if not _deferred:
        return
    pending = _pending
    if _comm is not None:
        from mpi4py import MPI

        pending = _comm.allreduce(_pending, op=MPI.LOR)
    if pending:
        _pending = False
        raise KeyboardInterrupt


def acknowledge() -> None:
    """Tell the watcher that the interrupt reached Python (no forced stop)."""
    if _ack_fd is not None:
        with contextlib.suppress(OSError):
            os.write(_ack_fd, b"a")
