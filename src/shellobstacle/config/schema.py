"""The configuration's schema: every section and key, its type, default and meaning.

The single source of truth: :mod:`shellobstacle.config.loader` validates against it and
``shellobstacle config-reference`` prints it (:func:`reference_text`), so the documentation
cannot drift from the loader.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

from shellobstacle.adapt.options import KAPPA_MODES
from shellobstacle.geometry.surface import SURFACE_KINDS
from shellobstacle.solvers.options import VI_LINE_SEARCHES, VI_TYPES
from shellobstacle.solvers.registry import METHODS, method_help
from shellobstacle.spec import BENDING_FORMS, MODELS, PENALTY_QUADRATURES, TRANSVERSE

__all__ = [
    "OPTIONAL",
    "OPTIONAL_SECTIONS",
    "REQUIRED",
    "REQUIRED_SECTIONS",
    "SCHEMA",
    "Key",
    "reference_text",
]


@dataclass(frozen=True)
class Key:
    """One configuration key: its type, default (``REQUIRED`` if none) and meaning."""

    type: str  # "float", "int", "str", "bool", "float[n]", "str|float[3]", "table", "points"
    default: Any
    help: str
    choices: Collection[str] = ()  # a live view for solver.method (the registry's names)


REQUIRED = object()
OPTIONAL = None

SCHEMA: dict[str, dict[str, Key]] = {
    "surface": {
        "kind": Key("str", REQUIRED, "built-in surface or 'expression'", SURFACE_KINDS),
        "radius": Key("float", OPTIONAL, "spherical_cap: sphere radius R"),
        "offset": Key("float", OPTIONAL, "spherical_cap/ellipsoid_cap: downward shift of θ_3"),
        "semi_axes": Key("float[3]", OPTIONAL, "ellipsoid_cap: semi-axes (A, B, C)"),
        "height": Key("float", OPTIONAL, "elliptic_paraboloid: apex height"),
        "curvatures": Key("float[2]", OPTIONAL, "elliptic_paraboloid: apex curvatures (k1, k2)"),
        "theta": Key("str[3]", OPTIONAL, "expression: θ(y1, y2) as three SymPy strings"),
    },
    "domain": {
        "kind": Key(
            "str", REQUIRED, "shape of ω", ("disk", "ellipse", "polygon", "rectangle", "file")
        ),
        "h": Key("float", OPTIONAL, "target mesh size (gmsh); the h obtained is reported"),
        "radius": Key("float", 0.5, "disk: radius"),
        "center": Key("float[2]", (0.0, 0.0), "disk/ellipse: centre"),
        "semi_axes": Key("float[2]", OPTIONAL, "ellipse: semi-axes"),
        "vertices": Key("points", OPTIONAL, "polygon: list of [y1, y2] vertices"),
        "corners": Key("points", OPTIONAL, "rectangle: [[y1_min, y2_min], [y1_max, y2_max]]"),
        "path": Key(
            "str",
            OPTIONAL,
            "file: a gmsh .msh file of triangles (relative to the config; a result folder's "
            "config.toml holds it absolute)",
        ),
        "refinements": Key("int", 0, "uniform refinements after meshing (nested meshes)"),
        "central_h": Key("float", OPTIONAL, "disk/ellipse: finer mesh size near the centre"),
        "central_radius": Key("float", OPTIONAL, "disk/ellipse: radius of the finer region"),
        "edge_h": Key("float", OPTIONAL, "disk/ellipse/polygon: finer mesh size along γ"),
        "edge_width": Key("float", OPTIONAL, "disk/ellipse/polygon: width of the finer band"),
        "gmsh_max_vertices": Key(
            "int", 8_000, "above this, gmsh meshes coarser and the mesh is refined (0: never)"
        ),
    },
    "material": {
        "epsilon": Key("float", REQUIRED, "half-thickness ε > 0"),
        "lambda": Key("float", REQUIRED, "Lamé constant λ ≥ 0"),
        "mu": Key("float", REQUIRED, "Lamé constant μ > 0"),
    },
    "load": {
        "p": Key("str|float[3]", REQUIRED, "contravariant force density p^i(y1, y2, r)"),
        "parameters": Key("table", {}, "named numbers the load may use (sweepable)"),
    },
    "model": {
        "kind": Key(
            "str",
            "membrane",
            "membrane: the paper's model (elliptic surfaces); koiter: membrane + bending, any "
            "immersed thin shell (P2, C⁰ interior penalty for ζ_3)",
            MODELS,
        ),
    },
    "obstacle": {
        "q": Key("float[3]", (0.0, 0.0, 1.0), "normal of the plane; H = {x·q ≥ 0}"),
    },
    "penalty": {
        "kappa": Key("float", OPTIONAL, "penalty parameter κ > 0"),
        "exponent": Key("float", OPTIONAL, "κ = h^exponent (the paper's coupling)"),
        "continuation": Key("bool", True, "reach κ through a ladder of larger κ (warm starts)"),
    },
    "discretization": {
        "degree": Key("int", 1, "Lagrange degree of all components (1 or 2; Koiter: 2)"),
        "transverse": Key("str", "clamped", "boundary condition of ζ_3", TRANSVERSE),
        "penalty_quadrature": Key(
            "str", "gauss", "where the penalty is integrated", PENALTY_QUADRATURES
        ),
        "quadrature_degree": Key("int", OPTIONAL, "quadrature degree (default 2·degree + 2)"),
        "interior_penalty": Key(
            "float", OPTIONAL, "koiter: σ of the facet penalty of ∂_n ζ_3 (default 16; c0ip: 8)"
        ),
        "bending": Key(
            "str",
            "hybrid",
            "koiter: the bending form, hybrid (a multiplier per facet) or c0ip (C⁰ interior "
            "penalty)",
            BENDING_FORMS,
        ),
    },
    "solver": {
        "method": Key("str", "newton", method_help(), METHODS.keys()),
        "linear_solver": Key(
            "str",
            "direct",
            "MUMPS, or inexact Newton with flexible CG and a field split (GAMG on ζ_α): "
            "about 70 % of the memory",
            ("direct", "iterative"),
        ),
        "factorization": Key(
            "str",
            "cholesky",
            "direct solver: Cholesky (symmetric positive definite; half the memory of LU), or LU",
            ("cholesky", "lu"),
        ),
        "contact_zone": Key(
            "bool",
            True,
            "direct solver: condense each Newton step onto the contact zone (K factorized once "
            "per zone, kept across κ); false: one factorization per κ reused by CG",
        ),
        "rtol": Key("float", 1e-10, "relative residual tolerance"),
        "stol": Key("float", 1e-12, "relative Newton-correction tolerance"),
        "max_iterations": Key(
            "int",
            100,
            "Newton iterations per κ; active-set: linear solves; snes-vi: PETSc's Newton "
            "steps; proximal-galerkin: proximal steps",
        ),
        "xi": Key("float", OPTIONAL, "brezis-sibony: Ξ of (38); default: from a λ_max estimate"),
        "mass": Key("str", "consistent", "brezis-sibony: mass matrix", ("consistent", "lumped")),
        "start": Key("str", "linearized", "brezis-sibony: ψ_0", ("zero", "linearized")),
        "bs_max_iterations": Key("int", 200000, "brezis-sibony: iteration cap"),
        "bs_rtol": Key("float", 1e-9, "brezis-sibony: relative L² increment tolerance"),
        "vi_type": Key(
            "str",
            "rsls",
            "snes-vi: PETSc's reduced-space (rsls) or semismooth Fischer–Burmeister (ssls) Newton",
            VI_TYPES,
        ),
        "vi_line_search": Key(
            "str",
            "l2",
            "snes-vi: PETSc's line search (l2: secant on ‖F‖²; bt, PETSc's default: "
            "backtracking, which stalls on Koiter's cylinder_koiter.toml; basic: full steps)",
            VI_LINE_SEARCHES,
        ),
        "proximal_tol": Key(
            "float",
            1e-9,
            "proximal-galerkin: stop at a relative increment ‖u_k − u_(k−1)‖/‖u_k‖ below this",
        ),
        "proximal_alpha_max": Key(
            "float", 1e5, "proximal-galerkin: cap of the (dimensionless) proximal parameter α̂"
        ),
    },
    "adapt": {
        "fraction": Key("float", 0.5, "Dörfler's θ: the marked cells hold this share of Σ η_T²"),
        "max_levels": Key("int", 10, "the most refinements (max_levels + 1 meshes solved)"),
        "target_error": Key("float", OPTIONAL, "stop once the estimate η is at most this"),
        "target_dofs": Key("int", OPTIONAL, "stop after the first mesh with this many dofs"),
        "kappa": Key(
            "str",
            "largest",
            "κ = h^exponent on adapted meshes: h the largest cell, each cell's own (local), or "
            "the smallest cell (finest)",
            KAPPA_MODES,
        ),
        "free_boundary": Key(
            "bool", False, "also refine the cells the boundary of the contact set runs through"
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
            default = (
                "required"
                if k.default is REQUIRED
                else ("—" if k.default is None else repr(k.default))
            )
            meaning = k.help + (f" (one of {', '.join(k.choices)})" if k.choices else "")
            lines.append(f"| `{name}` | {k.type} | {default} | {meaning} |")
        lines.append("")
    return "\n".join(lines)
