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

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


class Reporter:
    """Progress lines on rank 0 (stderr), also appended to a log file once one is known."""

    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet
        self.start = time.perf_counter()
        self.log: Path | None = None
        self.lines: list[str] = []

    def __call__(self, msg: str) -> None:
        line = f"[{time.perf_counter() - self.start:7.1f}s] {msg}"
        self.lines.append(line)
        if MPI.COMM_WORLD.rank != 0:
            return
        if not self.quiet:
            print(line, file=sys.stderr, flush=True)
        if self.log is not None:
            with self.log.open("a") as f:
                f.write(line + "\n")

    def attach(self, path: Path) -> None:
        """Start logging to ``path`` (the lines so far are written first)."""
        self.log = path
        if MPI.COMM_WORLD.rank == 0:
            path.write_text("".join(line + "\n" for line in self.lines))


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

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("config", help="TOML configuration file")
        sp.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="SECTION.KEY=VALUE",
            help="override a config value (TOML syntax), repeatable",
        )
        sp.add_argument("-q", "--quiet", action="store_true", help="print only errors")

    s = sub.add_parser(
        "solve",
        help="solve one penalized problem and write a result folder",
        formatter_class=fmt,
        epilog="example: shellobstacle solve examples/paper.toml -o paper-run",
    )
    common(s)
    s.add_argument(
        "-o",
        "--output",
        default=None,
        help="result folder (default: a new folder named after the config)",
    )
    s.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty -o")
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
    common(c)

    r = sub.add_parser(
        "reproduce",
        help="the paper's section 10 (batches 1-3) with a report",
        formatter_class=fmt,
        epilog="example: shellobstacle reproduce -o paper  (add --full for the paper's sizes)",
    )
    r.add_argument("-o", "--output", default=None, help="result folder")
    r.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty -o")
    r.add_argument(
        "--full", action="store_true", help="the paper's sizes (h ≈ 0.0312, 0.0078, 0.0039; long)"
    )
    r.add_argument("-q", "--quiet", action="store_true", help="print only errors")

    e = sub.add_parser(
        "experiment",
        help="one batch of the paper's study on any config",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n"
        "  shellobstacle experiment penalty examples/paper.toml --set domain.h=0.02\n"
        "  shellobstacle experiment mesh examples/paper.toml --q 0.5,1.0 --refinements 2\n"
        "  shellobstacle experiment load my.toml --parameter ell --values 0,10,20",
    )
    e.add_argument(
        "batch",
        choices=("penalty", "mesh", "load", "solvers"),
        help="penalty: κ = h^q → 0 on a fixed mesh; mesh: nested meshes with κ = h^q; "
        "load: sweep a load parameter; solvers: Newton vs Brezis–Sibony on --sizes",
    )
    common(e)
    e.add_argument("-o", "--output", default=None, help="result folder")
    e.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty -o")
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

    sub.add_parser("config-reference", help="print the configuration reference (Markdown)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 1 solver failure, 2 user error)."""
    args = _parser().parse_args(argv)
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
    report = Reporter(args.quiet)
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
        result = solve_config(cfg, force=force, progress=report)
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
    from shellobstacle.experiments.report import reproduce
    from shellobstacle.results import prepare_folder

    folder = prepare_folder(args.output, "paper-results", args.overwrite)
    report = Reporter(args.quiet)
    report.attach(folder / "log.txt")
    report(f"results go to {folder}/ (mode {'full' if args.full else 'fast'})")
    reproduce(folder, "full" if args.full else "fast", report)
    return EXIT_OK


def _floats(text: str, what: str) -> list[float]:
    from shellobstacle.config import ConfigError

    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{what}: expected comma-separated numbers, got {text!r}") from None


def _experiment(args: argparse.Namespace) -> int:
    """One batch on a user's config."""
    from shellobstacle.config import ConfigError, load_config, to_toml
    from shellobstacle.experiments import report as batches
    from shellobstacle.experiments.penalty import PenaltyStudyOptions
    from shellobstacle.results import atomic_write, prepare_folder

    cfg = load_config(args.config, args.set)
    if args.batch == "load" and cfg.penalty.exponent is None:
        raise ConfigError("experiment load needs penalty.exponent (κ = h^exponent)")
    default = f"{Path(args.config).stem}-{args.batch}"
    folder = prepare_folder(args.output, default, args.overwrite)
    report = Reporter(args.quiet)
    report.attach(folder / "log.txt")
    atomic_write(folder / "config.toml", to_toml(cfg.resolved))
    if args.batch == "penalty":
        opts = PenaltyStudyOptions(args.start, args.step, args.tol, args.q_max)
        quadratures = [v.strip() for v in args.quadratures.split(",")]
        text = batches.run_penalty(cfg, folder, [cfg.domain], report, opts, quadratures)
    elif args.batch == "mesh":
        q_values = _floats(args.q, "--q")
        text = batches.run_mesh(
            cfg, folder, cfg.domain, args.refinements, q_values, report, args.tol
        )
    elif args.batch == "solvers":
        sizes = [dataclasses.replace(cfg.domain, h=v) for v in _floats(args.sizes, "--sizes")]
        text = batches.run_solvers(cfg, folder, sizes, args.exponent, report)
    else:
        values = _floats(args.values, "--values")
        text = batches.run_load(
            cfg, folder, cfg.domain, values, cfg.penalty.exponent, report, args.parameter
        )
    atomic_write(folder / "report.md", f"# Experiment {args.batch}: {args.config}\n\n{text}")
    report(f"report written: {folder / 'report.md'}")
    return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
