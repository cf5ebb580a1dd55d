"""What a command is doing now, on a live status line of the terminal.

Library code marks its long phases (meshing, compiling the forms, each κ of a continuation,
each step of a sweep) with :func:`phase`, and notes finer progress inside them (a Newton step)
with :func:`note`. While a :class:`LiveStatus` runs (the command line starts one on rank 0
when stderr is a terminal, see :func:`on_terminal`), the line below the log shows the nested
phases with their elapsed times, refreshed four times a second::

    ⠹ 38 s  batch 3 (3/5): the load sweep (9 s) › batch 3: ell = 40 (4/5) (2 s) › κ 1/1 =
    1.10e-02 (2 s): Newton step 2, relative residual 3.1e-05

(one line on the terminal, cut at its width).

Anywhere else (a log file, a pipe, CI, pytest, ``-q``, ranks other than 0) nothing is shown,
and a phase costs a list append and a clock reading, no communication of its own (the
command line's Ctrl-C handling may add a meeting point, :func:`set_meeting_point`): library
calls and scripts print nothing of it. The lines above the status are the records of the
``shellobstacle`` logger, printed by the command line (:mod:`shellobstacle.cli.reporter`).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

__all__ = ["LiveStatus", "Phase", "note", "on_terminal", "phase", "set_meeting_point"]


@dataclass
class Phase:
    """A running phase: its text, when it started, and the latest note inside it."""

    text: str
    start: float
    detail: str = ""


_stack: list[Phase] = []
_live: LiveStatus | None = None


def _nowhere() -> None:
    """No meeting point (serial runs, library use)."""


_meet: Callable[[], None] = _nowhere


def set_meeting_point(meet: Callable[[], None] | None) -> None:
    """Call ``meet`` at every phase's start and end and at every note: the points all ranks
    reach together (the command line's Ctrl-C under MPI,
    :func:`shellobstacle.cli.interrupt.agree`); None: nothing."""
    global _meet
    _meet = meet or _nowhere


@contextmanager
def phase(text: str) -> Iterator[Phase]:
    """Mark a long phase (nested in the running ones) while the ``with`` block runs.

    Every rank runs the same phases: under MPI, the ranks stop at their starts and ends
    together after Ctrl-C (:func:`shellobstacle.cli.interrupt.agree`).
    """
    _meet()
    current = Phase(text, time.perf_counter())
    _stack.append(current)
    live = _live
    if live is not None:
        live.refresh()
    try:
        yield current
    finally:
        if current in _stack:
            _stack.remove(current)
    _meet()  # (not after an exception: that one goes on)


def note(text: str) -> None:
    """Show ``text`` after the innermost phase (e.g. ``"Newton step 3"``); no phase, no note.

    Every rank notes the same steps (of Newton's or Brezis–Sibony's iteration): under MPI, the
    ranks stop there together after Ctrl-C, as at a phase's start and end.
    """
    if _stack:
        _stack[-1].detail = text
    _meet()


def on_terminal(quiet: bool = False) -> bool:
    """Whether a live status line belongs on this process's stderr: rank 0, not ``quiet``, a
    terminal that can move its cursor (not ``TERM=dumb``), and not a CI job (``CI`` set)."""
    if quiet or os.environ.get("CI") or os.environ.get("TERM") == "dumb":
        return False
    try:
        if not sys.stderr.isatty():
            return False
    except (AttributeError, ValueError):  # replaced or closed stderr
        return False
    from mpi4py import MPI

    return MPI.COMM_WORLD.rank == 0


class LiveStatus:
    """The live status line on stderr (rich): the running phases, else the last message.

    Lines printed with :meth:`print` appear above it. :meth:`stop` removes the line (it is
    not part of the output); use it as a context manager or call :meth:`start` and
    :meth:`stop`. One runs at a time: :func:`phase` refreshes the running one.
    """

    def __init__(self) -> None:
        from rich.console import Console
        from rich.live import Live
        from rich.spinner import Spinner

        self.console = Console(stderr=True)
        self.message = "starting"
        self.t0 = time.perf_counter()
        self._spinner = Spinner("dots")
        self._live = Live(
            console=self.console,
            get_renderable=self._render,
            refresh_per_second=4,
            transient=True,  # (what other code prints to stdout or stderr goes above it)
        )

    def _render(self) -> Any:
        from rich.text import Text

        now = time.perf_counter()
        parts = [
            f"{p.text} ({now - p.start:.0f} s)" + (f": {p.detail}" if p.detail else "")
            for p in list(_stack)
        ]
        text = Text(f"{now - self.t0:.0f} s  ", style="bold")
        text.append(" › ".join(parts) if parts else self.message)
        text.no_wrap, text.overflow = True, "ellipsis"
        self._spinner.update(text=text)
        return self._spinner

    def start(self) -> LiveStatus:
        """Show the line (and make :func:`phase` refresh it)."""
        global _live
        self._live.start()
        _live = self
        return self

    def stop(self) -> None:
        """Remove the line."""
        global _live
        if _live is self:
            _live = None
        self._live.stop()

    def refresh(self) -> None:
        """Draw the line now (a phase has started)."""
        self._live.refresh()

    def print(self, line: str, message: str | None = None) -> None:
        """Print ``line`` above the status line, as it is (no markup, no highlighting); the
        status shows ``message`` while no phase runs."""
        if message is not None:
            self.message = message
        self.console.print(line, highlight=False, markup=False, soft_wrap=True)
        self.refresh()

    def __enter__(self) -> LiveStatus:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
