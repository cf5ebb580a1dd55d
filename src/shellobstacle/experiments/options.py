"""The ``experiment`` command's options, parsed and checked before any folder or mesh is made.

Every numeric option is finite and in its range, every list non-empty, every choice known, and
every sweep bounded; a mistake is a :class:`~shellobstacle.messages.ConfigError` naming the option
and the fix (exit 2). :func:`experiment_domains` lists the meshes a batch will make, so that
their size is checked against the machine (:mod:`shellobstacle.mesh.resources`) first.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from typing import Any

from shellobstacle.config.loader import Config, ConfigError
from shellobstacle.mesh.domains import DomainSpec, validate
from shellobstacle.obstacle import from_spec
from shellobstacle.solvers.registry import METHODS

__all__ = [
    "EXPERIMENT_READS",
    "MAX_STEPS",
    "experiment_domains",
    "experiment_options",
    "numbers",
    "require_experiment_fits",
]

#: The most values a sweep may take (penalty exponents, mesh exponents, load values, ...).
MAX_STEPS = 200
#: The most uniform refinements of ``experiment mesh`` (each quadruples the cells).
MAX_REFINEMENTS = 8
#: the kinds and methods whose keys a batch reads besides the config's own choice (its
#: warnings about keys that are not read leave them out): the sweeps solve by Newton whatever
#: solver.method, koiter-limit solves Koiter's model on any config, solvers runs Brezis–Sibony
#: beside Newton
EXPERIMENT_READS: dict[str, dict[str, tuple[str, ...]]] = {
    "penalty": {"solver.method": ("newton",)},
    "mesh": {"solver.method": ("newton",)},
    "load": {"solver.method": ("newton",)},
    "koiter-limit": {"model.kind": ("koiter",), "solver.method": ("newton",)},
    "solvers": {"solver.method": ("newton", "brezis-sibony")},
}


def numbers(text: str, what: str, positive: bool = False) -> list[float]:
    """Comma-separated finite numbers (at least one, at most :data:`MAX_STEPS`)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if not values:
        raise ConfigError(f"{what}: expected at least one number, got {text!r}")
    if len(values) > MAX_STEPS:
        raise ConfigError(f"{what}: {len(values)} values, at most {MAX_STEPS}: give fewer")
    for v in values:
        if not math.isfinite(v) or (positive and not v > 0):
            kind = "positive numbers" if positive else "finite numbers"
            raise ConfigError(f"{what}: expected {kind}, got {v:g}")
    return values


def _positive(value: float, what: str) -> float:
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{what} must be a positive number, got {value:g}")
    return value


def _quadratures(args: argparse.Namespace, cfg: Config) -> list[str]:
    """``--quadratures``, by default every one the element allows (vertex: P1 only)."""
    from shellobstacle.config.schema import SCHEMA

    degree = cfg.discretization.degree
    if args.quadratures is None:
        return ["gauss", "vertex"] if degree == 1 else ["gauss"]
    quadratures = [v.strip() for v in args.quadratures.split(",") if v.strip()]
    choices = SCHEMA["discretization"]["penalty_quadrature"].choices
    if not quadratures:
        raise ConfigError(f"--quadratures: expected one or more of {', '.join(choices)}")
    for q in quadratures:
        if q not in choices:
            raise ConfigError(f"--quadratures: {q!r} is not one of {', '.join(map(repr, choices))}")
    if len(set(quadratures)) != len(quadratures):
        raise ConfigError(f"--quadratures: {args.quadratures!r} names a quadrature twice")
    if "vertex" in quadratures and degree != 1:
        raise ConfigError(
            "--quadratures: 'vertex' is the nodal constraint of P1 elements, and "
            f"discretization.degree is {degree}: use --quadratures gauss"
        )
    return quadratures


def experiment_options(args: argparse.Namespace, cfg: Config) -> dict[str, Any]:
    """The options of ``args.batch`` that change its numbers (compared on ``--resume``),
    checked against ``cfg``.

    Raises:
        ConfigError: an option out of range, an empty or too long list, an unknown choice.
    """
    if args.batch != "adaptive" and not from_spec(cfg.shell.obstacle).affine:
        raise ConfigError(
            f"experiment {args.batch} solves with the plane's exact machinery and does not "
            f"linearize a curved obstacle (obstacle.kind = {cfg.shell.obstacle.kind!r}): use "
            "'shellobstacle solve' or 'experiment adaptive' for it"
        )
    tol = _positive(args.tol, "--tol")
    if args.batch == "penalty":
        start = _positive(args.start, "--start")
        step = _positive(args.step, "--step")
        q_max = _positive(args.q_max, "--q-max")
        if q_max < start:
            raise ConfigError(f"--q-max ({q_max:g}) must be at least --start ({start:g})")
        if (q_max - start) / step + 1 > MAX_STEPS:
            raise ConfigError(
                f"--start {start:g} --step {step:g} --q-max {q_max:g} make more than "
                f"{MAX_STEPS} exponents: use a larger --step"
            )
        return {
            "--start": start,
            "--step": step,
            "--q-max": q_max,
            "--tol": tol,
            "--quadratures": _quadratures(args, cfg),
        }
    if args.batch == "mesh":
        if not 0 <= args.refinements <= MAX_REFINEMENTS:
            raise ConfigError(
                f"--refinements must be between 0 and {MAX_REFINEMENTS} (each quadruples the "
                f"cells), got {args.refinements}"
            )
        return {
            "--q": numbers(args.q, "--q", positive=True),
            "--refinements": args.refinements,
            "--tol": tol,
        }
    if args.batch == "adaptive":
        return _adaptive_options(args, cfg)
    if args.batch == "solvers":
        return {
            "--sizes": numbers(args.sizes, "--sizes", positive=True),
            "--exponent": _positive(args.exponent, "--exponent"),
        }
    if args.batch == "koiter-limit":
        for name in ("edge_h", "edge_width"):
            value = getattr(args, name)
            if value is not None:
                _positive(value, f"--{name.replace('_', '-')}")
        return {
            "--epsilons": numbers(args.epsilons, "--epsilons", positive=True),
            "--edge-h": args.edge_h,
            "--edge-width": args.edge_width,
            "--full": args.full,
        }
    parameters = sorted(cfg.shell.load.parameters)
    if args.parameter not in parameters:
        have = ", ".join(parameters) if parameters else "none"
        raise ConfigError(
            f"--parameter {args.parameter!r}: the load has no such parameter (it has: {have}); "
            "add it to [load] parameters and use it in load.p"
        )
    return {"--parameter": args.parameter, "--values": numbers(args.values, "--values")}


def _adaptive_options(args: argparse.Namespace, cfg: Config) -> dict[str, Any]:
    """``--refinements``, ``--reference-dofs``, ``--dofs`` of ``experiment adaptive``, and the
    config choices it needs."""
    if not 0 <= args.refinements <= MAX_REFINEMENTS:
        raise ConfigError(
            f"--refinements must be between 0 and {MAX_REFINEMENTS} (each quadruples the "
            f"cells), got {args.refinements}"
        )
    if not args.reference_dofs > 0:
        raise ConfigError(f"--reference-dofs must be a positive number, got {args.reference_dofs}")
    if args.dofs is not None and not 0 < args.dofs <= args.reference_dofs:
        raise ConfigError(
            f"--dofs must be positive and at most --reference-dofs ({args.reference_dofs}), "
            f"got {args.dofs}"
        )
    if cfg.shell.model != "membrane":
        raise ConfigError(
            "experiment adaptive refines by the membrane model's error indicators: set "
            "model.kind = 'membrane'"
        )
    if not METHODS[cfg.method].adaptive:
        names = " or ".join(repr(m.name) for m in METHODS.values() if m.adaptive)
        raise ConfigError(f"experiment adaptive solves by {names}: set solver.method = {names}")
    return {
        "--refinements": args.refinements,
        "--reference-dofs": args.reference_dofs,
        "--dofs": args.dofs,
    }


def experiment_domains(
    args: argparse.Namespace, cfg: Config, options: dict[str, Any]
) -> list[DomainSpec]:
    """The largest meshes ``args.batch`` will make (for the resource check), validated.

    Raises:
        ConfigError: a size option makes an impossible domain (e.g. ``--sizes`` larger
            than ω).
    """
    domain = cfg.domain
    try:
        if args.batch in ("mesh", "adaptive"):
            finest = domain.refinements + options["--refinements"]
            domains = [dataclasses.replace(domain, refinements=finest)]
        elif args.batch == "solvers":
            domains = [dataclasses.replace(domain, h=h) for h in options["--sizes"]]
        elif args.batch == "koiter-limit":
            from shellobstacle.experiments.koiter_limit import study_domain

            epsilons, full = options["--epsilons"], options["--full"]
            domains = [study_domain(domain, epsilons, args.edge_h, args.edge_width, full)]
        else:
            domains = [domain]
        for spec in domains:
            validate(spec)
    except ValueError as err:
        raise ConfigError(f"{_size_option(args)}: {err}") from None
    return domains


def require_experiment_fits(
    args: argparse.Namespace, cfg: Config, domains: list[DomainSpec]
) -> None:
    """Refuse (:class:`~shellobstacle.mesh.resources.ResourceError`) a mesh of ``domains`` that
    would not fit in this machine's memory with the model the batch solves."""
    from shellobstacle.mesh.resources import require_fits

    model, degree = cfg.shell.model, cfg.discretization.degree
    if args.batch == "koiter-limit":
        model, degree = "koiter", 2
    for domain in domains:
        require_fits(domain, model, degree, what=_size_option(args))


def _size_option(args: argparse.Namespace) -> str:
    """What sets the size of the batch's meshes, as errors name it."""
    return {"solvers": "--sizes", "koiter-limit": "--edge-h/--edge-width"}.get(
        args.batch, "[domain]"
    )
