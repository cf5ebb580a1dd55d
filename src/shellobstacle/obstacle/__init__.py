"""The obstacle: the gap ``g``, its derivative, its values where the constraint is enforced
and the contact measured there.

- :mod:`~shellobstacle.obstacle.base`: the :class:`Obstacle` interface (``g`` and ``c`` on a
  geometry, their values at points, the contact face);
- :mod:`~shellobstacle.obstacle.plane`: the half-space ``{x·q ≥ c}``;
- :mod:`~shellobstacle.obstacle.quadrics`: balls and round cylinders;
- :mod:`~shellobstacle.obstacle.expression`: ``{g(x) ≥ 0}`` for a user's formula ``g``;
- :mod:`~shellobstacle.obstacle.points`: the points where a discretization enforces
  ``g ≥ 0`` (nodes or the penalty's quadrature points) and the contact measured there.
"""

from __future__ import annotations

from typing import Any

from shellobstacle.obstacle.base import Obstacle, PointGap
from shellobstacle.obstacle.expression import ExpressionObstacle
from shellobstacle.obstacle.plane import Plane
from shellobstacle.obstacle.quadrics import Cylinder, Sphere

__all__ = ["Cylinder", "ExpressionObstacle", "Obstacle", "Plane", "PointGap", "Sphere", "from_spec"]

FACE_SIGN = {"middle": 0.0, "lower": -1.0, "upper": 1.0}
"""The contact face ``θ + s a_3``: ``s = FACE_SIGN[contact_face] · ε``."""


def from_spec(spec: Any, epsilon: float = 0.0) -> Obstacle:
    """The obstacle that a configuration's ``[obstacle]`` (:class:`~shellobstacle.spec.Obstacle`)
    describes, for a shell of half-thickness ``epsilon`` (the faces' offset)."""
    offset = FACE_SIGN[spec.contact_face] * epsilon
    if spec.kind == "plane":
        return Plane(spec.q, spec.c, offset)
    if spec.kind == "sphere":
        return Sphere(spec.center, spec.radius, spec.side, offset)
    if spec.kind == "cylinder":
        return Cylinder(spec.point, spec.axis, spec.radius, spec.side, offset)
    return ExpressionObstacle(spec.g, offset)
