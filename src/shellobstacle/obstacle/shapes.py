"""The shapes of obstacle, by kind: ``obstacle.kind`` in the config.

A shape is an :class:`~shellobstacle.obstacle.base.Obstacle` subclass that declares its
``kind``, a one-line ``summary`` and its ``parameters``
(:class:`~shellobstacle.obstacle.parameters.Parameter`); :data:`SHAPES` maps each kind to one.
Everything else reads the declarations: the Python API checks an obstacle's values with
:func:`checked` (:class:`~shellobstacle.spec.Obstacle`), the config's schema and reference list
the parameters (:mod:`shellobstacle.config.schema`), :func:`from_spec` builds the obstacle, a
picture's title is its :meth:`~shellobstacle.obstacle.base.Obstacle.describe` and the user
guide shows :func:`shape_table`. Adding a shape is one class and one :func:`register` call.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable, Mapping
from typing import Any, Protocol

from shellobstacle.messages import not_one_of
from shellobstacle.obstacle.base import Obstacle
from shellobstacle.obstacle.expression import ExpressionObstacle
from shellobstacle.obstacle.parameters import TYPES, Parameter
from shellobstacle.obstacle.plane import Plane
from shellobstacle.obstacle.quadrics import Cylinder, Sphere

__all__ = [
    "CONTACT_FACES",
    "FACE_SIGN",
    "SHAPES",
    "ObstacleData",
    "checked",
    "declared",
    "example",
    "from_spec",
    "register",
    "require_read",
    "shape_help",
    "shape_table",
]

#: every shape, by kind (the order of the config reference and the user guide's table)
SHAPES: dict[str, type[Obstacle]] = {}

FACE_SIGN = {"middle": 0.0, "lower": -1.0, "upper": 1.0}
"""The contact face ``θ + s a_3``: ``s = FACE_SIGN[contact_face] · ε``."""
CONTACT_FACES = tuple(FACE_SIGN)
#: the keys of ``[obstacle]`` that no shape may declare as a parameter
RESERVED = ("kind", "contact_face", "parameters")


class ObstacleData(Protocol):
    """What :func:`from_spec` reads of an obstacle's data
    (:class:`~shellobstacle.spec.Obstacle`)."""

    kind: str
    contact_face: str
    parameters: Mapping[str, Any]


def register(shape: type[Obstacle], replace: bool = False) -> type[Obstacle]:
    """Add ``shape`` to :data:`SHAPES` under ``shape.kind`` and return it.

    Raises:
        ValueError: the kind is taken (unless ``replace``), or the declaration is incomplete
            or inconsistent: a parameter its constructor does not take, a default or an
            example its own check refuses, or a key that another shape reads with another
            type.
    """
    problem = _problem(shape, replace)
    if problem:
        raise ValueError(f"{getattr(shape, '__name__', shape)!r} cannot be registered: {problem}")
    SHAPES[shape.kind] = shape
    return shape


def _problem(shape: Any, replace: bool) -> str | None:
    """What is wrong with the declaration of ``shape`` (None: nothing)."""
    if not (isinstance(shape, type) and issubclass(shape, Obstacle)):
        return "it is not a subclass of Obstacle"
    if not shape.kind or not isinstance(shape.kind, str) or not shape.summary:
        return "it declares no kind or no summary"
    if shape.kind in SHAPES and not replace:
        return f"a shape of kind {shape.kind!r} is already registered"
    arguments = inspect.signature(shape).parameters
    if "offset" not in arguments:
        return "its constructor takes no offset"
    names = [p.name for p in shape.parameters]
    if len(set(names)) != len(names):
        return f"its parameters repeat a name: {names}"
    others = [(k, p) for k, s in SHAPES.items() if k != shape.kind for p in s.parameters]
    for p in shape.parameters:
        if not isinstance(p, Parameter) or p.name in RESERVED or not p.name.isidentifier():
            return f"{p!r} is not a Parameter with a name of its own"
        if p.name not in arguments:
            return f"its constructor takes no argument {p.name!r}"
        if p.type not in TYPES:
            return f"{p.name}: type {p.type!r} is not one of {', '.join(TYPES)}"
        value = p.example if p.default is None else p.default
        if value is None:
            return f"{p.name} has neither a default nor an example"
        try:
            p.check(value, f"obstacle.{p.name}")
        except ValueError as err:
            return f"its own value of {p.name}: {err}"
        for kind, other in others:
            if other.name == p.name and other.type != p.type:
                return (
                    f"obstacle.{p.name} is a {other.type} for obstacle.kind = {kind!r}, not a "
                    f"{p.type}: give the parameter another name"
                )
    return None


def declared(name: str) -> list[tuple[str, Parameter]]:
    """The kind and the declaration of every shape that reads the key ``name``."""
    return [(kind, p) for kind, s in SHAPES.items() for p in s.parameters if p.name == name]


def require_read(kind: str, names: Iterable[str]) -> None:
    """A ValueError naming the first key of ``names`` that ``obstacle.kind = kind`` does not
    read, and the kinds that do; nothing if it reads them all."""
    reads = {p.name for p in SHAPES[kind].parameters}
    for name in names:
        if name not in ("kind", "contact_face", *reads):
            kinds = " or ".join(repr(k) for k, _ in declared(name))
            raise ValueError(
                f"obstacle.{name} is not read by obstacle.kind = {kind!r}: set obstacle.kind = "
                f"{kinds}, or remove it"
            )


def checked(kind: str, given: Mapping[str, Any]) -> dict[str, Any]:
    """The parameters of ``obstacle.kind = kind``, each checked by its declaration, its
    default where ``given`` has none: the one validation of an obstacle's values.

    A key of another shape is accepted at that shape's default (and left out).

    Raises:
        ValueError: the kind is not registered, a key of another shape holds another value,
            a parameter without a default is missing, or a value its declaration refuses.
    """
    if kind not in SHAPES:
        raise ValueError(not_one_of("obstacle.kind", kind, tuple(SHAPES)))
    require_read(kind, [n for n, v in given.items() if not _unset(n, v)])
    shape = SHAPES[kind]
    missing = [p.name for p in shape.parameters if p.default is None and _absent(given.get(p.name))]
    if missing:
        raise ValueError(f"obstacle.kind = {kind!r} needs obstacle.{', obstacle.'.join(missing)}")
    out = {}
    for p in shape.parameters:
        value = given.get(p.name)
        out[p.name] = p.default if value is None else p.check(value, f"obstacle.{p.name}")
    return out


def _unset(name: str, value: Any) -> bool:
    """Whether ``value`` of the key ``name`` says nothing: None or a shape's default."""
    return value is None or any(p.is_default(value) for _, p in declared(name))


def _absent(value: Any) -> bool:
    return value is None or (isinstance(value, str) and not value)


def example(kind: str) -> dict[str, Any]:
    """The declared examples of the parameters of ``kind`` that have no default: with them,
    a valid obstacle of that kind (``Obstacle(kind=kind, **example(kind))``)."""
    return {p.name: p.example for p in SHAPES[kind].parameters if p.default is None}


def from_spec(spec: ObstacleData, epsilon: float = 0.0) -> Obstacle:
    """The obstacle that a configuration's ``[obstacle]`` (:class:`~shellobstacle.spec.Obstacle`)
    describes, for a shell of half-thickness ``epsilon`` (the faces' offset)."""
    offset = FACE_SIGN[spec.contact_face] * epsilon
    return SHAPES[spec.kind](**spec.parameters, offset=offset)


def shape_help() -> str:
    """What ``obstacle.kind`` chooses, each shape in one line (the config reference)."""
    shapes = "; ".join(f"{kind}: {s.summary}" for kind, s in SHAPES.items())
    return f"the rigid obstacle (the contact face must stay where g ≥ 0): {shapes}"


def shape_table() -> str:
    """The Markdown table of :data:`SHAPES` (the user guide's, between its markers)."""
    lines = ["| `obstacle.kind` | the obstacle | its keys |", "|---|---|---|"]
    for kind, s in SHAPES.items():
        keys = ", ".join(
            f"`{p.name}`" + ("" if p.default is None else f" = {p.default!r}") for p in s.parameters
        )
        lines.append(f"| `{kind}` | {s.summary} | {keys} |")
    return "\n".join(lines)


def _builtin() -> None:
    """Register the package's shapes."""
    for shape in (Plane, Sphere, Cylinder, ExpressionObstacle):
        register(shape)


_builtin()
