"""The command line: solve, check, reproduce, experiment, doctor, config-reference.

:func:`main` parses (:mod:`shellobstacle.cli.parser`), dispatches to
:mod:`shellobstacle.cli.commands` and turns what went wrong into one line and an exit code; it
changes nothing in the process (the ``shellobstacle`` executable may tune it first:
:mod:`shellobstacle.__main__`).
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from collections.abc import Sequence

from mpi4py import MPI

from shellobstacle.cli import commands
from shellobstacle.cli.commands import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_INVALID,
    EXIT_OK,
    EXIT_USAGE,
)
from shellobstacle.cli.output import EXIT_CLOSED_PIPE, emit
from shellobstacle.cli.parser import parser

__all__ = [
    "EXIT_CLOSED_PIPE",
    "EXIT_FAILED",
    "EXIT_INTERRUPTED",
    "EXIT_INVALID",
    "EXIT_OK",
    "EXIT_USAGE",
    "main",
]


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 solver failure, 2 user error, 3 a solution
    outside the model's validity, 130 interrupted, 141 stdout's reader has gone: see
    :mod:`shellobstacle.cli.output`, which also makes SIGPIPE ignored again, Python's default
    that PETSc and gmsh change)."""
    try:
        return _main(argv)
    except BrokenPipeError:  # (stdout is silenced: nothing more can be said)
        return EXIT_CLOSED_PIPE


def _main(argv: Sequence[str] | None) -> int:
    args = parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    args.folder = None  # the ResultFolder, once known (for the messages below)
    args.report = None  # the Reporter, whose log.txt also gets how the run ended
    from shellobstacle.checks.assumptions import AssumptionError
    from shellobstacle.cli.jit_cache import guarded_compilations
    from shellobstacle.config.loader import ConfigError
    from shellobstacle.geometry.expressions import ExpressionError
    from shellobstacle.io.folders import ResultsError
    from shellobstacle.solvers.base import ConvergenceError

    try:
        try:
            with guarded_compilations():  # an interrupted compilation leaves the cache sound
                return _dispatch(args)
        finally:  # the live status line goes before the last messages are printed
            if args.report is not None:
                args.report.close()
    except (ConfigError, ExpressionError, AssumptionError, ResultsError) as err:
        _record(args, f"error: {_one_line(str(err))}")
        if MPI.COMM_WORLD.rank == 0:
            emit(f"shellobstacle: error: {_one_line(f'{err}{_kept(args)}')}", sys.stderr)
        return EXIT_USAGE
    except ConvergenceError as err:
        _record(args, f"solver failure: {_one_line(str(err))}")
        if MPI.COMM_WORLD.rank == 0:
            emit(
                f"shellobstacle: solver failure: {_one_line(str(err))}: raise "
                "solver.max_iterations or loosen solver.rtol in a new run"
                f"{_steps_recorded(args) or _kept(args)}",
                sys.stderr,
            )
        return EXIT_FAILED
    except KeyboardInterrupt:
        from shellobstacle.cli import interrupt

        interrupt.acknowledge()
        _record(args, "interrupted")
        if MPI.COMM_WORLD.rank == 0:
            hint = _resume_hint(args) or _kept(args) or _summary_kept(args)
            emit(f"shellobstacle: interrupted{hint}", sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        raise  # stdout's reader has gone: not a bug
    except Exception:
        _record(args, f"internal error (a bug):\n{traceback.format_exc()}")
        if MPI.COMM_WORLD.rank == 0:
            emit(traceback.format_exc().rstrip("\n"), sys.stderr)
            emit(
                "shellobstacle: internal error (a bug): please report it with the traceback "
                f"above and your config file{_kept(args)}",
                sys.stderr,
            )
        return EXIT_FAILED
    finally:  # the result folder is free for the next run
        from shellobstacle.io.lock import release_folders

        release_folders()


def _dispatch(args: argparse.Namespace) -> int:
    """Run the command of ``args``; returns its exit code."""
    _require_text(args.argv)
    if args.command == "config-reference":
        from shellobstacle.config.schema import reference_text

        emit(reference_text())
        return EXIT_OK
    if args.command == "doctor":
        return commands.doctor(args)
    if args.command == "check":
        return commands.check(args)
    if args.command == "solve":
        return commands.solve(args)
    if args.command == "reproduce":
        return commands.reproduce(args)
    if args.command == "experiment":
        return commands.experiment(args)
    return EXIT_USAGE


def _one_line(text: str) -> str:
    """``text`` with its invisible characters escaped (the ``\\r`` of a script with CRLF line
    endings, tabs, newlines of an expression, line separators): a message the user can read
    and that stays on one line."""
    return "".join(
        c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text
    )


def _require_text(argv: Sequence[str]) -> None:
    """Refuse an argument that is not UTF-8 text (a byte such as 0xff in a file name arrives
    as a lone surrogate): the paths and values are written into UTF-8 logs, configs and
    reports, which cannot hold it."""
    from shellobstacle.config.loader import ConfigError

    for arg in argv:
        try:
            arg.encode("utf-8")
        except UnicodeEncodeError:
            try:  # the bytes as given (0xff shown as \xff)
                shown = os.fsencode(arg).decode("utf-8", "backslashreplace")
            except UnicodeError:
                shown = arg.encode("utf-8", "backslashreplace").decode("utf-8")
            raise ConfigError(
                f"the argument '{shown}' is not UTF-8 text: rename the file or folder, or "
                "give a UTF-8 value"
            ) from None


def _record(args: argparse.Namespace, text: str) -> None:
    """Write how the run ended into its log.txt (once the run has one)."""
    if args.report is not None:
        args.report.record(text)


def _logged(args: argparse.Namespace) -> bool:
    return args.folder is not None and args.report is not None and args.report.log is not None


def _kept(args: argparse.Namespace) -> str:
    """For a failed replacement (--overwrite): the old results are kept, the log is beside."""
    if not _logged(args) or not args.folder.staged:
        return ""
    return (
        f" ({args.folder.target}/ is unchanged; this run's log is {args.folder.path}/log.txt, "
        "removed by the next run)"
    )


def _steps_recorded(args: argparse.Namespace) -> str:
    """For an experiment or reproduce that stopped: where its finished steps are."""
    if args.folder is None or not hasattr(args, "resume"):
        return ""
    return f"; the finished steps are recorded in {args.folder.path}/steps/"


def _summary_kept(args: argparse.Namespace) -> str:
    """For a solve interrupted while it wrote its outputs: its summary.json is in place
    (:func:`shellobstacle.io.summary.write_solution`); rank 0."""
    if args.folder is None or not (args.folder.path / "summary.json").is_file():
        return ""
    return (
        f" while writing the outputs; {args.folder.target}/summary.json records the solution "
        "and the files written (outputs_complete: false)"
    )


def _resume_hint(args: argparse.Namespace) -> str:
    """For an interrupted experiment or reproduce: where its steps are and how to continue."""
    steps = _steps_recorded(args)
    if not steps:
        return ""
    folder = args.folder
    unchanged = f" ({folder.target}/ is unchanged until it finishes)" if folder.staged else ""
    return f"{steps}: continue with the same command and --resume -o {folder.target}{unchanged}"
