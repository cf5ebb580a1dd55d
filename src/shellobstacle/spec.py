"""The data of a shell obstacle problem (docs/model.md §2–5): the physical shell (surface,
material, load, obstacle) and the discretization (the penalty's data:
:class:`~shellobstacle.penalty.spec.PenaltySpec`).

These small frozen dataclasses are the Python API that mirrors the config file; they
validate at construction exactly as the config does, with its messages, and know nothing about
meshes. :func:`finite`, :func:`integer` and :func:`boolean`
(:mod:`shellobstacle.messages`) check a single value for both: the config loader checks every
number and flag of a file with them.
"""

from __future__ import annotations

import functools
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import sympy as sp

from shellobstacle.geometry.expressions import is_safe_name, parse, y1, y2
from shellobstacle.geometry.surface import Surface
from shellobstacle.messages import boolean, finite, integer, not_one_of
from shellobstacle.obstacle.shapes import CONTACT_FACES, SHAPES, checked, declared

__all__ = [
    "BENDING_FORMS",
    "EDGE_CONDITIONS",
    "MODELS",
    "PENALTY_QUADRATURES",
    "TRANSVERSE",
    "Discretization",
    "Edge",
    "Load",
    "Material",
    "Obstacle",
    "Shell",
    "boolean",
    "finite",
    "integer",
]


@dataclass(frozen=True)
class Material:
    """Half-thickness ``ε > 0`` and Lamé constants ``λ ≥ 0``, ``μ > 0``."""

    epsilon: float
    lam: float
    mu: float

    def __post_init__(self) -> None:
        for name, key in (("epsilon", "epsilon"), ("lam", "lambda"), ("mu", "mu")):
            object.__setattr__(self, name, finite(getattr(self, name), f"material.{key}"))
        if not self.epsilon > 0:
            raise ValueError(f"material.epsilon must be > 0 (half-thickness), got {self.epsilon}")
        if not self.lam >= 0:
            raise ValueError(f"material.lambda must be >= 0 (Lamé constant), got {self.lam}")
        if not self.mu > 0:
            raise ValueError(f"material.mu must be > 0 (Lamé constant), got {self.mu}")

    @property
    def symbols(self) -> dict[str, float]:
        """Names under which load expressions see the material constants."""
        return {"epsilon": self.epsilon, "lambda": self.lam, "mu": self.mu}


@dataclass(frozen=True)
class Load:
    """Contravariant force density ``p^{i,ε}(y)`` as three SymPy-syntax expressions.

    Expressions may use ``y1, y2, r = √(y1² + y2²)``, the material constants by
    name (``epsilon``, ``lambda``, ``mu``) and the names in ``parameters``, which
    become ``dolfinx.fem.Constant`` objects so a sweep over them reuses one compiled
    problem.
    """

    p: tuple[str, str, str]
    parameters: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.p, str) or len(self.p) != 3:
            raise ValueError(f"load.p needs three components (p^1, p^2, p^3), got {self.p!r}")
        object.__setattr__(self, "p", tuple(_component(v, i) for i, v in enumerate(self.p)))
        for name in self.parameters:
            if not is_safe_name(name) or name in ("y1", "y2", "r", "epsilon", "lambda", "mu"):
                raise ValueError(f"load.parameters: {name!r} cannot be used as a parameter name")
        for name, value in self.parameters.items():
            finite(value, f"load.parameters.{name}")

    def expressions(self, material: Material) -> tuple[sp.Expr, sp.Expr, sp.Expr]:
        """The three components as SymPy expressions in ``y1, y2`` and the parameter symbols."""
        return _parse_load(tuple(self.p), tuple(sorted(self.parameters)), material)

    @staticmethod
    def uniform_normal_pressure(p: float) -> Load:
        """``p^{i,ε} = (0, 0, p)``: a pressure along ``a^3``."""
        return Load(("0", "0", repr(float(p))))


def _component(value: Any, i: int) -> str:
    """A component of ``load.p``: a string expression, or a number as its ``repr``."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"load.p[{i + 1}] must be a string expression, got {value!r}")
    return repr(finite(value, f"load.p[{i + 1}]"))


@functools.lru_cache(maxsize=32)
def _parse_load(
    p: tuple[str, ...], parameters: tuple[str, ...], material: Material
) -> tuple[sp.Expr, sp.Expr, sp.Expr]:
    """Parse the load once per (strings, parameter names, material): long strings are slow."""
    names: dict[str, Any] = {"y1": y1, "y2": y2, "r": sp.sqrt(y1**2 + y2**2)}
    names |= {k: sp.Float(v) for k, v in material.symbols.items()}
    names |= {k: sp.Symbol(k, real=True) for k in parameters}
    return tuple(parse(t, names, f"load.p[{i + 1}]") for i, t in enumerate(p))  # type: ignore[return-value]


@dataclass(frozen=True, init=False)
class Obstacle:
    """The rigid obstacle: the admissible set ``{x : g(x) ≥ 0}`` of the contact face
    (docs/model.md :eq:`gap`; :mod:`shellobstacle.obstacle` computes with it).

    ``kind`` names a shape of :data:`~shellobstacle.obstacle.shapes.SHAPES` (by default
    ``plane``, the paper's half-space) and the keywords give its parameters, which its
    declaration checks (:func:`~shellobstacle.obstacle.shapes.checked`) and which read as
    attributes: ``Obstacle(kind="sphere", center=(0, 0, -2), radius=2).radius``. The plane's
    normal may come first, ``Obstacle(q)``. A key of another shape reads as that shape's
    default; given another value, it is refused, as the config refuses it.

    ``contact_face``: the surface that must stay admissible, ``θ + η`` (``"middle"``) or the
    face ``θ ∓ ε a_3 + η`` (``"lower"``/``"upper"``).

    Attributes:
        kind: the shape.
        parameters: its parameters by name, checked, with their defaults.
        contact_face: the face that must stay admissible.
    """

    kind: str = field(default="plane", metadata={"choices": SHAPES.keys()})
    parameters: Mapping[str, Any] = field(default_factory=dict)
    contact_face: str = field(default="middle", metadata={"choices": CONTACT_FACES})

    def __init__(
        self,
        q: Any = None,
        kind: str = "plane",
        contact_face: str = "middle",
        parameters: Mapping[str, Any] | None = None,
        **given: Any,
    ) -> None:
        given = {**(parameters or {}), **given, **({} if q is None else {"q": q})}
        for name in given:
            if not declared(name):
                raise TypeError(f"Obstacle() got an unexpected keyword argument {name!r}")
        values = checked(kind, given)
        if contact_face not in CONTACT_FACES:
            raise ValueError(not_one_of("obstacle.contact_face", contact_face, CONTACT_FACES))
        object.__setattr__(self, "kind", kind)
        object.__setattr__(self, "parameters", values)
        object.__setattr__(self, "contact_face", contact_face)

    def __getattr__(self, name: str) -> Any:
        """A parameter: this shape's value, another shape's default (None if it has none)."""
        found = declared(name) if not name.startswith("_") and name != "parameters" else []
        if not found:
            raise AttributeError(f"'Obstacle' object has no attribute {name!r}")
        return self.parameters.get(name, found[0][1].default)

    def __hash__(self) -> int:
        return hash((self.kind, tuple(sorted(self.parameters.items())), self.contact_face))

    def __repr__(self) -> str:
        given = "".join(f", {k}={v!r}" for k, v in self.parameters.items())
        return f"Obstacle(kind={self.kind!r}{given}, contact_face={self.contact_face!r})"

    def keys(self) -> tuple[str, ...]:
        """The ``[obstacle]`` keys this kind reads."""
        return ("kind", *self.parameters, "contact_face")


EDGE_CONDITIONS = ("clamped", "simply-supported", "free", "symmetry")


@dataclass(frozen=True)
class Edge:
    """A part of the boundary γ and its condition (docs/model.md §9;
    :mod:`~shellobstacle.models.edges` finds its facets on a mesh).

    The part is the boundary facets whose midpoint satisfies ``where``, a condition in
    ``y1, y2, r`` in SymPy syntax (``"y1 < -0.499"``, ``"And(y1 > 0, y2 > 0)"``), or the facets
    of the gmsh physical curve ``tag`` of a ``domain.kind = "file"`` mesh. ``condition``:
    ``"clamped"`` (ζ = 0 and ∂_ν ζ_3 = 0), ``"simply-supported"`` (ζ = 0), ``"free"`` (nothing)
    or ``"symmetry"`` (on a line y_α = c about which θ is symmetric: ζ_α = 0 and
    ∂_ν ζ_3 = 0). Facets that no edge selects are clamped.
    """

    condition: str = field(metadata={"choices": EDGE_CONDITIONS})
    where: str | None = None
    tag: int | None = None

    def __post_init__(self) -> None:
        if self.condition not in EDGE_CONDITIONS:
            raise ValueError(not_one_of("edge.condition", self.condition, EDGE_CONDITIONS))
        if (self.where is None) == (self.tag is None):
            raise ValueError(
                "an [[edge]] needs where = '<condition in y1, y2>' or tag = <gmsh physical "
                f"curve>, exactly one of them; got where = {self.where!r}, tag = {self.tag!r}"
            )
        if self.tag is not None:
            integer(self.tag, "edge.tag")
            if self.tag < 1:
                raise ValueError(f"edge.tag must be a gmsh physical tag >= 1, got {self.tag}")
        if self.where is not None:
            self.predicate()

    def predicate(self) -> sp.Expr:
        """``where`` as a SymPy expression in ``y1, y2``: 1 where it holds, else 0."""
        return _parse_where(self.where)

    def __str__(self) -> str:
        part = f"where = {self.where!r}" if self.where is not None else f"tag = {self.tag}"
        return f"[[edge]] {part} ({self.condition})"


@functools.lru_cache(maxsize=32)
def _parse_where(text: str) -> sp.Expr:
    """Parse a condition with the expressions' parser, as the indicator
    ``Piecewise((1, condition), (0, True))``; its errors quote ``text``."""
    names = {"y1": y1, "y2": y2, "r": sp.sqrt(y1**2 + y2**2)}
    wrapped = f"Piecewise((1, {text}), (0, True))" if isinstance(text, str) else text
    try:
        return parse(wrapped, names, "edge.where")
    except ValueError as err:
        if "must be a Boolean" in str(err):
            raise ValueError(
                f"edge.where must be a condition on the facet's midpoint such as "
                f"'y1 < -0.499', got {text!r}"
            ) from None
        raise type(err)(str(err).replace(repr(wrapped), repr(text))) from None


MODELS = ("membrane", "koiter")
KINEMATICS = ("linear", "nonlinear")


@dataclass(frozen=True)
class Shell:
    """Everything physical: the middle surface, the material, the load, the obstacle, the
    shell model: ``"membrane"`` (docs/model.md §2–4, elliptic surfaces) or ``"koiter"`` (§8, the
    membrane energy plus bending; any immersed thin shell), and the conditions on parts of γ
    (:class:`Edge`; γ is clamped where none is given). The edges are the shell's, not the
    discretization's: which edges are supported is part of the physical problem, as the load
    is, and a mesh only locates them. ``kinematics``: ``"linear"`` (the strains linear in ζ)
    or ``"nonlinear"`` (Koiter's model only: the strains of the deformed surface, §11)."""

    surface: Surface
    material: Material
    load: Load
    obstacle: Obstacle = field(default_factory=Obstacle)
    model: str = field(default="membrane", metadata={"choices": MODELS})
    edges: tuple[Edge, ...] = ()
    kinematics: str = field(default="linear", metadata={"choices": KINEMATICS})

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(not_one_of("model.kind", self.model, MODELS))
        if self.kinematics not in KINEMATICS:
            raise ValueError(not_one_of("model.kinematics", self.kinematics, KINEMATICS))
        if self.kinematics == "nonlinear" and self.model != "koiter":
            raise ValueError(
                "model.kinematics = 'nonlinear' is Koiter's model (a membrane has no bending "
                "stiffness in compression): set model.kind = 'koiter' or kinematics = 'linear'"
            )
        object.__setattr__(self, "edges", tuple(self.edges))
        for edge in self.edges:
            if not isinstance(edge, Edge):
                raise ValueError(f"Shell.edges holds Edge objects, got {edge!r}")
            if self.model == "membrane" and edge.condition != "clamped":
                raise ValueError(
                    f"{edge}: the membrane model needs ζ_α = 0 on all of γ (its energy controls "
                    "ζ_α in H¹₀ only): remove the edge or set model.kind = 'koiter'"
                )

    def load_expressions(self) -> tuple[sp.Expr, sp.Expr, sp.Expr]:
        """``p^{i,ε}`` as SymPy expressions (see :meth:`Load.expressions`)."""
        return self.load.expressions(self.material)


TRANSVERSE = ("clamped", "free")
PENALTY_QUADRATURES = ("gauss", "vertex")
BENDING_FORMS = ("hybrid", "c0ip")


@dataclass(frozen=True)
class Discretization:
    """Finite-element choices (docs/model.md §5).

    Attributes:
        degree: Lagrange degree of all three components (1 or 2).
        transverse: ``"clamped"`` (ζ_3 = 0 on γ, the paper's numerics) or ``"free"`` (ζ_3 ∈ L²).
        penalty_quadrature: ``"gauss"`` (the paper's) or ``"vertex"`` (nodal, mass-lumped; P1).
        quadrature_degree: for the membrane and load integrals (default ``2 * degree + 2``).
        interior_penalty: ``σ`` of the facet terms of Koiter's bending energy (default
            :data:`~shellobstacle.models.hybrid_bending.DEFAULT_HYBRID_PENALTY` or
            :data:`~shellobstacle.models.koiter.DEFAULT_INTERIOR_PENALTY`); unused by the membrane.
        bending: Koiter's bending form, ``"hybrid"`` (a multiplier per facet,
            :mod:`~shellobstacle.models.hybrid_bending`) or ``"c0ip"`` (the C⁰ interior penalty,
            :mod:`~shellobstacle.models.koiter`); unused by the membrane.
    """

    degree: int = 1
    transverse: str = field(default="clamped", metadata={"choices": TRANSVERSE})
    penalty_quadrature: str = field(default="gauss", metadata={"choices": PENALTY_QUADRATURES})
    quadrature_degree: int | None = None
    interior_penalty: float | None = None
    bending: str = field(default="hybrid", metadata={"choices": BENDING_FORMS})

    def __post_init__(self) -> None:
        integer(self.degree, "discretization.degree")
        if self.quadrature_degree is not None:
            integer(self.quadrature_degree, "discretization.quadrature_degree")
        if self.interior_penalty is not None:
            value = finite(self.interior_penalty, "discretization.interior_penalty")
            object.__setattr__(self, "interior_penalty", value)
        if self.degree not in (1, 2):
            raise ValueError(f"discretization.degree must be 1 or 2, got {self.degree}")
        if self.transverse not in TRANSVERSE:
            raise ValueError(not_one_of("discretization.transverse", self.transverse, TRANSVERSE))
        if self.penalty_quadrature not in PENALTY_QUADRATURES:
            key, value = "discretization.penalty_quadrature", self.penalty_quadrature
            raise ValueError(not_one_of(key, value, PENALTY_QUADRATURES))
        if self.penalty_quadrature == "vertex" and self.degree != 1:
            raise ValueError(
                "discretization.penalty_quadrature = 'vertex' is the nodal constraint of P1; "
                "use degree = 1, or penalty_quadrature = 'gauss' with degree = 2"
            )
        if self.quadrature_degree is not None and not 1 <= self.quadrature_degree <= 20:
            raise ValueError(
                f"discretization.quadrature_degree must be in 1..20, got {self.quadrature_degree}"
            )
        if self.bending not in BENDING_FORMS:
            raise ValueError(not_one_of("discretization.bending", self.bending, BENDING_FORMS))
        if self.interior_penalty is not None and not self.interior_penalty > 0:
            raise ValueError(
                f"discretization.interior_penalty must be > 0, got {self.interior_penalty}"
            )

    @property
    def qdegree(self) -> int:
        """Quadrature degree actually used for the membrane and load integrals."""
        return self.quadrature_degree or 2 * self.degree + 2

    @property
    def bending_qdegree(self) -> int:
        """Quadrature degree of the hybrid bending form's cell integrals (``2 · degree``
        unless ``quadrature_degree`` is given)."""
        return self.quadrature_degree or 2 * self.degree
