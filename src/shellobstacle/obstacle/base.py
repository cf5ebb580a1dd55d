"""The obstacle: the admissible set ``{g ≥ 0}`` of the deformed middle surface (docs/model.md
:eq:`gap`).

An :class:`Obstacle` owns the gap ``g(η) = g(θ + η_i a^i)`` of a covariant displacement ``η``
and its derivative ``c_j = ∂g/∂η_j``, on any
:class:`~shellobstacle.geometry.surface.Geometry` (UFL for the forms, NumPy at points, SymPy
for manufactured solutions). Where the constraint is
enforced and how contact is measured there is :mod:`shellobstacle.obstacle.points`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from shellobstacle.geometry.surface import Geometry, Surface, dot

__all__ = ["Obstacle", "PointGap"]


@dataclass(frozen=True)
class PointGap:
    """The gap's data at ``n`` points: ``g(η) ≈ g0 + c·η`` there (exact for an affine gap).

    Attributes:
        g0: ``g(θ)``, the reference shell's gap, shape ``(n,)``.
        c: ``c_j = ∂g/∂η_j`` at ``η = 0``, shape ``(n, 3)``.
    """

    g0: np.ndarray
    c: np.ndarray

    def gap(self, eta: np.ndarray) -> np.ndarray:
        """``g0 + c·η`` for displacements ``η`` of shape ``(n, 3)``."""
        return self.g0 + np.sum(self.c * eta, axis=1)


class Obstacle(ABC):
    """A rigid obstacle: the deformed middle surface ``θ + η_i a^i`` must satisfy ``g ≥ 0``.

    Attributes:
        affine: whether ``g`` is affine in ``η`` (``g = g(θ) + c·η`` with ``c`` independent of
            ``η``): then the penalty is piecewise quadratic and its quadrature-point operators
            (:class:`~shellobstacle.penalty.quadrature.QuadraturePenalty`) and the nodal bounds
            (:class:`~shellobstacle.solvers.nodal.NodalConstraint`) are exact.
    """

    affine: bool = False

    @abstractmethod
    def gap(self, G: Geometry, eta: Sequence[Any]) -> Any:
        """``g(θ + η_i a^i)`` on the geometry ``G`` (UFL, NumPy or SymPy, as ``G``)."""

    @abstractmethod
    def c(self, G: Geometry, eta: Sequence[Any] | None = None) -> list[Any]:
        """``c_j = ∂g/∂η_j`` at ``η`` (at ``η = 0`` if None): the gap's linearization."""

    def c_norm(self, G: Geometry, eta: Sequence[Any] | None = None) -> Any:
        """``|c| = (Σ_j c_j²)^{1/2}``, the scale of the penalty term (:eq:`penalty-sum`)."""
        c = self.c(G, eta)
        return G.sqrt(dot(c, c))

    def reference_gap(self, G: Geometry) -> Any:
        """``g(θ)``: the gap of the undeformed shell."""
        return self.gap(G, [0, 0, 0])

    def reference_gap_at(self, surface: Surface, points: np.ndarray) -> np.ndarray:
        """``g(θ)`` at ``points`` of ω, shape ``(n,)``."""
        return self.at_points(surface, points).g0

    def at_points(self, surface: Surface, points: np.ndarray) -> PointGap:
        """``g(θ)`` and ``c`` at ``points`` of ω (shape ``(n, 2)`` or ``(n, 3)``)."""
        n = points.shape[0]
        G = surface.geometry_numpy(points)
        g0 = np.broadcast_to(np.asarray(self.reference_gap(G), dtype=float), (n,)).copy()
        c = np.column_stack([np.broadcast_to(np.asarray(cj, float), (n,)) for cj in self.c(G)])
        return PointGap(g0, c)
