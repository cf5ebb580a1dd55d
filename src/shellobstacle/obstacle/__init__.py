"""The obstacle: the gap ``g`` and its derivative, on any geometry and at points. Where a
discretization enforces ``g ≥ 0`` and measures the contact is :mod:`shellobstacle.post.points`.

- :mod:`~shellobstacle.obstacle.base`: the :class:`Obstacle` interface (``g`` and ``c`` on a
  geometry, their values at points, the contact face);
- :mod:`~shellobstacle.obstacle.shapes`: :data:`SHAPES`, the kinds of obstacle the config
  names, each a subclass declaring its :mod:`~shellobstacle.obstacle.parameters`;
- :mod:`~shellobstacle.obstacle.plane`: the half-space ``{x·q ≥ c}``;
- :mod:`~shellobstacle.obstacle.quadrics`: balls and round cylinders;
- :mod:`~shellobstacle.obstacle.expression`: ``{g(x) ≥ 0}`` for a user's formula ``g``.
"""

from __future__ import annotations

from shellobstacle.obstacle.base import Obstacle, PointGap
from shellobstacle.obstacle.expression import ExpressionObstacle
from shellobstacle.obstacle.parameters import Parameter
from shellobstacle.obstacle.plane import Plane
from shellobstacle.obstacle.quadrics import Cylinder, Sphere
from shellobstacle.obstacle.shapes import FACE_SIGN, SHAPES, from_spec, register

__all__ = [
    "FACE_SIGN",
    "SHAPES",
    "Cylinder",
    "ExpressionObstacle",
    "Obstacle",
    "Parameter",
    "Plane",
    "PointGap",
    "Sphere",
    "from_spec",
    "register",
]
