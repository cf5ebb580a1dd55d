"""The half-space ``{x : x·q ≥ c}`` (docs/model.md :eq:`gap`; the paper's obstacle when
``c = 0``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from shellobstacle.geometry.surface import Geometry, Surface, dot
from shellobstacle.obstacle.base import Obstacle, number
from shellobstacle.obstacle.parameters import Parameter

__all__ = ["Plane"]


class Plane(Obstacle):
    """The plane ``x·q = c`` with the shell on the side of ``q``: ``g(x) = x·q − c``.

    The gap of a displacement ``η`` is affine, ``g(η) = (θ + s a_3)·q − c + η_j c_j`` with
    ``c_j = a^j·q``. With ``c = 0`` and the middle surface (``s = 0``) these are the paper's
    expressions, term for term.

    Args:
        q: the plane's unit normal.
        c: the plane's offset along ``q``.
        offset: ``s``, the contact face's offset along ``a_3``.
    """

    kind = "plane"
    summary = "the half-space x·q ≥ c (the paper's: c = 0)"
    parameters = (
        Parameter(
            "q",
            "float[3]",
            "normal of the plane; g = x·q − c",
            default=(0.0, 0.0, 1.0),
            unit=("half-space", "normal"),
        ),
        Parameter("c", "float", "the plane's offset along q", default=0.0),
    )
    affine = True
    convex = True
    constant_parameters = ("q", "level")
    singular_set = "nowhere"

    def __init__(self, q: Sequence[float], c: float = 0.0, offset: float = 0.0) -> None:
        super().__init__(offset)
        self.q = np.asarray(q, dtype=float)
        self.level = float(c)
        if self.q.shape != (3,) or abs(float(np.linalg.norm(self.q)) - 1.0) > 1e-12:
            raise ValueError(f"a plane needs a unit normal q of three numbers, got {q!r}")

    def __repr__(self) -> str:
        extra = f", c={self.level:g}" if self.level else ""
        extra += f", offset={self.offset:g}" if self.offset else ""
        return f"Plane(q={tuple(float(v) for v in self.q)}{extra})"

    def describe(self) -> str:
        return f"the plane x·q = {self.level:g}"

    def value(self, G: Geometry, x: Sequence[Any]) -> Any:
        """``x·q − c`` (``x·q`` for a number ``c = 0``)."""
        g = dot(x, self.q)
        return g if isinstance(self.level, float) and self.level == 0.0 else g - self.level

    def gradient(self, G: Geometry, x: Sequence[Any]) -> list[Any]:
        """``q``."""
        return [number(v) for v in self.q]

    def gap(self, G: Geometry, eta: Sequence[Any]) -> Any:
        """``g(η) = g(θ + s a_3) + η_j c_j``."""
        c = self.c(G)
        return self.reference_gap(G) + sum(eta[j] * c[j] for j in range(3))

    def c(self, G: Geometry, eta: Sequence[Any] | None = None) -> list[Any]:
        """``c_j = a^j·q`` (the same for every ``η``)."""
        return [dot(G.a_contra[j], self.q) for j in range(3)]

    def reference_gap_at(self, surface: Surface, points: np.ndarray) -> np.ndarray:
        """``(θ + s a_3)·q − c`` at ``points`` (``θ`` alone when ``s = 0``)."""
        if self.offset:
            return super().reference_gap_at(surface, points)
        theta = surface.theta_numpy(points)
        g = np.asarray(dot(theta, self.q), float) - self.level
        return np.broadcast_to(g, (points.shape[0],)).copy()
