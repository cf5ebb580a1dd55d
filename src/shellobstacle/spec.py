"""The data of a shell obstacle problem (docs/model.md §2–5): the physical shell (surface,
material, load, obstacle) and the discretization (the penalty's data:
:class:`~shellobstacle.penalty.spec.PenaltySpec`).

These small frozen dataclasses are the Python API that mirrors the config file; they
validate at construction exactly as the config does, with its messages, and know nothing about
meshes. :func:`finite`, :func:`integer` and :func:`boolean` check a single value for both: the
config loader checks every number and flag of a file with them.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import sympy as sp

from shellobstacle.geometry.expressions import is_safe_name, parse, y1, y2
from shellobstacle.geometry.surface import Surface
from shellobstacle.messages import not_one_of

__all__ = [
    "BENDING_FORMS",
    "MODELS",
    "OBSTACLE_KINDS",
    "PENALTY_QUADRATURES",
    "TRANSVERSE",
    "Discretization",
    "Load",
    "Material",
    "Obstacle",
    "Shell",
    "boolean",
    "finite",
    "integer",
    "obstacle_kinds_reading",
    "require_obstacle_keys",
]


def finite(value: Any, what: str) -> float:
    """``value`` as a float if it is a finite number (not a bool), else a ValueError naming
    ``what``: the check of every number of the config and of the dataclasses below."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{what} must be a number, got {value!r}")
    try:
        out = float(value)
    except OverflowError:
        raise ValueError(f"{what} is too large to be a floating-point number") from None
    if not math.isfinite(out):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return out


def boolean(value: Any, what: str) -> bool:
    """``value`` if it is true or false, else a ValueError naming ``what``."""
    if not isinstance(value, bool):
        raise ValueError(f"{what} must be true or false, got {value!r}")
    return value


def integer(value: Any, what: str) -> int:
    """``value`` if it is an integer (not a bool), else a ValueError naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{what} must be an integer, got {value!r}")
    return int(value)


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


OBSTACLE_KINDS = ("plane", "sphere", "cylinder", "expression")
SIDES = ("outside", "inside")
CONTACT_FACES = ("middle", "lower", "upper")

#: the keys of ``[obstacle]`` that each kind reads (besides ``kind`` and ``contact_face``):
#: the one statement of it, which the config's schema and :class:`Obstacle` read
OBSTACLE_KEYS = {
    "plane": ("q", "c"),
    "sphere": ("center", "radius", "side"),
    "cylinder": ("point", "axis", "radius", "side"),
    "expression": ("g",),
}


def obstacle_kinds_reading(name: str) -> tuple[str, ...]:
    """The obstacle kinds that read the ``[obstacle]`` key ``name`` (:data:`OBSTACLE_KEYS`)."""
    return tuple(kind for kind, keys in OBSTACLE_KEYS.items() if name in keys)


def require_obstacle_keys(kind: str, given: Iterable[str]) -> None:
    """A ValueError naming the first key of ``given`` that ``obstacle.kind = kind`` does not
    read, and the kinds that do; nothing if it reads them all."""
    for name in given:
        if name not in ("kind", "contact_face", *OBSTACLE_KEYS[kind]):
            kinds = " or ".join(map(repr, obstacle_kinds_reading(name)))
            raise ValueError(
                f"obstacle.{name} is not read by obstacle.kind = {kind!r}: set obstacle.kind = "
                f"{kinds}, or remove it"
            )


@dataclass(frozen=True)
class Obstacle:
    """The rigid obstacle: the admissible set ``{x : g(x) ≥ 0}`` of the contact face
    (docs/model.md :eq:`gap`; :mod:`shellobstacle.obstacle` computes with it).

    - ``plane``: ``g(x) = x·q − c`` (the paper's half-space when ``c = 0``); ``q`` is
      normalized (with a warning if needed).
    - ``sphere``: ``g(x) = |x − center| − radius`` (``side = "outside"``: the shell stays out
      of the ball) or ``radius − |x − center|`` (``"inside"``).
    - ``cylinder``: the same with the distance to the axis through ``point`` along ``axis``.
    - ``expression``: ``g`` a formula in the ambient coordinates ``x1, x2, x3``.

    ``contact_face``: the surface that must stay admissible, ``θ + η`` (``"middle"``) or the
    face ``θ ∓ ε a_3 + η`` (``"lower"``/``"upper"``).

    A key the kind does not read (:data:`OBSTACLE_KEYS`) given a value other than its default
    is refused, as the config refuses it.
    """

    q: tuple[float, float, float] = (0.0, 0.0, 1.0)
    kind: str = field(default="plane", metadata={"choices": OBSTACLE_KINDS})
    c: float = 0.0
    center: tuple[float, float, float] | None = None
    radius: float | None = None
    side: str = field(default="outside", metadata={"choices": SIDES})
    point: tuple[float, float, float] | None = None
    axis: tuple[float, float, float] | None = None
    g: str | None = None
    contact_face: str = field(default="middle", metadata={"choices": CONTACT_FACES})

    def __post_init__(self) -> None:
        for name, value, choices in (
            ("kind", self.kind, OBSTACLE_KINDS),
            ("side", self.side, SIDES),
            ("contact_face", self.contact_face, CONTACT_FACES),
        ):
            if value not in choices:
                raise ValueError(not_one_of(f"obstacle.{name}", value, choices))
        require_obstacle_keys(self.kind, [f.name for f in _FIELDS if self._set(f.name, f.default)])
        needed = {"sphere": ("center", "radius"), "cylinder": ("point", "axis", "radius")}
        missing = [k for k in needed.get(self.kind, ()) if getattr(self, k) is None]
        if self.kind == "expression" and not self.g:
            missing.append("g")
        if missing:
            raise ValueError(
                f"obstacle.kind = {self.kind!r} needs obstacle.{', obstacle.'.join(missing)}"
            )
        object.__setattr__(self, "c", finite(self.c, "obstacle.c"))
        for name in ("center", "point"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _three(value, f"obstacle.{name}"))
        if self.radius is not None:
            object.__setattr__(self, "radius", finite(self.radius, "obstacle.radius"))
            if not self.radius > 0:
                raise ValueError(f"obstacle.radius must be > 0, got {self.radius!r}")
        if self.g is not None and not isinstance(self.g, str):
            raise ValueError(f"obstacle.g must be a string, got {self.g!r}")
        if self.axis is not None:
            object.__setattr__(self, "axis", _unit(self.axis, "obstacle.axis", "axis"))
        object.__setattr__(self, "q", _unit(self.q, "obstacle.q", "half-space"))

    def keys(self) -> tuple[str, ...]:
        """The ``[obstacle]`` keys this kind reads."""
        return ("kind", *OBSTACLE_KEYS[self.kind], "contact_face")

    def _set(self, name: str, default: Any) -> bool:
        """Whether the field ``name`` holds something other than its default."""
        value = getattr(self, name)
        if default is None:
            return value is not None
        if isinstance(default, tuple):
            same = _numeric(value) and np.shape(value) == np.shape(default)
            return not (same and np.array_equal(np.asarray(value, dtype=float), default))
        return bool(value != default)


#: the fields of :class:`Obstacle` that a kind may not read
_FIELDS = [f for f in dataclasses.fields(Obstacle) if f.name not in ("kind", "contact_face")]


def _three(value: Any, what: str) -> tuple[float, float, float]:
    """Three finite numbers (not bools), or a ValueError naming ``what``."""
    if isinstance(value, str) or not _numeric(value) or np.shape(value) != (3,):
        raise ValueError(f"{what} must be three finite numbers, got {value!r}")
    x, y, z = (finite(v, f"{what}[{i + 1}]") for i, v in enumerate(value))
    return (x, y, z)


def _numeric(value: Any) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def _unit(value: Any, what: str, noun: str) -> tuple[float, float, float]:
    """``value/|value|`` (a warning if ``|value| ≠ 1``), or a ValueError for a zero vector."""
    v = np.asarray(_three(value, what))
    largest = float(np.max(np.abs(v)))
    if largest == 0.0:
        vector = "normal" if noun == "half-space" else "direction"
        raise ValueError(f"{what} = (0, 0, 0) defines no {noun}: give a nonzero {vector}")
    norm = largest * float(np.linalg.norm(v / largest))  # no overflow for huge entries
    if abs(norm - 1.0) > 1e-12:
        warnings.warn(
            f"{what} = {tuple(value)} has norm {norm:.6g}; using it divided by its norm",
            stacklevel=4,
        )
    unit = (v / largest) / float(np.linalg.norm(v / largest))
    return (float(unit[0]), float(unit[1]), float(unit[2]))


MODELS = ("membrane", "koiter")


@dataclass(frozen=True)
class Shell:
    """Everything physical: the middle surface, the material, the load, the obstacle, and the
    shell model: ``"membrane"`` (docs/model.md §2–4, elliptic surfaces) or ``"koiter"`` (§8, the
    membrane energy plus bending; any immersed thin shell)."""

    surface: Surface
    material: Material
    load: Load
    obstacle: Obstacle = field(default_factory=Obstacle)
    model: str = field(default="membrane", metadata={"choices": MODELS})

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(not_one_of("model.kind", self.model, MODELS))

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
