"""The half-space ``{x : x·q ≥ 0}`` (docs/model.md :eq:`gap`; the paper's obstacle)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from shellobstacle.geometry.surface import Geometry, Surface, dot
from shellobstacle.obstacle.base import Obstacle

__all__ = ["Plane"]


class Plane(Obstacle):
    """The plane ``x·q = 0`` with the shell on the side of ``q``: ``g(x) = x·q``.

    The gap of a displacement ``η`` is affine, ``g(η) = (θ + η_j a^j)·q = θ·q + η_j c_j`` with
    ``c_j = a^j·q``.

    Args:
        q: the plane's unit normal.
    """

    affine = True

    def __init__(self, q: Sequence[float]) -> None:
        self.q = np.asarray(q, dtype=float)
        if self.q.shape != (3,) or abs(float(np.linalg.norm(self.q)) - 1.0) > 1e-12:
            raise ValueError(f"a plane needs a unit normal q of three numbers, got {q!r}")

    def __repr__(self) -> str:
        return f"Plane(q={tuple(float(v) for v in self.q)})"

    def gap(self, G: Geometry, eta: Sequence[Any]) -> Any:
        """``g(η) = θ·q + η_j c_j``."""
        c = self.c(G)
        return self.reference_gap(G) + sum(eta[j] * c[j] for j in range(3))

    def reference_gap(self, G: Geometry) -> Any:
        """``g(θ) = θ·q``, the height of the reference shell above the plane."""
        return dot(G.theta, self.q)

    def reference_gap_at(self, surface: Surface, points: np.ndarray) -> np.ndarray:
        """``θ·q`` at ``points`` (``θ`` alone: no derivatives evaluated)."""
        theta = surface.theta_numpy(points)
        return np.broadcast_to(np.asarray(dot(theta, self.q), float), (points.shape[0],)).copy()

    def c(self, G: Geometry, eta: Sequence[Any] | None = None) -> list[Any]:
        """``c_j = a^j·q`` (the same for every ``η``)."""
        return [dot(G.a_contra[j], self.q) for j in range(3)]
