"""The arguments of the command line: its commands, their options and the examples in their
help (:func:`parser`; :mod:`shellobstacle.cli.main` runs what they ask)."""

from __future__ import annotations

import argparse
import platform
import re
from collections.abc import Sequence

import shellobstacle
from shellobstacle.cli.output import emit

__all__ = ["parser"]


class _Version(argparse.Action):
    """``--version``: the package's version, then Python's and the key dependencies' (imported
    only when asked, :mod:`shellobstacle.dependencies`)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs) -> None:
        kwargs |= {"nargs": 0, "default": argparse.SUPPRESS}
        super().__init__(option_strings, argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        from shellobstacle.dependencies import installed_versions, summary

        emit(f"shellobstacle {shellobstacle.__version__}")
        emit(f"Python {platform.python_version()}; {summary(installed_versions())}")
        parser.exit()


class _Parser(argparse.ArgumentParser):
    """An argument parser that takes ``-1e-2`` and ``-0.5,1`` as values, not options.

    argparse's own pattern knows ``-1`` and ``-.5`` only, so ``--epsilons -1e-2`` stopped at
    "expected one argument" with the whole usage; the value now reaches the option's check,
    which names what is wrong in one line. No option of this parser looks like a number.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(
            r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(,[-+.\deE]*)*$"
        )


def parser() -> argparse.ArgumentParser:
    """The parser of ``shellobstacle``'s arguments, one subcommand per command."""
    fmt = argparse.ArgumentDefaultsHelpFormatter
    p = _Parser(
        prog="shellobstacle",
        description="Elliptic membrane shells pushed against a plane: penalty method, "
        "finite elements, Newton (Meixner & Piersanti 2024).",
        epilog="example: shellobstacle solve examples/paper.toml --set domain.h=0.02 -o out",
        formatter_class=fmt,
    )
    p.add_argument(
        "--version", action=_Version, help="the versions of shellobstacle and its dependencies"
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
            "-o",
            "--output",
            default=None,
            help=f"result folder (default: a new folder {default}, or {default}-2, -3, ... "
            "if taken); a folder that a failed run left without results is reused",
        )
        group = sp.add_mutually_exclusive_group()
        group.add_argument(
            "--overwrite",
            action="store_true",
            help="replace the results in -o: the run writes into .NAME.partial beside it and "
            "swaps it in whole when it ends; if it fails, the old results stay",
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
    output(s, resume=False, default="CONFIG-solve")
    s.add_argument(
        "--force",
        action="store_true",
        help="proceed although the theory's assumptions fail (recorded in the results) or the "
        "mesh looks too large for this machine's memory",
    )

    c = sub.add_parser(
        "check",
        help="evaluate the theory's assumptions on the data and mesh",
        formatter_class=fmt,
        epilog="example: shellobstacle check examples/paper.toml",
    )
    common(c, verbose=False)
    c.add_argument(
        "--force",
        action="store_true",
        help="mesh although the mesh looks too large for this machine's memory",
    )

    r = sub.add_parser(
        "reproduce",
        help="the paper's section 10 (batches 1-3) with a report",
        formatter_class=fmt,
        epilog="example: shellobstacle reproduce -o paper  (add --full for the paper's sizes; "
        "after an interruption: shellobstacle reproduce -o paper --resume)",
    )
    output(r, resume=True, default="reproduce-MODE")
    r.add_argument(
        "--full",
        action="store_true",
        help="the paper's sizes (h ≈ 0.0312, 0.0078, 0.0039; long); mode full, else fast",
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
        "  shellobstacle experiment koiter-limit examples/paper.toml --epsilons 1e-1,1e-2,1e-3\n"
        "  shellobstacle experiment adaptive examples/paper.toml --reference-dofs 200000\n"
        "  shellobstacle experiment penalty my.toml -o b1 --resume   # after an interruption",
    )
    e.add_argument(
        "batch",
        choices=("penalty", "mesh", "load", "solvers", "koiter-limit", "adaptive"),
        help="penalty: κ = h^q → 0 on a fixed mesh; mesh: nested meshes with κ = h^q; "
        "load: sweep a load parameter; solvers: Newton vs Brezis–Sibony on --sizes; "
        "koiter-limit: Koiter's model against the membrane model as ε → 0; adaptive: "
        "the error against dofs of uniform and adaptive refinement ([adapt])",
    )
    common(e)
    output(e, resume=True, default="CONFIG-BATCH")
    e.add_argument("--start", type=float, default=0.5, help="penalty: first exponent q (0.5)")
    e.add_argument("--step", type=float, default=0.5, help="penalty: exponent step (0.5)")
    e.add_argument("--q-max", type=float, default=12.0, help="penalty: last exponent tried (12)")
    e.add_argument("--tol", type=float, default=2e-6, help="stop below this difference (2e-6)")
    e.add_argument(
        "--quadratures",
        default=None,
        help="penalty: penalty quadratures (gauss,vertex with P1 elements, gauss with P2)",
    )
    e.add_argument("--q", default="0.4,0.5,0.6,0.7,1.0,1.3", help="mesh: exponents q")
    e.add_argument(
        "--refinements", type=int, default=3, help="mesh, adaptive: uniform refinements (3)"
    )
    e.add_argument(
        "--reference-dofs",
        type=int,
        default=200_000,
        help="adaptive: the reference is the exact VI on adapted meshes up to this many dofs",
    )
    e.add_argument(
        "--dofs",
        type=int,
        default=None,
        help="adaptive: the adaptive loop's last mesh has at least this many dofs (default: "
        "adapt.target_dofs, else --reference-dofs / 8)",
    )
    e.add_argument("--parameter", default="ell", help="load: the [load] parameter to sweep")
    e.add_argument("--values", default="0,10,20,40,80", help="load: its values")
    e.add_argument("--sizes", default="0.1,0.07", help="solvers: gmsh target sizes of ω")
    e.add_argument("--exponent", type=float, default=1.5, help="solvers: κ = h^exponent")
    e.add_argument(
        "--epsilons", default="1e-1,3.16e-2,1e-2,3.16e-3,1e-3", help="koiter-limit: Koiter's ε"
    )
    e.add_argument(
        "--edge-h",
        type=float,
        default=None,
        help="koiter-limit: mesh size along γ (default: domain.edge_h, else h/2)",
    )
    e.add_argument(
        "--edge-width",
        type=float,
        default=None,
        help="koiter-limit: width of the band meshed at --edge-h (default: domain.edge_width, "
        "else 3√(smallest ε))",
    )
    e.add_argument(
        "--full",
        action="store_true",
        help="koiter-limit: the config's own mesh sizes (long); by default they are scaled up "
        "alike to a mesh of about 10⁵ dofs",
    )
    e.add_argument(
        "--force",
        action="store_true",
        help="proceed although a mesh looks too large for this machine's memory",
    )

    d = sub.add_parser(
        "doctor",
        help="the environment, versions, process tuning in force and known problems",
        epilog="example: shellobstacle doctor",
    )
    d.add_argument(
        "--repair",
        action="store_true",
        help="remove the files at fault in broken entries of the FFCx cache (a compilation "
        "cut short, a marker without its source or module)",
    )
    sub.add_parser(
        "config-reference",
        help="print the configuration reference (Markdown)",
        epilog="example: shellobstacle config-reference > docs/config-reference.md",
    )
    return p
