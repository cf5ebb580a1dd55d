"""The configuration's schema: every section and key, its type, default and meaning.

:mod:`shellobstacle.config.loader` validates against it and ``shellobstacle config-reference``
prints it (:func:`reference_text`), so the documentation cannot drift from the loader. The defaults
and choices of the keys that set a field of the API's dataclasses (``NewtonOptions``,
``Discretization``, ``DomainSpec``, ...) are read from those fields (:func:`bound`), so that
the command line and the Python API cannot drift either; a ``[solver]`` key sets a field of
the options of every method in :data:`SOLVER_FIELDS`, and its default is that method's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.geometry.surface import SURFACE_KINDS
from shellobstacle.mesh.domains import KINDS, DomainSpec
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.options import (
    PETSC_OPTIONS_HELP,
)
from shellobstacle.solvers.registry import METHODS, method_help
from shellobstacle.spec import (
    Discretization,
    Load,
    Obstacle,
    Shell,
)

__all__ = [
    "METHOD_OPTIONS",
    "OPTIONAL",
    "OPTIONAL_SECTIONS",
    "REQUIRED",
    "REQUIRED_SECTIONS",
    "SCHEMA",
    "SELECTORS",
    "SOLVER_FIELDS",
    "ByValue",
    "Key",
    "bound",
    "reference_text",
]

REQUIRED = object()
OPTIONAL = None


class ByValue(dict):
    """A default that depends on the section's selector (:data:`SELECTORS`): value → default."""


@dataclass(frozen=True)
class Key:
    """One configuration key: its type, default (``REQUIRED`` if none, a :class:`ByValue` if
    it depends on the selector) and meaning; ``when``: the values of its section's selector
    (:data:`SELECTORS`) that use it, empty for every value."""

    type: str  # "float", "int", "str", "bool", "float[n]", "str|float[3]", "table", "points",
    # "options" (a table of PETSc options)
    default: Any
    help: str
    choices: Collection[str] = ()  # a live view for solver.method (the registry's names)
    when: tuple[str, ...] = ()
    #: the dataclass fields the key sets: (class, field name) per selector value, or ("", ...)
    fields: Mapping[str, tuple[type, str]] = field(default_factory=dict)

    def default_for(self, selector: Any) -> Any:
        """The default when the section's selector is ``selector``."""
        if isinstance(self.default, ByValue):
            return self.default.get(selector)
        return self.default

    def used_by(self, selector: Any) -> bool:
        """Whether the key is read when the section's selector is ``selector``."""
        return not self.when or selector in self.when


def _default(owner: type, name: str) -> Any:
    """The default of the field ``owner.name`` (``REQUIRED`` if it has none)."""
    f = {f.name: f for f in dataclasses.fields(owner)}[name]
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return REQUIRED


def bound(
    owner: type,
    name: str,
    type: str,
    help: str,
    *,
    choices: tuple[str, ...] | None = None,
    when: tuple[str, ...] = (),
) -> Key:
    """The key that sets the field ``owner.name``: its default and (unless narrowed by
    ``choices``) its choices are the field's."""
    f = {f.name: f for f in dataclasses.fields(owner)}[name]
    found = tuple(f.metadata.get("choices", ()))
    return Key(type, _default(owner, name), help, found if choices is None else choices, when,
               {"": (owner, name)})  # fmt: skip


class _MethodOptions(Mapping[str, type]):
    """``solver.method`` → its options class, read from the registry (a live view: a method
    registered later is in it; a method that takes no options is not)."""

    def __getitem__(self, name: str) -> type:
        cls = METHODS[name].options_type
        if cls is None:
            raise KeyError(name)
        return cls

    def __iter__(self) -> Iterator[str]:
        return (name for name, m in METHODS.items() if m.options_type is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


#: the options class of each ``solver.method``
METHOD_OPTIONS: Mapping[str, type] = _MethodOptions()
_ALL = tuple(METHOD_OPTIONS)
#: ``[solver]`` key → the field it sets in the options of each method that reads it
SOLVER_FIELDS: dict[str, dict[str, str]] = {
    "linear_solver": {"newton": "linear_solver"},
    "factorization": dict.fromkeys(("newton", "snes-vi", "proximal-galerkin"), "factorization"),
    "contact_zone": {"newton": "contact_zone"},
    "rtol": {"newton": "rtol", "snes-vi": "rtol", "proximal-galerkin": "newton_rtol"},
    "stol": {"newton": "stol", "snes-vi": "stol"},
    "max_iterations": dict.fromkeys(
        ("newton", "active-set", "snes-vi", "proximal-galerkin"), "max_iterations"
    ),
    "xi": {"brezis-sibony": "xi"},
    "mass": {"brezis-sibony": "mass"},
    "start": {"brezis-sibony": "start"},
    "bs_max_iterations": {"brezis-sibony": "max_iterations"},
    "bs_rtol": {"brezis-sibony": "rtol"},
    "vi_type": {"snes-vi": "vi_type"},
    "vi_line_search": {"snes-vi": "line_search"},
    "proximal_tol": {"proximal-galerkin": "tol"},
    "proximal_alpha_max": {"proximal-galerkin": "alpha_max"},
    "petsc_options": dict.fromkeys(_ALL, "petsc_options"),
}


def _solver(name: str, type: str, help: str, choices: tuple[str, ...] | None = None) -> Key:
    """The ``[solver]`` key ``name``: the default of each method that reads it is the field's
    of that method's options (:data:`SOLVER_FIELDS`)."""
    fields = {m: (METHOD_OPTIONS[m], f) for m, f in SOLVER_FIELDS[name].items()}
    defaults = ByValue({m: _default(cls, f) for m, (cls, f) in fields.items()})
    values = list(defaults.values())
    default = values[0] if all(v == values[0] for v in values) else defaults
    if choices is None:
        found = [
            {f.name: f for f in dataclasses.fields(cls)}[f].metadata.get("choices", ())
            for cls, f in fields.values()
        ]
        choices = tuple(found[0])
    when = () if set(fields) == set(_ALL) else tuple(fields)
    return Key(type, default, help, choices, when, fields)


_PENALIZED = ("newton", "brezis-sibony")

SCHEMA: dict[str, dict[str, Key]] = {
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
    },
    "obstacle": {
        "q": bound(Obstacle, "q", "float[3]", "normal of the plane; H = {x·q ≥ 0}"),
    },
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
    "solver": {
        "method": Key("str", "newton", method_help(), METHODS.keys()),
        "linear_solver": _solver(
            "linear_solver",
            "str",
            "MUMPS, or inexact Newton with flexible CG and a field split (GAMG on ζ_α): "
            "about 70 % of the memory",
        ),
        "factorization": _solver(
            "factorization",
            "str",
            "direct solver: Cholesky (symmetric positive definite; half the memory of LU), or LU",
        ),
        "contact_zone": _solver(
            "contact_zone",
            "bool",
            "direct solver: condense each Newton step onto the contact zone (K factorized once "
            "per zone, kept across κ); false: one factorization per κ reused by CG",
        ),
        "rtol": _solver("rtol", "float", "relative residual tolerance"),
        "stol": _solver("stol", "float", "relative Newton-correction tolerance"),
        "max_iterations": _solver(
            "max_iterations",
            "int",
            "Newton iterations per κ; active-set: linear solves; snes-vi: PETSc's Newton "
            "steps; proximal-galerkin: proximal steps",
        ),
        "xi": _solver("xi", "float", "Ξ of (38); default: from a λ_max estimate"),
        "mass": _solver("mass", "str", "mass matrix"),
        "start": _solver("start", "str", "ψ_0", choices=("zero", "linearized")),
        "bs_max_iterations": _solver("bs_max_iterations", "int", "iteration cap"),
        "bs_rtol": _solver("bs_rtol", "float", "relative L² increment tolerance"),
        "vi_type": _solver(
            "vi_type",
            "str",
            "PETSc's reduced-space (rsls) or semismooth Fischer–Burmeister (ssls) Newton",
        ),
        "vi_line_search": _solver(
            "vi_line_search",
            "str",
            "PETSc's line search (l2: secant on ‖F‖²; bt, PETSc's default: backtracking, which "
            "stalls on Koiter's cylinder_koiter.toml; basic: full steps)",
        ),
        "proximal_tol": _solver(
            "proximal_tol",
            "float",
            "stop at a relative increment ‖u_k − u_(k−1)‖/‖u_k‖ below this",
        ),
        "proximal_alpha_max": _solver(
            "proximal_alpha_max", "float", "cap of the (dimensionless) proximal parameter α̂"
        ),
        "petsc_options": _solver("petsc_options", "options", PETSC_OPTIONS_HELP),
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
#: sections that switch a feature on by being present (absent: not in the resolved config)
OPTIONAL_SECTIONS = ("adapt",)
#: the key whose value decides which keys of a section are read (``Key.when``), and what to
#: say when a key is not read
SELECTORS: dict[str, tuple[str, str]] = {
    "surface": ("surface.kind", "does not use it"),
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
        lines += [
            f"## [{section}]{req}",
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
