"""Balls and round cylinders: ``g`` the signed distance to their surface (docs/model.md
:eq:`gap`).

Outside (``side = "outside"``) ``g = d − R`` with ``d`` the distance to the centre or the
axis; inside, ``g = R − d``. Inside a ball or a cylinder the admissible set is convex (the
paper's theory applies); outside it is not, and a solution is a local one.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from shellobstacle.geometry.surface import Geometry, dot
from shellobstacle.obstacle.base import Obstacle, number
from shellobstacle.obstacle.parameters import Parameter

__all__ = ["Cylinder", "Sphere"]

#: the two parameters of every round obstacle
RADIUS = Parameter("radius", "float", "radius R > 0", above=0.0, example=1.0)
SIDE = Parameter(
    "side",
    "str",
    "outside: g = distance − R (the shell stays out; not convex); inside: R − distance",
    default="outside",
    choices=("outside", "inside"),
)


class _Round(Obstacle):
    """A surface at distance ``R`` from a centre (a point or a line); its parameters are
    Constants in the forms (:meth:`~shellobstacle.obstacle.base.Obstacle.on_mesh`)."""

    def __init__(self, radius: float, side: str, offset: float) -> None:
        super().__init__(offset)
        self.radius, self.side = float(radius), side
        self.sign = {"outside": 1.0, "inside": -1.0}[side]
        self.convex = side == "inside"

    def radial(self, x: Sequence[Any]) -> list[Any]:
        """The vector from the centre (or its foot on the axis) to ``x``."""
        raise NotImplementedError

    def value(self, G: Geometry, x: Sequence[Any]) -> Any:
        """``±(d − R)`` with ``d = |radial(x)|``."""
        r = self.radial(x)
        return self.sign * (G.sqrt(dot(r, r)) - self.radius)

    def gradient(self, G: Geometry, x: Sequence[Any]) -> list[Any]:
        """``±radial(x)/d``: ``0/0`` at the centre (the axis), :attr:`singular_set`."""
        r = self.radial(x)
        d = G.sqrt(dot(r, r))
        return [self.sign * rk / d for rk in r]

    def singular_distance(self, G: Geometry, x: Sequence[Any]) -> Any:
        """``d/R``: the distance to the centre (the axis) over the radius."""
        r = self.radial(x)
        return G.sqrt(dot(r, r)) / number(self.radius)

    def curvature_radius(self, x: np.ndarray) -> np.ndarray:
        """``R`` (the surface ``g = 0``: a sphere's two principal radii, a cylinder's
        smaller one)."""
        return np.full(x.shape[0], float(self.radius))


class Sphere(_Round):
    """The ball ``|x − center| ≤ R``: the shell stays outside it or inside it."""

    kind = "sphere"
    summary = "outside or inside a ball"
    parameters = (
        Parameter("center", "float[3]", "centre of the ball", example=(0.0, 0.0, -1.0)),
        RADIUS,
        SIDE,
    )
    constant_parameters = ("center", "radius")
    singular_set = "the ball's centre, where ∇g = ±(x − centre)/|x − centre| is 0/0"

    def __init__(
        self, center: Sequence[float], radius: float, side: str = "outside", offset: float = 0.0
    ) -> None:
        super().__init__(radius, side, offset)
        self.center = np.asarray(center, dtype=float)

    def __repr__(self) -> str:
        return f"Sphere(center={tuple(self.center)}, radius={self.radius:g}, side={self.side!r})"

    def describe(self) -> str:
        centre = ", ".join(f"{v:g}" for v in self.center)
        return f"the ball of radius {self.radius:g} centred at ({centre})"

    def radial(self, x: Sequence[Any]) -> list[Any]:
        return [x[k] - number(self.center[k]) for k in range(3)]


class Cylinder(_Round):
    """The round cylinder of radius ``R`` about the line through ``point`` along ``axis``
    (divided by its norm)."""

    kind = "cylinder"
    summary = "outside or inside a round cylinder"
    parameters = (
        Parameter("point", "float[3]", "a point of the cylinder's axis", example=(0.0, 0.0, -1.0)),
        Parameter(
            "axis",
            "float[3]",
            "the cylinder's axis",
            unit=("axis", "direction"),
            example=(1.0, 0.0, 0.0),
        ),
        RADIUS,
        SIDE,
    )
    constant_parameters = ("origin", "axis", "radius")
    singular_set = "the cylinder's axis, where ∇g = ±(radial part)/|radial part| is 0/0"

    def __init__(
        self,
        point: Sequence[float],
        axis: Sequence[float],
        radius: float,
        side: str = "outside",
        offset: float = 0.0,
    ) -> None:
        super().__init__(radius, side, offset)
        self.origin = np.asarray(point, dtype=float)
        axis = np.asarray(axis, dtype=float)
        self.axis = axis / np.linalg.norm(axis)

    def __repr__(self) -> str:
        return (
            f"Cylinder(point={tuple(self.origin)}, axis={tuple(self.axis)}, "
            f"radius={self.radius:g}, side={self.side!r})"
        )

    def describe(self) -> str:
        return f"the cylinder of radius {self.radius:g}"

    def radial(self, x: Sequence[Any]) -> list[Any]:
        d = [x[k] - number(self.origin[k]) for k in range(3)]
        axis = [number(a) for a in self.axis]
        t = dot(d, axis)
        return [d[k] - t * axis[k] for k in range(3)]
