"""The configuration's schema: every section and key, its type, default and meaning.

:mod:`shellobstacle.config.loader` validates against it and ``shellobstacle config-reference``
prints it (:func:`reference_text`), so the documentation cannot drift from the loader. The
defaults and choices of the keys that set a field of the API's dataclasses (``Discretization``,
``DomainSpec``, ...) are read from those fields (:mod:`shellobstacle.config.keys`), and the
keys of ``[solver]`` and ``[obstacle]`` are made from the declarations of the registered
methods' options and shapes, so the command line and the Python API cannot drift either.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.config.keys import (
    OPTIONAL,
    REQUIRED,
    ByValue,
    Key,
    RegistryKeys,
    bound,
    option_key,
)
from shellobstacle.geometry.surface import SURFACE_KINDS
from shellobstacle.mesh.domains import KINDS, DomainSpec
from shellobstacle.obstacle.shapes import SHAPES, declared, shape_help
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.options import config_keys
from shellobstacle.solvers.registry import DEFAULT, METHODS, method_help
from shellobstacle.spec import EDGE_CONDITIONS, Discretization, Load, Obstacle, Shell

__all__ = [
    "ARRAY_SECTIONS",
    "OPTIONAL_SECTIONS",
    "REQUIRED_SECTIONS",
    "SCHEMA",
    "SELECTORS",
    "reference_text",
]

#: the methods that read [penalty] (the registry's at import)
_PENALIZED = tuple(m.name for m in METHODS.values() if m.penalized)


def _obstacle_keys() -> dict[str, Key]:
    """The keys of ``[obstacle]`` for the shapes registered now
    (:data:`~shellobstacle.obstacle.shapes.SHAPES`): ``kind``, every shape's parameters,
    ``contact_face``. A key that several shapes read is one key: their type, each one's
    default (:class:`ByValue` where they differ) and meaning."""
    keys = {"kind": bound(Obstacle, "kind", "str", shape_help())}
    names = dict.fromkeys(p.name for s in SHAPES.values() for p in s.parameters)
    for name in names:
        found = declared(name)
        defaults = {kind: p.default for kind, p in found}
        default = defaults[found[0][0]]
        if any(v != default for v in defaults.values()):
            default = ByValue(defaults)
        helps = dict.fromkeys(p.help for _, p in found)
        help = found[0][1].help
        if len(helps) > 1:
            help = "; ".join(f"{p.help} ({kind})" for kind, p in found)
        choices = tuple(dict.fromkeys(c for _, p in found for c in p.choices))
        kinds = tuple(kind for kind, _ in found)
        fields = {kind: (Obstacle, "parameters") for kind in kinds}
        keys[name] = Key(found[0][1].type, default, help, choices, kinds, fields)
    keys["contact_face"] = bound(
        Obstacle,
        "contact_face",
        "str",
        "the face that must stay admissible: middle (θ), lower (θ − ε a_3) or upper (θ + ε a_3)",
    )
    return keys


def _solver_keys() -> dict[str, Key]:
    """The keys of ``[solver]`` for the methods registered now
    (:data:`~shellobstacle.solvers.registry.METHODS`): ``method``, then every key their
    options declare (:func:`~shellobstacle.solvers.options.option`), those every method
    reads last; a key that several methods read is one key
    (:func:`~shellobstacle.config.keys.option_key`)."""
    keys = {"method": Key("str", DEFAULT, method_help(), tuple(METHODS))}
    readers: dict[str, dict[str, tuple[type, dataclasses.Field]]] = {}
    for name, method in METHODS.items():
        for key, f in config_keys(method.options_type).items():
            readers.setdefault(key, {})[name] = (method.options_type, f)
    every = [key for key, found in readers.items() if set(found) == set(METHODS)]
    for key in sorted(readers, key=every.__contains__):  # the keys every method reads last
        keys[key] = option_key(readers[key], every=key in every)
    return keys


SCHEMA: dict[str, Mapping[str, Key]] = {
    "surface": {
        "kind": Key("str", REQUIRED, "built-in surface or 'expression'", SURFACE_KINDS),
        "radius": Key("float", OPTIONAL, "sphere radius R", when=("spherical_cap",)),
        "offset": Key(
            "float", OPTIONAL, "downward shift of θ_3", when=("spherical_cap", "ellipsoid_cap")
        ),
        "semi_axes": Key("float[3]", OPTIONAL, "semi-axes (A, B, C)", when=("ellipsoid_cap",)),
        "height": Key("float", OPTIONAL, "apex height", when=("elliptic_paraboloid",)),
        "curvatures": Key(
            "float[2]", OPTIONAL, "apex curvatures (k1, k2)", when=("elliptic_paraboloid",)
        ),
        "theta": Key("str[3]", OPTIONAL, "θ(y1, y2) as three SymPy strings", when=("expression",)),
    },
    "domain": {
        "kind": Key("str", REQUIRED, "shape of ω", KINDS),
        "h": bound(
            DomainSpec,
            "h",
            "float",
            "target mesh size (gmsh); the h obtained is reported",
            when=tuple(k for k in KINDS if k != "file"),
        ),
        "radius": bound(DomainSpec, "radius", "float", "radius", when=("disk",)),
        "center": bound(DomainSpec, "center", "float[2]", "centre", when=("disk", "ellipse")),
        "semi_axes": bound(DomainSpec, "semi_axes", "float[2]", "semi-axes", when=("ellipse",)),
        "vertices": bound(
            DomainSpec, "vertices", "points", "list of [y1, y2] vertices", when=("polygon",)
        ),
        "corners": bound(
            DomainSpec,
            "corners",
            "points",
            "[[y1_min, y2_min], [y1_max, y2_max]]",
            when=("rectangle",),
        ),
        "path": bound(
            DomainSpec,
            "path",
            "str",
            "a gmsh .msh file of triangles (relative to the config; a result folder's "
            "config.toml holds it absolute)",
            when=("file",),
        ),
        "refinements": bound(
            DomainSpec, "refinements", "int", "uniform refinements after meshing (nested meshes)"
        ),
        "central_h": bound(
            DomainSpec, "central_h", "float", "disk/ellipse: finer mesh size near the centre"
        ),
        "central_radius": bound(
            DomainSpec, "central_radius", "float", "disk/ellipse: radius of the finer region"
        ),
        "edge_h": bound(
            DomainSpec, "edge_h", "float", "disk/ellipse/polygon: finer mesh size along γ"
        ),
        "edge_width": bound(
            DomainSpec, "edge_width", "float", "disk/ellipse/polygon: width of the finer band"
        ),
        "gmsh_max_vertices": bound(
            DomainSpec,
            "gmsh_max_vertices",
            "int",
            "above this, gmsh meshes coarser and the mesh is refined (0: never)",
            when=("disk", "ellipse", "polygon"),
        ),
    },
    "material": {
        "epsilon": Key("float", REQUIRED, "half-thickness ε > 0"),
        "lambda": Key("float", REQUIRED, "Lamé constant λ ≥ 0"),
        "mu": Key("float", REQUIRED, "Lamé constant μ > 0"),
    },
    "load": {
        "p": Key("str|float[3]", REQUIRED, "contravariant force density p^i(y1, y2, r)"),
        "parameters": bound(
            Load,
            "parameters",
            "table",
            "named numbers the load may use (sweepable)",
        ),
    },
    "model": {
        "kind": bound(
            Shell,
            "model",
            "str",
            "membrane: the paper's model (elliptic surfaces); koiter: membrane + bending, any "
            "immersed thin shell (P2, C⁰ interior penalty for ζ_3)",
        ),
        "kinematics": bound(
            Shell,
            "kinematics",
            "str",
            "linear: strains linear in ζ; nonlinear: Koiter's strains of the deformed surface "
            "(large deflections; kind = 'koiter', bending = 'c0ip', method = 'newton')",
        ),
    },
    "obstacle": RegistryKeys(SHAPES, _obstacle_keys),
    "penalty": {
        "kappa": bound(PenaltySpec, "kappa", "float", "penalty parameter κ > 0", when=_PENALIZED),
        "exponent": bound(
            PenaltySpec,
            "exponent",
            "float",
            "κ = h^exponent (the paper's coupling)",
            when=_PENALIZED,
        ),
        "continuation": bound(
            PenaltySpec,
            "continuation",
            "bool",
            "reach κ through a ladder of larger κ (warm starts)",
            when=_PENALIZED,
        ),
    },
    "discretization": {
        "degree": bound(
            Discretization, "degree", "int", "Lagrange degree of all components (1 or 2; Koiter: 2)"
        ),
        "transverse": bound(Discretization, "transverse", "str", "boundary condition of ζ_3"),
        "penalty_quadrature": bound(
            Discretization, "penalty_quadrature", "str", "where the penalty is integrated"
        ),
        "quadrature_degree": bound(
            Discretization, "quadrature_degree", "int", "quadrature degree (default 2·degree + 2)"
        ),
        "interior_penalty": bound(
            Discretization,
            "interior_penalty",
            "float",
            "σ of the facet penalty of ∂_n ζ_3 (default 16; c0ip: 8)",
            when=("koiter",),
        ),
        "bending": bound(
            Discretization,
            "bending",
            "str",
            "the bending form, hybrid (a multiplier per facet) or c0ip (C⁰ interior penalty)",
            when=("koiter",),
        ),
    },
    "solver": RegistryKeys(METHODS, _solver_keys),
    "edge": {
        "condition": Key(
            "str",
            REQUIRED,
            "clamped: ζ = 0, ∂_ν ζ_3 = 0; simply-supported: ζ = 0; free: nothing; symmetry: "
            "ζ_α = 0 and ∂_ν ζ_3 = 0 on a line y_α = c about which θ is symmetric (membrane: "
            "clamped only)",
            EDGE_CONDITIONS,
        ),
        "where": Key(
            "str",
            OPTIONAL,
            "the part: the boundary facets whose midpoint satisfies this condition in y1, y2, "
            "r (e.g. 'y1 < -0.499', 'And(y1 > 0, y2 > 0)')",
        ),
        "tag": Key(
            "int", OPTIONAL, "or the part: a gmsh physical curve of a domain.kind = 'file' mesh"
        ),
    },
    "adapt": {
        "fraction": bound(
            AdaptOptions,
            "fraction",
            "float",
            "Dörfler's θ: the marked cells hold this share of Σ η_T²",
        ),
        "max_levels": bound(
            AdaptOptions,
            "max_levels",
            "int",
            "the most refinements (max_levels + 1 meshes solved)",
        ),
        "target_error": bound(
            AdaptOptions, "target_error", "float", "stop once the estimate η is at most this"
        ),
        "target_dofs": bound(
            AdaptOptions, "target_dofs", "int", "stop after the first mesh with this many dofs"
        ),
        "kappa": bound(
            AdaptOptions,
            "kappa",
            "str",
            "κ = h^exponent on adapted meshes: h the largest cell, each cell's own (local), or "
            "the smallest cell (finest)",
        ),
        "free_boundary": bound(
            AdaptOptions,
            "free_boundary",
            "bool",
            "also refine the cells the boundary of the contact set runs through",
        ),
    },
    "output": {
        "paraview": Key("bool", True, "write VTX (.bp) files for ParaView"),
        "figures": Key("bool", True, "write PNG figures"),
        "pictures": Key(
            "bool",
            True,
            "draw the 3D pictures: shell_3d.png of a solve (when figures are written), "
            "*_shell_3d.png of an experiment (PyVista, the extra shellobstacle[pictures]; "
            "skipped with one warning without it)",
        ),
    },
}

REQUIRED_SECTIONS = ("surface", "domain", "material", "load")
#: sections written as arrays of tables (``[[edge]]``), each table validated as a section
ARRAY_SECTIONS = ("edge",)
#: sections that switch a feature on by being present (absent: not in the resolved config)
OPTIONAL_SECTIONS = ("adapt",)
#: the key whose value decides which keys of a section are read (``Key.when``), and what to
#: say when a key is not read
SELECTORS: dict[str, tuple[str, str]] = {
    "surface": ("surface.kind", "does not use it"),
    "obstacle": ("obstacle.kind", "does not use it"),
    "domain": ("domain.kind", "does not use it"),
    "discretization": ("model.kind", "does not use it"),
    "penalty": ("solver.method", "solves the nodal constraint exactly (κ = 0)"),
    "solver": ("solver.method", "does not use it"),
}


def reference_text() -> str:
    """The configuration reference (Markdown), generated from :data:`SCHEMA`."""
    lines = ["# Configuration reference", ""]
    for section, keys in SCHEMA.items():
        req = " (required section)" if section in REQUIRED_SECTIONS else ""
        if section in OPTIONAL_SECTIONS:
            req = " (optional section: present, even empty, it switches the feature on)"
        title = f"[{section}]"
        if section in ARRAY_SECTIONS:
            title = f"[[{section}]]"
            req = (
                " (an array of tables, one per part of γ; facets no part selects are clamped; "
                "give `where` or `tag`)"
            )
        lines += [
            f"## {title}{req}",
            "",
            "| key | type | default | meaning |",
            "|---|---|---|---|",
        ]
        for name, k in keys.items():
            meaning = ("/".join(k.when) + ": " if k.when else "") + k.help
            meaning += f" (one of {', '.join(k.choices)})" if k.choices else ""
            lines.append(f"| `{name}` | {k.type} | {_default_text(k.default)} | {meaning} |")
        lines.append("")
    return "\n".join(lines)


def _default_text(default: Any) -> str:
    """A default as the reference shows it; one that depends on the selector as the most
    common value followed by the others, e.g. ``100 (active-set: 200)``."""
    if default is REQUIRED:
        return "required"
    if default is None:
        return "—"
    if not isinstance(default, ByValue):
        return repr(default)
    values = list(default.values())
    common = max(values, key=values.count)
    others = ", ".join(f"{m}: {v!r}" for m, v in default.items() if v != common)
    return f"{common!r} ({others})"
