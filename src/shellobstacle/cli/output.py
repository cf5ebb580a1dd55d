"""What the command line prints, and a reader that has gone
(``shellobstacle config-reference | head -1``).

PETSc catches SIGPIPE (its handler prints an error and calls ``MPI_Abort``) and gmsh resets it
to the default (death by the signal). Before every write, :func:`emit` restores Python's own
disposition (ignored), under which a write into a closed pipe raises ``BrokenPipeError``
instead. A closed stdout ends the command quietly with :data:`EXIT_CLOSED_PIPE`
(:func:`shellobstacle.cli.main.main`); a closed stderr only silences the progress lines: the
run goes on, its ``log.txt`` gets every line, and under MPI no rank is left waiting for rank 0
in a collective call.
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import sys
import threading
from typing import TextIO

__all__ = ["EXIT_CLOSED_PIPE", "emit"]

#: the exit status after stdout's reader has gone: 128 + SIGPIPE, as a shell reports a command
#: that a closed pipe stopped
EXIT_CLOSED_PIPE = 128 + signal.SIGPIPE


def emit(text: str, stream: TextIO | None = None) -> None:
    """Print ``text`` and a newline to ``stream`` (stdout when None) at once.

    Raises:
        BrokenPipeError: stdout's reader has gone (stdout is then silenced: nothing more is
            written, also not when Python flushes it at exit). A closed stderr is silenced
            without an error.
    """
    stream = sys.stdout if stream is None else stream
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    try:
        print(text, file=stream, flush=True)
    except BrokenPipeError:
        _silence(stream)
        if stream is not sys.stderr:
            raise


def _silence(stream: TextIO) -> None:
    """Point the file descriptor of ``stream`` at /dev/null."""
    with contextlib.suppress(OSError, ValueError, io.UnsupportedOperation):
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, stream.fileno())
        os.close(null)
