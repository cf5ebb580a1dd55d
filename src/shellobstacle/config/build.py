"""A resolved configuration → the package's objects (shell, domain, discretization, penalty,
the method's options): their constructors validate, with the API's messages."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from shellobstacle.config.options import adapt_options, method_options
from shellobstacle.config.origins import in_section
from shellobstacle.config.validated import Config
from shellobstacle.geometry.surface import Surface
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.messages import ConfigError
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import Discretization, Edge, Load, Material, Obstacle, Shell

__all__ = ["build"]


def _need(sec: Mapping[str, Any], section: str, names: tuple[str, ...], why: str) -> None:
    for n in names:
        if n not in sec:
            raise ConfigError(f"[{section}] needs '{n}' for {why}")


def _surface(s: Mapping[str, Any]) -> Surface:
    """The surface of ``[surface]``."""
    kind = s["kind"]
    if kind == "spherical_cap":
        _need(s, "surface", ("radius", "offset"), "kind = 'spherical_cap'")
        return Surface.spherical_cap(s["radius"], s["offset"])
    if kind == "ellipsoid_cap":
        _need(s, "surface", ("semi_axes", "offset"), "kind = 'ellipsoid_cap'")
        return Surface.ellipsoid_cap(s["semi_axes"], s["offset"])
    if kind == "elliptic_paraboloid":
        _need(s, "surface", ("height", "curvatures"), "kind = 'elliptic_paraboloid'")
        return Surface.elliptic_paraboloid(s["height"], s["curvatures"])
    _need(s, "surface", ("theta",), "kind = 'expression'")
    return Surface.from_strings(s["theta"])


def _obstacle(o: Mapping[str, Any]) -> Obstacle:
    """The obstacle of ``[obstacle]`` (the keys its kind reads; vectors as tuples)."""
    return Obstacle(**{k: tuple(v) if isinstance(v, list) else v for k, v in o.items()})


def build(r: dict[str, dict[str, Any]], source: str, given: set[str]) -> Config:
    """The objects of a resolved configuration; their constructors validate (the API's
    messages, which :func:`parse_config` prefixes with the file or the ``--set``). ``given``:
    the keys of ``[solver]`` and the dotted others the file or a ``--set`` gives."""
    with in_section("surface"):
        surface = _surface(r["surface"])
    m = r["material"]
    material = Material(m["epsilon"], m["lambda"], m["mu"])
    load = Load(tuple(r["load"]["p"]), dict(r["load"].get("parameters", {})))
    model = r["model"]["kind"]
    edges = tuple(Edge(**e) for e in r.get("edge", []))
    shell = Shell(
        surface, material, load, _obstacle(r["obstacle"]), model, edges, r["model"]["kinematics"]
    )
    shell.load_expressions()  # parse now: errors name the key

    d = dict(r["domain"])
    if "path" in d and not Path(d["path"]).is_absolute():
        # relative to the config; the resolved config (a result folder's config.toml) holds
        # the absolute path, so that it reruns from anywhere
        base = Path(source).parent if source not in ("<config>", "") else Path(".")
        d["path"] = r["domain"]["path"] = str((base / d["path"]).resolve())
    with in_section("domain"):
        if d["kind"] == "file" and "path" in d:
            _require_mesh_file(d["path"])
        domain = DomainSpec(**d)

    disc = Discretization(**r["discretization"])
    sv = r["solver"]
    if model == "koiter":
        _koiter_choices(sv, disc)

    p = r.get("penalty", {})
    penalty = None
    if not METHODS[sv["method"]].penalized:
        r["penalty"] = {}
    else:
        penalty = PenaltySpec(p.get("kappa"), p.get("exponent"), p["continuation"])
    solver, options = method_options(sv, given)
    adapt = adapt_options(r, shell, penalty, sv["method"]) if "adapt" in r else None
    config = Config(
        shell,
        domain,
        disc,
        penalty,
        solver,
        sv["method"],
        dict(r["output"]),
        r,
        source,
        options,
        adapt,
    )
    # the nodal methods' P1 takes the vertex rule (Config's default)
    r["discretization"]["penalty_quadrature"] = config.discretization.penalty_quadrature
    return config


def _require_mesh_file(path: str) -> None:
    """A mesh file is a regular file: refused at loading, before any result folder."""
    p = Path(path)
    problem = "is a directory" if p.is_dir() else "does not exist" if not p.exists() else None
    if problem or not p.is_file():
        raise ConfigError(
            f"domain.path: mesh file {path!r} {problem or 'is not a regular file'}: give a "
            "gmsh .msh file (a relative path is relative to the config file)"
        )


def _koiter_choices(sv: Mapping[str, Any], disc: Discretization) -> None:
    """The solver and discretization choices Koiter's model cannot take."""
    if sv.get("linear_solver") == "iterative":
        raise ConfigError(
            "solver.linear_solver = 'iterative' preconditions ζ_3 as the membrane's L² "
            "unknown, not Koiter's bending: use linear_solver = 'direct' or 'multigrid'"
        )
    if sv.get("nested_iteration") == "on":
        raise ConfigError(
            "solver.nested_iteration relaxes ζ_3 as the membrane's L² unknown, which Koiter's "
            "bending differentiates: remove the key or set it to 'off'"
        )
    if disc.degree != 2:
        raise ConfigError(
            "model.kind = 'koiter' needs discretization.degree = 2 (ζ_3 ∈ H² by "
            f"C⁰ interior penalty), got {disc.degree}: remove the key or set it to 2"
        )
    if disc.transverse != "clamped":
        raise ConfigError(
            "model.kind = 'koiter' clamps ζ_3 and ∂_ν ζ_3 on γ: remove "
            "discretization.transverse or set it to 'clamped'"
        )
