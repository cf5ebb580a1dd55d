"""What each command of the command line does (:mod:`shellobstacle.cli.main` parses)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mpi4py import MPI

from shellobstacle.cli.output import emit
from shellobstacle.cli.reporter import Reporter
from shellobstacle.progress import LiveStatus, on_terminal, phase

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INVALID, EXIT_INTERRUPTED = 0, 1, 2, 3, 130


def check(args: argparse.Namespace) -> int:
    from shellobstacle.api import make_mesh
    from shellobstacle.checks.assumptions import check_assumptions, format_checks
    from shellobstacle.mesh.resources import require_fits

    cfg, config_warnings = _load(args)
    if not args.force:
        require_fits(cfg.domain, solve=False)
    if MPI.COMM_WORLD.rank == 0:
        for message in config_warnings:
            emit(f"shellobstacle: warning: {message}", sys.stderr)
    with _live_status():
        mesh = make_mesh(cfg.domain)
        with phase("checking the assumptions"):
            checks = check_assumptions(cfg.shell, mesh)
    if MPI.COMM_WORLD.rank == 0:
        emit(
            f"{cfg.shell.surface.description}; q = {cfg.shell.obstacle.q}; "
            f"ε = {cfg.shell.material.epsilon}"
        )
        emit(format_checks(checks))
        failed = [c.name for c in checks if not c.passed]
        if failed:
            emit(
                f"shellobstacle: error: assumptions fail: {', '.join(failed)} (see the table)",
                sys.stderr,
            )
    return EXIT_OK if all(c.passed for c in checks) else EXIT_USAGE


@contextmanager
def _live_status() -> Iterator[None]:
    """The live status line on a terminal (nothing elsewhere) while the block runs."""
    if not on_terminal():
        yield
        return
    with LiveStatus():
        yield


def _load(args: argparse.Namespace) -> tuple[Any, list[str]]:
    """The config of ``args`` and the warnings of loading it, which the command reports once
    every check has passed (a refused command prints its one error line only)."""
    from shellobstacle.config.loader import load_config
    from shellobstacle.experiments.options import EXPERIMENT_READS

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cfg = load_config(args.config, args.set, EXPERIMENT_READS.get(getattr(args, "batch", "")))
    return cfg, [str(w.message) for w in caught]


def solve(args: argparse.Namespace) -> int:
    cfg, config_warnings = _load(args)
    report = Reporter(args.quiet, args.verbose)
    args.report = report
    default = f"{Path(args.config).stem}-solve"
    return run_and_write(
        cfg, args.output, default, args.overwrite, args.force, report, config_warnings, args
    )


def run_and_write(
    cfg: Any,
    output: str | None,
    default: str,
    overwrite: bool,
    force: bool,
    report: Reporter,
    config_warnings: Sequence[str] = (),
    args: argparse.Namespace | None = None,
) -> int:
    """Solve a config and write its result folder; returns the exit code.

    A solve that does not converge has results too (the last iterate, the residual history):
    they replace an old folder like a converged solve's, and the exit code is 1.
    """
    from shellobstacle.api import solve
    from shellobstacle.config.loader import to_toml
    from shellobstacle.io.folders import prepare_folder
    from shellobstacle.io.records import atomic_write
    from shellobstacle.io.summary import write_solution
    from shellobstacle.mesh.resources import require_fits
    from shellobstacle.post.contact import contact_text
    from shellobstacle.solvers.auto import estimated_linear_solver
    from shellobstacle.solvers.registry import METHODS, options_for

    if not force:
        model, degree = cfg.shell.model, cfg.discretization.degree
        method = METHODS[cfg.method]
        options = options_for(method, cfg.method_options, cfg.solver)
        linear = estimated_linear_solver(method, options, cfg.domain, model, degree)
        require_fits(cfg.domain, model, degree, linear_solver=linear)
    where = prepare_folder(output, default, overwrite)
    if args is not None:
        args.folder = where
    folder = where.path
    report.attach(folder / "log.txt")
    _announce(where, report)
    for message in config_warnings:
        report(f"warning: {message}")
    atomic_write(folder / "config.toml", to_toml(cfg.resolved))
    with report.reporting_warnings() as raised:
        result = solve(cfg, force=force)
    seen = [*config_warnings, *raised]
    summary = write_solution(result, cfg, folder, seen)
    if not result.converged:
        report(f"FAILED: {result.error}")
        report(f"the last iterate and the residual history are in {where.target}/")
        _commit(where, report)
        return EXIT_FAILED
    report(
        f"done: κ = {summary['kappa']:.3e}, {contact_text(summary, projected=True)}, "
        f"min ζ_3 = {summary['zeta3_min']:.5g}"
    )
    if summary.get("local_solution"):
        from shellobstacle.post.sides import local_solution_text

        report(local_solution_text(summary))
    _commit(where, report)
    if not summary["validity"]["valid"]:
        report(
            "the solution is outside the model's validity (see the warnings above and "
            f"{where.target}/summary.json's 'validity'): exit status {EXIT_INVALID}"
        )
        return EXIT_INVALID
    return EXIT_OK


def _announce(where: Any, report: Reporter, note: str = "") -> None:
    """Say where the results go (and, for a replacement, where they are written first)."""
    staged = ""
    if where.staged:
        staged = (
            f"; written to {where.path}/ and swapped in when the run ends, the old results "
            "stay until then"
        )
    report(f"results go to {where.target}/{note}{staged}")


def _commit(where: Any, report: Reporter) -> None:
    """The run has ended with results: put them in place (a replacement is swapped in)."""
    where.commit()
    if where.staged:
        report.log = where.target / "log.txt"
        report(f"replaced {where.target}/ with this run's results")


def reproduce(args: argparse.Namespace) -> int:
    """The paper's section 10 (batches 1–4 and the solver comparison) with report.md."""
    from shellobstacle.config.loader import load_config
    from shellobstacle.experiments.reproduce import PAPER_CONFIG, reproduce
    from shellobstacle.io.folders import prepare_folder

    mode = "full" if args.full else "fast"
    args.report = report = Reporter(args.quiet, args.verbose)
    meta = {
        "command": "reproduce",
        "mode": mode,
        "config": _compared_config(load_config(PAPER_CONFIG)),
    }
    where = prepare_folder(args.output, f"reproduce-{mode}", args.overwrite, resume=args.resume)
    args.folder = where
    folder = where.path
    checkpoint = _open_checkpoint(folder, meta, args, report)
    report.attach(folder / "log.txt", append=args.resume)
    _announce(where, report, f" (mode {mode}{', resumed' if args.resume else ''})")
    with report.reporting_warnings():
        reproduce(folder, mode, checkpoint)
    _finish(checkpoint, report)
    _commit(where, report)
    return EXIT_OK


def _compared_config(cfg: Any) -> dict[str, Any]:
    """The resolved configuration without the sections that do not change any number."""
    return {k: v for k, v in cfg.resolved.items() if k != "output"}


def _open_checkpoint(
    folder: Path, meta: dict[str, Any], args: argparse.Namespace, report: Reporter
) -> Any:
    """Start recording the steps in ``folder/steps`` (or check them for ``--resume``)."""
    from shellobstacle.io.checkpoint import open_checkpoint
    from shellobstacle.io.records import versions

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


def experiment(args: argparse.Namespace) -> int:
    """One batch on a user's config."""
    from shellobstacle.config.loader import ConfigError, to_toml
    from shellobstacle.experiments import koiter_limit
    from shellobstacle.experiments.options import (
        experiment_domains,
        experiment_options,
        require_experiment_fits,
    )
    from shellobstacle.io.folders import prepare_folder
    from shellobstacle.io.records import atomic_write

    cfg, config_warnings = _load(args)
    if args.batch == "load" and cfg.penalty is None:
        raise ConfigError(
            "experiment load solves penalized problems (κ = h^exponent), and solver.method = "
            f"{cfg.method!r} has no κ: set solver.method = 'newton' and penalty.exponent"
        )
    if args.batch == "load" and cfg.penalty.exponent is None:
        raise ConfigError(
            "experiment load needs penalty.exponent (κ = h^exponent): set it instead of "
            "penalty.kappa, e.g. --set penalty.exponent=1.5"
        )
    options = experiment_options(args, cfg)
    if args.batch == "koiter-limit":
        koiter_limit.validate(cfg, options["--epsilons"], args.edge_h, args.edge_width)
    domains = experiment_domains(args, cfg, options)  # validated, also with --force
    if not args.force:
        require_experiment_fits(args, cfg, domains)
    meta = {
        "command": "experiment",
        "batch": args.batch,
        "options": options,
        "config": _compared_config(cfg),
    }
    default = f"{Path(args.config).stem}-{args.batch}"
    report = Reporter(args.quiet, args.verbose)
    args.report = report
    where = prepare_folder(args.output, default, args.overwrite, resume=args.resume)
    args.folder = where
    folder = where.path
    checkpoint = _open_checkpoint(folder, meta, args, report)
    report.attach(folder / "log.txt", append=args.resume)
    _announce(where, report, " (resumed)" if args.resume else "")
    for message in config_warnings:
        report(f"warning: {message}")
    atomic_write(folder / "config.toml", to_toml(cfg.resolved))
    kw: dict[str, Any] = {"checkpoint": checkpoint}
    with report.reporting_warnings():
        text = _run_batch(args, cfg, folder, options, kw)
    loaded = checkpoint.stats["loaded"]
    if loaded:
        text += (
            f"\n\nResumed: {loaded} finished step(s) were taken from the records of an "
            "interrupted run (`steps/`), not recomputed; their `seconds` are those of that run.\n"
        )
    atomic_write(folder / "report.md", f"# Experiment {args.batch}: {args.config}\n\n{text}")
    report(f"report written: {where.target / 'report.md'}")
    _finish(checkpoint, report)
    _commit(where, report)
    return EXIT_OK


def _run_batch(
    args: argparse.Namespace,
    cfg: Any,
    folder: Path,
    options: dict[str, Any],
    kw: dict[str, Any],
) -> str:
    """Run the batch of ``experiment``; returns its report section."""
    from shellobstacle.experiments import (
        adaptive,
        koiter_limit,
        load,
        mesh,
        solvers,
    )
    from shellobstacle.experiments.penalty import PenaltyStudyOptions, run_penalty

    if args.batch == "penalty":
        opts = PenaltyStudyOptions(args.start, args.step, args.tol, args.q_max)
        quadratures = options["--quadratures"]
        text = run_penalty(cfg, folder, [cfg.domain], opts, quadratures, **kw)
    elif args.batch == "mesh":
        text = mesh.run_mesh(
            cfg, folder, cfg.domain, args.refinements, options["--q"], args.tol, **kw
        )
    elif args.batch == "adaptive":
        study = adaptive.AdaptiveStudyOptions(
            args.refinements, options["--reference-dofs"], options["--dofs"]
        )
        text = adaptive.run_adaptive(cfg, folder, cfg.domain, study, **kw)
    elif args.batch == "solvers":
        sizes = [dataclasses.replace(cfg.domain, h=v) for v in options["--sizes"]]
        text = solvers.run_solvers(cfg, folder, sizes, args.exponent, **kw)
    elif args.batch == "koiter-limit":
        domain = koiter_limit.study_domain(
            cfg.domain, options["--epsilons"], args.edge_h, args.edge_width, options["--full"]
        )
        epsilons = options["--epsilons"]
        text = koiter_limit.run_koiter_limit(cfg, folder, domain, epsilons, **kw)
    else:
        text = load.run_load(
            cfg,
            folder,
            cfg.domain,
            options["--values"],
            cfg.penalty.exponent,
            args.parameter,
            **kw,
        )
    return text


def doctor(args: argparse.Namespace) -> int:
    """The environment, versions and process tuning; exit 1 when a problem was found
    (``--repair``: after repairing the FFCx cache)."""
    from shellobstacle.cli.doctor import repair_cache, report
    from shellobstacle.compat import bootstrap

    repaired = repair_cache() if args.repair and MPI.COMM_WORLD.rank == 0 else []
    lines, problems = report(bootstrap())
    if MPI.COMM_WORLD.rank == 0:
        emit("\n".join([*lines, *repaired]))
        for problem in problems:
            emit(f"problem: {problem}")
        if not problems:
            emit("no problems found")
    return EXIT_FAILED if problems else EXIT_OK
