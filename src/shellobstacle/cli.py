"""Command line: ``shellobstacle solve | check | reproduce | config-reference``."""

from __future__ import annotations

import argparse
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
PAPER_CONFIG = Path(__file__).parent / "configs" / "paper.toml"


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
        help="the paper's section 10 problem, with a report",
        formatter_class=fmt,
        epilog="example: shellobstacle reproduce -o paper",
    )
    r.add_argument("-o", "--output", default=None, help="result folder")
    r.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty -o")
    r.add_argument("--full", action="store_true", help="the paper's mesh size h ≈ 0.0078")
    r.add_argument("-q", "--quiet", action="store_true", help="print only errors")

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
    return EXIT_OK if all(c.passed for c in checks) else EXIT_USAGE


def _solve(args: argparse.Namespace) -> int:
    from shellobstacle.config import load_config

    cfg = load_config(args.config, args.set)
    default = f"{Path(args.config).stem}-results"
    return run_and_write(
        cfg, args.output, default, args.overwrite, args.force, Reporter(args.quiet)
    )


def run_and_write(
    cfg: Any, output: str | None, default: str, overwrite: bool, force: bool, report: Reporter
) -> int:
    """Solve a config and write its result folder; returns the exit code."""
    from shellobstacle.config import to_toml
    from shellobstacle.report import write_solution
    from shellobstacle.results import atomic_write, prepare_folder
    from shellobstacle.pipeline import solve_config

    folder = prepare_folder(output, default, overwrite)
    report.attach(folder / "log.txt")
    report(f"results go to {folder}/")
    atomic_write(folder / "config.toml", to_toml(cfg.resolved))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = solve_config(cfg, force=force, progress=report)
    summary = write_solution(result, cfg, folder, report, [str(w.message) for w in caught])
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
    """The paper's section 10 problem (a single solve until the batch experiments land)."""
    from shellobstacle.config import load_config

    overrides = [] if args.full else ["domain.h=0.02"]
    cfg = load_config(PAPER_CONFIG, overrides)
    report = Reporter(args.quiet)
    code = run_and_write(cfg, args.output, "paper-results", args.overwrite, False, report)
    if report.log is not None:
        write_report(report.log.parent)
    return code


def write_report(folder: Path) -> None:
    """``report.md``: what was solved, the key numbers and the figure (rank 0)."""
    import json

    from shellobstacle.results import atomic_write

    if MPI.COMM_WORLD.rank != 0:
        return
    s = json.loads((folder / "summary.json").read_text())
    rows = "\n".join(
        f"| {c['kappa']:.3e} | {c['iterations']} | {c['relative_residual']:.1e} | "
        f"{c['seconds']:.2f} | {c['reason']} |"
        for c in s["continuation"]
    )
    times = ", ".join(f"{k} {v:.2f} s" for k, v in s["timings"].items())
    v = s["versions"]
    text = f"""# The paper's section 10 problem

{s["surface"]}; ω = disk of radius 0.5; ε = 0.001, λ = 0.4, μ = 0.012; q = (0, 0, 1);
load (0, 0, g) with the paper's discontinuous g; P1, clamped, Gauss-point penalty.

| quantity | value |
|---|---|
| converged | {s["converged"]} |
| h (largest cell diameter) | {s["h"]:.5g} |
| degrees of freedom | {s["dofs"]} |
| κ = h^1.5 | {s["kappa"]:.4e} |
| Newton steps (all κ) | {s["iterations"]} |
| contact area (√a dy) | {s["contact_area"]:.6g} |
| contact area (projected, dy) | {s["contact_area_projected"]:.6g} |
| largest violation max{{g}}⁻ | {s["max_violation"]:.3e} |
| ζ_3 min / max | {s["zeta3_min"]:.6g} / {s["zeta3_max"]:.6g} |
| energy J(ζ) | {s["energy"]:.6e} |

Continuation in κ (warm starts):

| κ | Newton steps | relative residual | seconds | stop reason |
|---|---|---|---|---|
{rows}

![cross-section](cross_section.png)

Timings: {times}.

Machine: {v["machine"]}, {v["cpus"]} CPUs, {v["mpi_ranks"]} MPI rank(s); shellobstacle
{v["shellobstacle"]}, DOLFINx {v["dolfinx"]}, PETSc {v["petsc"]}, Python {v["python"]};
{v["date"]}. The batch experiments of section 10 (κ and h convergence, load sweep) are
not part of this report yet.
"""
    atomic_write(folder / "report.md", text)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
