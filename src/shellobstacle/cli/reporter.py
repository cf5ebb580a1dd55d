"""What a command says: the records of the ``shellobstacle`` logger as lines on rank 0's stderr
and in the run's log file, and on a terminal the live status line of
:mod:`shellobstacle.progress` below them.

The library only logs (``logging.getLogger(__name__)`` in each module, a ``NullHandler`` on the
package's logger); the command line installs the one handler, :class:`Reporter`, for the time
of a command. Its levels: ``-q`` prints errors only, the default information too, ``-v`` also
the debug records (one per Newton step); the log file gets every record the logger passes.
"""

from __future__ import annotations

import logging
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

__all__ = ["PACKAGE", "Reporter"]

#: the logger of the package, whose records a command prints
PACKAGE = logging.getLogger("shellobstacle")
_log = logging.getLogger(__name__)


class Reporter(logging.Handler):
    """The command's handler of the ``shellobstacle`` logger: each record as a line
    ``[   1.2s] message`` (``warning: message`` for a warning) on stderr, rank 0 only, and in
    the log file once one is known (:meth:`attach`).

    ``quiet`` prints errors only (the log file still gets every line); ``verbose`` lets the
    debug records through (one line per Newton step). Calling the reporter logs ``msg`` as
    information. :meth:`close` removes the handler (and the live status line).
    """

    def __init__(self, quiet: bool = False, verbose: bool = False) -> None:
        super().__init__(logging.DEBUG)
        self.quiet = quiet
        self.start = time.perf_counter()
        self.log: Path | None = None
        self.lines: list[str] = []
        self.rank = MPI.COMM_WORLD.rank
        self._status: Any = None
        if on_terminal(quiet):
            # on a terminal: a live status line (the running phases and their times) below
            # the log lines; in files, pipes and CI only the plain lines are written
            self._status = LiveStatus().start()
        self._level = PACKAGE.level
        PACKAGE.setLevel(logging.DEBUG if verbose else logging.INFO)
        PACKAGE.addHandler(self)

    def close(self) -> None:
        """Stop handling the logger's records and remove the live status line (the command
        has ended); idempotent."""
        if self in PACKAGE.handlers:
            PACKAGE.removeHandler(self)
            PACKAGE.setLevel(self._level)
        if self._status is not None:
            self._status.stop()
            self._status = None
        super().close()

    def __call__(self, msg: str) -> None:
        _log.info(msg)

    def emit(self, record: logging.LogRecord) -> None:
        msg = record.getMessage()
        if record.levelno == logging.WARNING:
            msg = f"warning: {msg}"
        line = f"[{time.perf_counter() - self.start:7.1f}s] {msg}"
        self.lines.append(line)
        if self.rank != 0:
            return
        if self._status is not None:
            self._status.print(line, msg)
        elif not self.quiet or record.levelno >= logging.ERROR:
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
                _log.warning(text)

        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.showwarning = show
            yield seen

    def record(self, text: str) -> None:
        """Append ``text`` (how the run ended: an error, a traceback) to the log file only.

        The terminal gets it from :func:`shellobstacle.cli.main`; nothing happens before the
        log file is known.
        """
        if self.log is None or self.rank != 0:
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
        if self.rank == 0:
            text = "".join(line + "\n" for line in self.lines)
            if append and path.exists():
                with path.open("a") as f:
                    f.write("--- resumed ---\n" + text)
            else:
                path.write_text(text)
