"""Progress of a command: lines on rank 0's stderr and in a log file, and on a terminal the
live status line of :mod:`shellobstacle.progress` below them."""

from __future__ import annotations

import sys
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mpi4py import MPI

from shellobstacle.cli.output import emit
from shellobstacle.progress import LiveStatus, on_terminal

__all__ = ["NewtonEcho", "Reporter"]


class Reporter:
    """Progress lines on rank 0 (stderr), also appended to a log file once one is known.

    ``quiet`` prints nothing (the log file still gets every line); ``verbose`` adds a line per
    Newton iteration (:meth:`newton`, passed as ``newton_progress`` to the solvers).
    """

    def __init__(self, quiet: bool = False, verbose: bool = False) -> None:
        self.quiet = quiet
        self.verbose = verbose
        self.start = time.perf_counter()
        self.log: Path | None = None
        self.lines: list[str] = []
        self._status: Any = None
        if on_terminal(quiet):
            # on a terminal: a live status line (the running phases and their times) below
            # the log lines; in files, pipes and CI only the plain lines are written
            self._status = LiveStatus().start()

    def close(self) -> None:
        """Remove the live status line (the command has ended); idempotent."""
        if self._status is not None:
            self._status.stop()
            self._status = None

    def __del__(self) -> None:
        self.close()

    def __call__(self, msg: str) -> None:
        line = f"[{time.perf_counter() - self.start:7.1f}s] {msg}"
        self.lines.append(line)
        if MPI.COMM_WORLD.rank != 0:
            return
        if self._status is not None:
            self._status.print(line, msg)
        elif not self.quiet:
            emit(line, sys.stderr)  # (a closed stderr is silenced: the run goes on)
        if self.log is not None:
            with self.log.open("a") as f:
                f.write(line + "\n")

    @contextmanager
    def reporting_warnings(self) -> Iterator[list[str]]:
        """Report every warning raised in the block as a line ``warning: ...`` (stderr and the
        log file) when it is raised, once per text, and collect the texts in the list yielded
        (for ``summary.json``'s ``warnings``): e.g. a PETSc option that no solver read."""
        seen: list[str] = []

        def show(message: Any, *_args: Any, **_kwargs: Any) -> None:
            text = str(message)
            if text not in seen:
                seen.append(text)
                self(f"warning: {text}")

        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.showwarning = show
            yield seen

    def record(self, text: str) -> None:
        """Append ``text`` (how the run ended: an error, a traceback) to the log file only.

        The terminal gets it from :func:`shellobstacle.cli.main`; nothing happens before the
        log file is known.
        """
        if self.log is None or MPI.COMM_WORLD.rank != 0:
            return
        try:
            with self.log.open("a") as f:
                f.write(f"[{time.perf_counter() - self.start:7.1f}s] {text.rstrip()}\n")
        except OSError:  # the folder is gone: the terminal still has the message
            pass

    def attach(self, path: Path, append: bool = False) -> None:
        """Start logging to ``path`` (the lines so far are written first).

        With ``append`` (a resumed run) the earlier log is kept and continued.
        """
        self.log = path
        if MPI.COMM_WORLD.rank == 0:
            text = "".join(line + "\n" for line in self.lines)
            if append and path.exists():
                with path.open("a") as f:
                    f.write("--- resumed ---\n" + text)
            else:
                path.write_text(text)

    @property
    def newton(self) -> NewtonEcho | None:
        """The per-iteration callback in verbose mode, else None."""
        return NewtonEcho(self) if self.verbose else None


class NewtonEcho:
    """``newton_progress`` of the verbose mode: one line per Newton iteration."""

    def __init__(self, say: Reporter) -> None:
        self.say = say

    def __call__(self, it: int, relres: float) -> None:
        self.say(f"    Newton {it}: relative residual {relres:.3e}")

    def finished(self, result: Any) -> None:
        """After a solve: its step lengths (the exact line search's t) and stop reason."""
        steps = ", ".join(f"{t:.3g}" for t in result.step_lengths) or "none"
        self.say(f"    Newton: {result.iterations} steps, step lengths {steps}; {result.reason}")
