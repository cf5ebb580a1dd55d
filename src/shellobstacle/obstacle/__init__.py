"""The obstacle: the gap ``g``, its derivative, its values where the constraint is enforced
and the contact measured there.

- :mod:`~shellobstacle.obstacle.base`: the :class:`Obstacle` interface (``g`` and ``c`` on a
  geometry, their values at points);
- :mod:`~shellobstacle.obstacle.plane`: the half-space ``{x·q ≥ 0}``;
- :mod:`~shellobstacle.obstacle.points`: the points where a discretization enforces
  ``g ≥ 0`` (nodes or the penalty's quadrature points) and the contact measured there.
"""

from __future__ import annotations

from typing import Any

from shellobstacle.obstacle.base import Obstacle, PointGap
from shellobstacle.obstacle.plane import Plane

__all__ = ["Obstacle", "Plane", "PointGap", "from_spec"]


def from_spec(spec: Any) -> Obstacle:
    """The obstacle that a configuration's ``[obstacle]`` (:class:`~shellobstacle.spec.Obstacle`)
    describes: today the plane ``x·q = 0``."""
    return Plane(spec.q)
