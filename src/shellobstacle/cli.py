"""Command line: ``shellobstacle solve | check | reproduce | experiment | config-reference``."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import traceback
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mpi4py import MPI

import shellobstacle

__all__ = ["main"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


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
        if not quiet and MPI.COMM_WORLD.rank == 0 and sys.stderr.isatty():
            # on a terminal: a live status line (spinner, elapsed time, current step) below the
            # log lines; in files, pipes and CI only the plain lines are written
            from rich.console import Console

            self._console = Console(stderr=True)
            self._status = self._console.status("starting", spinner="dots")
            self._status.start()

    def __del__(self) -> None:
        if self._status is not None:
            self._status.stop()

    def __call__(self, msg: str) -> None:
        line = f"[{time.perf_counter() - self.start:7.1f}s] {msg}"
        self.lines.append(line)
        if MPI.COMM_WORLD.rank != 0:
            return
        if self._status is not None:
            self._console.print(line, highlight=False, markup=False)
            self._status.update(f"{time.perf_counter() - self.start:.0f} s — {msg}")
        elif not self.quiet:
            print(line, file=sys.stderr, flush=True)
        if self.log is not None:
            with self.log.open("a") as f:
                f.write(line + "\n")

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


def _parser() -> argparse.ArgumentParser:
    fmt = argparse.ArgumentDefaultsHelpFormatter
    p = argparse.ArgumentParser(
        prog="shellobstacle",
        description="Elliptic membrane shells pushed against a plane: penalty method, "
        "finite elements, Newton (Meixner & Piersanti 2024).",
        epilog="example: shellobstacle solve examples/paper.toml --set domain.h=0.02 -o out",
        formatter_class=fmt,
    )
    p.add_argument(
        "--version", action="version", version=f"shellobstacle {shellobstacle.__version__}"
    )
    sub = p.add_subparsers(dest="command", required=True)

    def verbosity(sp: argparse.ArgumentParser, verbose: bool = True) -> None:
        group = sp.add_mutually_exclusive_group()
        group.add_argument("-q", "--quiet", action="store_true", help="print only errors")
        if verbose:
            group.add_argument(
                "-v",
                "--verbose",
                action="store_true",
                help="print also a line per Newton iteration (relative residual, step lengths)",
            )

    def common(sp: argparse.ArgumentParser, verbose: bool = True) -> None:
        sp.add_argument("config", help="TOML configuration file")
        sp.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="SECTION.KEY=VALUE",
            help="override a config value (TOML syntax), repeatable",
        )
        verbosity(sp, verbose)

    def output(sp: argparse.ArgumentParser, resume: bool, default: str) -> None:
        sp.add_argument(
            "-o", "--output", default=None, help=f"result folder (default: a new folder {default})"
        )
        group = sp.add_mutually_exclusive_group()
        group.add_argument(
            "--overwrite", action="store_true", help="allow writing into a non-empty -o"
        )
        if resume:
            group.add_argument(
                "--resume",
                action="store_true",
                help="continue the interrupted run in -o OUT (same command and config): "
                "the steps recorded in OUT/steps/ are not recomputed",
            )

    s = sub.add_parser(
        "solve",
        help="solve one penalized problem and write a result folder",
        formatter_class=fmt,
        description="Solve one penalized problem (continuation in κ) and write a result "
        "folder. There is no --resume: the continuation is short, an interrupted solve is "
        "simply run again (experiment and reproduce record their steps and can resume).",
        epilog="example: shellobstacle solve examples/paper.toml -o paper-run",
    )
    common(s)
    output(s, resume=False, default="named after the config")
    s.add_argument(
        "--force",
        action="store_true",
        help="proceed although the theory's assumptions fail (recorded in the results)",
    )

    c = sub.add_parser(
        "check",
        help="evaluate the theory's assumptions on the data and mesh",
        formatter_class=fmt,
        epilog="example: shellobstacle check examples/paper.toml",
    )
    common(c, verbose=False)

    r = sub.add_parser(
        "reproduce",
        help="the paper's section 10 (batches 1-3) with a report",
        formatter_class=fmt,
        epilog="example: shellobstacle reproduce -o paper  (add --full for the paper's sizes; "
        "after an interruption: shellobstacle reproduce -o paper --resume)",
    )
    output(r, resume=True, default="paper-results")
    r.add_argument(
        "--full", action="store_true", help="the paper's sizes (h ≈ 0.0312, 0.0078, 0.0039; long)"
    )
    verbosity(r)

    e = sub.add_parser(
        "experiment",
        help="one batch of the paper's study on any config",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n"
        "  shellobstacle experiment penalty examples/paper.toml --set domain.h=0.02\n"
        "  shellobstacle experiment mesh examples/paper.toml --q 0.5,1.0 --refinements 2\n"
        "  shellobstacle experiment load my.toml --parameter ell --values 0,10,20\n"
        "  shellobstacle experiment penalty my.toml -o b1 --resume   # after an interruption",
    )
    e.add_argument(
        "batch",
        choices=("penalty", "mesh", "load", "solvers"),
        help="penalty: κ = h^q → 0 on a fixed mesh; mesh: nested meshes with κ = h^q; "
        "load: sweep a load parameter; solvers: Newton vs Brezis–Sibony on --sizes",
    )
    common(e)
    output(e, resume=True, default="CONFIG-BATCH")
    e.add_argument("--start", type=float, default=0.5, help="penalty: first exponent q (0.5)")
    e.add_argument("--step", type=float, default=0.5, help="penalty: exponent step (0.5)")
    e.add_argument("--q-max", type=float, default=12.0, help="penalty: last exponent tried (12)")
    e.add_argument("--tol", type=float, default=2e-6, help="stop below this difference (2e-6)")
    e.add_argument("--quadratures", default="gauss,vertex", help="penalty: penalty quadratures")
    e.add_argument("--q", default="0.4,0.5,0.6,0.7,1.0,1.3", help="mesh: exponents q")
    e.add_argument("--refinements", type=int, default=3, help="mesh: uniform refinements (3)")
    e.add_argument("--parameter", default="ell", help="load: the [load] parameter to sweep")
    e.add_argument("--values", default="0,10,20,40,80", help="load: its values")
    e.add_argument("--sizes", default="0.1,0.07", help="solvers: gmsh target sizes of ω")
    e.add_argument("--exponent", type=float, default=1.5, help="solvers: κ = h^exponent")

    sub.add_parser(
        "config-reference",
        help="print the configuration reference (Markdown)",
        epilog="example: shellobstacle config-reference > docs/config-reference.md",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 solver failure, 2 user error)."""
    args = _parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    args.folder = None  # the result folder, once known (for the interruption message)
    from shellobstacle.checks import AssumptionError
    from shellobstacle.config import ConfigError
    from shellobstacle.expressions import ExpressionError
    from shellobstacle.results import ResultsError

    try:
        if args.command == "config-reference":
            from shellobstacle.config import reference_text

            print(reference_text())
            return EXIT_OK
        if args.command == "check":
            return _check(args)
        if args.command == "solve":
            return _solve(args)
        if args.command == "reproduce":
            return _reproduce(args)
        if args.command == "experiment":
            return _experiment(args)
    except (ConfigError, ExpressionError, AssumptionError, ResultsError) as err:
        if MPI.COMM_WORLD.rank == 0:
            print(f"shellobstacle: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        if MPI.COMM_WORLD.rank == 0:
            hint = ""
            if args.folder is not None and hasattr(args, "resume"):
                hint = (
                    f"; the finished steps are recorded in {args.folder}/steps/: continue with "
                    f"the same command and --resume -o {args.folder}"
                )
            print(f"shellobstacle: interrupted{hint}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception:
        if MPI.COMM_WORLD.rank == 0:
            traceback.print_exc()
            print(
                "shellobstacle: internal error (a bug): please report it with the traceback "
                "above and your config file",
                file=sys.stderr,
            )
        return EXIT_FAILED
    return EXIT_USAGE


def _check(args: argparse.Namespace) -> int:
    from shellobstacle.checks import check_assumptions, format_checks
    from shellobstacle.config import load_config
    from shellobstacle.pipeline import make_mesh

    cfg = load_config(args.config, args.set)
    mesh = make_mesh(cfg.domain)
    checks = check_assumptions(cfg.shell, mesh)
    if MPI.COMM_WORLD.rank == 0:
        print(
            f"{cfg.shell.surface.description}; q = {cfg.shell.obstacle.q}; "
            f"ε = {cfg.shell.material.epsilon}"
        )
        print(format_checks(checks))
        failed = [c.name for c in checks if not c.passed]
        if failed:
            print(
                f"shellobstacle: error: assumptions fail: {', '.join(failed)} (see the table)",
                file=sys.stderr,
            )
    return EXIT_OK if all(c.passed for c in checks) else EXIT_USAGE


def _solve(args: argparse.Namespace) -> int:
    from shellobstacle.config import load_config

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cfg = load_config(args.config, args.set)
    report = Reporter(args.quiet, args.verbose)
    for w in caught:
        report(f"warning: {w.message}")
    default = f"{Path(args.config).stem}-results"
    return run_and_write(
        cfg,
        args.output,
        default,
        args.overwrite,
        args.force,
        report,
        [str(w.message) for w in caught],
    )


def run_and_write(
    cfg: Any,
    output: str | None,
    default: str,
    overwrite: bool,
    force: bool,
    report: Reporter,
    config_warnings: Sequence[str] = (),
) -> int:
    """Solve a config and write its result folder; returns the exit code."""
    from shellobstacle.config import to_toml
    from shellobstacle.pipeline import solve_config
    from shellobstacle.report import write_solution
    from shellobstacle.results import atomic_write, prepare_folder

    folder = prepare_folder(output, default, overwrite)
    report.attach(folder / "log.txt")
    report(f"results go to {folder}/")
    atomic_write(folder / "config.toml", to_toml(cfg.resolved))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = solve_config(cfg, force=force, progress=report, newton_progress=report.newton)
    seen = [*config_warnings, *(str(w.message) for w in caught)]
    summary = write_solution(result, cfg, folder, report, seen)
    if not result.converged:
        report(f"FAILED: {result.error}")
        report(f"the last iterate and the residual history are in {folder}/")
        return EXIT_FAILED
    report(
        f"done: κ = {summary['kappa']:.3e}, contact area {summary['contact_area']:.5g} "
        f"(projected {summary['contact_area_projected']:.5g}), min ζ_3 = {summary['zeta3_min']:.5g}"
    )
    return EXIT_OK


def _reproduce(args: argparse.Namespace) -> int:
    """The paper's section 10: batches 1-3 with report.md."""
    from shellobstacle.config import load_config
    from shellobstacle.experiments.report import PAPER_CONFIG, reproduce
    from shellobstacle.results import prepare_folder

    mode = "full" if args.full else "fast"
    meta = {
        "command": "reproduce",
        "mode": mode,
        "config": _compared_config(load_config(PAPER_CONFIG)),
    }
    folder = prepare_folder(args.output, "paper-results", args.overwrite, resume=args.resume)
    args.folder = folder
    report = Reporter(args.quiet, args.verbose)
    checkpoint = _open_checkpoint(folder, meta, args, report)
    report.attach(folder / "log.txt", append=args.resume)
    report(f"results go to {folder}/ (mode {mode}{', resumed' if args.resume else ''})")
    reproduce(folder, mode, report, checkpoint, report.newton)
    _finish(checkpoint, report)
    return EXIT_OK


def _compared_config(cfg: Any) -> dict[str, Any]:
    """The resolved configuration without the sections that do not change any number."""
    return {k: v for k, v in cfg.resolved.items() if k != "output"}


def _open_checkpoint(
    folder: Path, meta: dict[str, Any], args: argparse.Namespace, report: Reporter
) -> Any:
    """Start recording the steps in ``folder/steps`` (or check them for ``--resume``)."""
    from shellobstacle.checkpoint import open_checkpoint
    from shellobstacle.results import versions

    ranks = MPI.COMM_WORLD.size
    info = {"argv": args.argv, "ranks": ranks, "versions": versions()}
    checkpoint = open_checkpoint(folder, {**meta, **info}, args.resume)
    old = checkpoint.recorded_meta
    if old is not None:
        started = " ".join(old.get("argv", []))
        report(f"resuming the interrupted run in {folder}/ (started as: {started})")
        if old.get("ranks") != ranks:
            report(
                f"note: the interrupted run used {old.get('ranks')} MPI rank(s), this one "
                f"{ranks}: recorded and new steps agree to solver tolerance, not bitwise"
            )
    return checkpoint


def _finish(checkpoint: Any, report: Reporter) -> None:
    """Drop the saved vectors (only an unfinished sweep needs them) and say what was reused."""
    checkpoint.finish()
    loaded = checkpoint.stats["loaded"]
    if loaded:
        report(
            f"resumed: {loaded} finished step(s) taken from {checkpoint.dir}/, "
            f"{checkpoint.stats['saved']} computed now"
        )


def _floats(text: str, what: str) -> list[float]:
    from shellobstacle.config import ConfigError

    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{what}: expected comma-separated numbers, got {text!r}") from None


def _experiment_options(args: argparse.Namespace) -> dict[str, Any]:
    """The options of ``args.batch`` that change its numbers (compared on ``--resume``)."""
    if args.batch == "penalty":
        return {
            "--start": args.start,
            "--step": args.step,
            "--q-max": args.q_max,
            "--tol": args.tol,
            "--quadratures": [v.strip() for v in args.quadratures.split(",")],
        }
    if args.batch == "mesh":
        return {
            "--q": _floats(args.q, "--q"),
            "--refinements": args.refinements,
            "--tol": args.tol,
        }
    if args.batch == "solvers":
        return {"--sizes": _floats(args.sizes, "--sizes"), "--exponent": args.exponent}
    return {"--parameter": args.parameter, "--values": _floats(args.values, "--values")}


def _experiment(args: argparse.Namespace) -> int:
    """One batch on a user's config."""
    from shellobstacle.config import ConfigError, load_config, to_toml
    from shellobstacle.experiments import report as batches
    from shellobstacle.experiments.penalty import PenaltyStudyOptions
    from shellobstacle.results import atomic_write, prepare_folder

    cfg = load_config(args.config, args.set)
    if args.batch == "load" and cfg.penalty.exponent is None:
        raise ConfigError("experiment load needs penalty.exponent (κ = h^exponent)")
    options = _experiment_options(args)
    meta = {
        "command": "experiment",
        "batch": args.batch,
        "options": options,
        "config": _compared_config(cfg),
    }
    default = f"{Path(args.config).stem}-{args.batch}"
    folder = prepare_folder(args.output, default, args.overwrite, resume=args.resume)
    args.folder = folder
    report = Reporter(args.quiet, args.verbose)
    checkpoint = _open_checkpoint(folder, meta, args, report)
    report.attach(folder / "log.txt", append=args.resume)
    atomic_write(folder / "config.toml", to_toml(cfg.resolved))
    kw: dict[str, Any] = {"checkpoint": checkpoint, "newton_progress": report.newton}
    if args.batch == "penalty":
        opts = PenaltyStudyOptions(args.start, args.step, args.tol, args.q_max)
        quadratures = options["--quadratures"]
        text = batches.run_penalty(cfg, folder, [cfg.domain], report, opts, quadratures, **kw)
    elif args.batch == "mesh":
        text = batches.run_mesh(
            cfg, folder, cfg.domain, args.refinements, options["--q"], report, args.tol, **kw
        )
    elif args.batch == "solvers":
        sizes = [dataclasses.replace(cfg.domain, h=v) for v in options["--sizes"]]
        text = batches.run_solvers(cfg, folder, sizes, args.exponent, report, **kw)
    else:
        text = batches.run_load(
            cfg,
            folder,
            cfg.domain,
            options["--values"],
            cfg.penalty.exponent,
            report,
            args.parameter,
            **kw,
        )
    loaded = checkpoint.stats["loaded"]
    if loaded:
        text += (
            f"\n\nResumed: {loaded} finished step(s) were taken from the records of an "
            "interrupted run (`steps/`), not recomputed; their `seconds` are those of that run.\n"
        )
    atomic_write(folder / "report.md", f"# Experiment {args.batch}: {args.config}\n\n{text}")
    report(f"report written: {folder / 'report.md'}")
    _finish(checkpoint, report)
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
