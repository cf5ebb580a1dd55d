"""The obstacle: the admissible set ``{g ≥ 0}`` of the shell's contact face (docs/model.md
:eq:`gap`).

An :class:`Obstacle` owns the gap ``g(η) = g(θ + s a_3 + η_i a^i)`` of a covariant
displacement ``η`` (``s``: the contact face's offset, 0 for the middle surface, ``∓ε`` for
the lower and upper faces) and its derivative ``c_j = ∂g/∂η_j = ∇g·a^j``, on any
:class:`~shellobstacle.geometry.surface.Geometry` (UFL for the forms, NumPy at points, SymPy
for manufactured solutions). A kind gives ``g`` and ``∇g`` at a point ``x`` of space
(:meth:`Obstacle.value`, :meth:`Obstacle.gradient`). Where the constraint is enforced and how
contact is measured there is :mod:`shellobstacle.post.points`.

A kind of obstacle the config names (``obstacle.kind``) is a subclass that declares its
:attr:`~Obstacle.kind`, :attr:`~Obstacle.summary` and :attr:`~Obstacle.parameters`, registered
in :data:`~shellobstacle.obstacle.shapes.SHAPES`.
"""

from __future__ import annotations

import copy
import numbers
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from shellobstacle.geometry.surface import Geometry, Surface, dot
from shellobstacle.obstacle.parameters import Parameter

__all__ = ["Obstacle", "PointGap", "number"]


def number(v: Any) -> Any:
    """A parameter's entry as every backend takes it: a Python float (from a NumPy one), or
    a UFL scalar (an entry of a :meth:`Obstacle.on_mesh` copy's Constant) as it is."""
    return float(v) if isinstance(v, numbers.Real) else v


@dataclass(frozen=True)
class PointGap:
    """The gap's data at ``n`` points: ``g(η) ≈ g0 + c·η`` there (exact for an affine gap;
    for a curved obstacle, the linearization at the displacement it was taken at).

    Attributes:
        g0: the linearization's value at ``η = 0`` (``g(θ)`` for an affine gap), shape ``(n,)``.
        c: ``c_j = ∂g/∂η_j``, shape ``(n, 3)``.
    """

    g0: np.ndarray
    c: np.ndarray

    def gap(self, eta: np.ndarray) -> np.ndarray:
        """``g0 + c·η`` for displacements ``η`` of shape ``(n, 3)``."""
        return self.g0 + np.sum(self.c * eta, axis=1)


class Obstacle(ABC):
    """A rigid obstacle: the contact face ``θ + s a_3 + η_i a^i`` must satisfy ``g ≥ 0``.

    A registered shape (:func:`~shellobstacle.obstacle.shapes.register`) declares, as class
    attributes, what the config and the documentation say of it:

    * ``kind``: the value of ``obstacle.kind`` that chooses it;
    * ``summary``: its ``g`` in one line (the config reference, the user guide's table);
    * ``parameters``: the keys of ``[obstacle]`` it reads, each an argument of its
      constructor, which also takes ``offset``.

    Attributes:
        affine: whether ``g`` is affine in ``x`` (a plane): then ``g(η) = g(0) + c·η`` with
            ``c`` independent of ``η``, the penalty is piecewise quadratic and its
            quadrature-point operators and the nodal bounds are exact. Otherwise the solvers
            work on the gap's linearization (:mod:`shellobstacle.solvers.linearization`).
        convex: whether the admissible set ``{g ≥ 0}`` is convex (the paper's theory); None
            when not known (a user's curved ``g``).
        offset: ``s``, the contact face's distance from the middle surface along ``a_3``.
        constant_parameters: the attributes (numbers, or arrays of three) that
            :meth:`on_mesh` makes ``dolfinx.fem.Constant`` objects.
    """

    kind: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    parameters: ClassVar[tuple[Parameter, ...]] = ()
    affine: bool = False
    convex: bool | None = False
    constant_parameters: ClassVar[tuple[str, ...]] = ()
    singular_set: ClassVar[str] = "a point where ∇g is not finite"
    """Where ``∇g`` is undefined, for the error that a constraint point there raises
    (:mod:`shellobstacle.models.singular`)."""

    def __init__(self, offset: float = 0.0) -> None:
        self.offset = float(offset)

    def describe(self) -> str:
        """This obstacle in words, for a picture's title: ``"the ball of radius 2 centred at
        (0, 0, -2)"``."""
        return "the obstacle g = 0"

    def on_mesh(self, mesh: Any) -> Obstacle:
        """This obstacle for the UFL forms on ``mesh``: a copy whose
        :attr:`constant_parameters` are ``dolfinx.fem.Constant`` objects holding their
        values (a vector's entries as the UFL scalars ``C[k]``), so that the forms of another
        radius, centre, axis, … are the same forms, compiled once. For UFL only. An
        obstacle without such parameters is its own copy."""
        if not self.constant_parameters:
            return self
        from petsc4py import PETSc

        import dolfinx.fem

        out = copy.copy(self)
        for name in self.constant_parameters:
            value = np.asarray(getattr(self, name), dtype=PETSc.ScalarType)
            constant = dolfinx.fem.Constant(mesh, value)
            entries = [constant[k] for k in range(value.size)] if value.ndim else constant
            setattr(out, name, entries)
        return out

    @abstractmethod
    def value(self, G: Geometry, x: Sequence[Any]) -> Any:
        """``g(x)`` at a point ``x`` of space (three scalars of ``G``'s backend)."""

    @abstractmethod
    def gradient(self, G: Geometry, x: Sequence[Any]) -> list[Any]:
        """``∇g(x)``, three scalars of ``G``'s backend."""

    def singular_distance(self, G: Geometry, x: Sequence[Any]) -> Any | None:
        """The distance from ``x`` to :attr:`singular_set` over the obstacle's size (``G``'s
        backend), None where no formula gives it (a plane: none; a user's ``g``: the check
        is that ``∇g`` is finite)."""
        return None

    def curvature_radius(self, x: np.ndarray) -> np.ndarray:
        """The smallest principal radius of curvature of the level surface of ``g`` through
        each point ``x`` (NumPy, shape ``(n, 3)``; ``inf`` where it is flat): near the
        contact, the obstacle's own (:mod:`shellobstacle.post.resolution`)."""
        return np.full(x.shape[0], np.inf)

    def point(self, G: Geometry, eta: Sequence[Any] | None = None) -> list[Any]:
        """``θ + s a_3 + η_i a^i``: the contact face displaced by ``η`` (0 if None)."""
        x = list(G.theta)
        if self.offset:
            x = [x[k] + self.offset * G.a3[k] for k in range(3)]
        if eta is not None:
            a = G.a_contra
            x = [x[k] + sum(eta[i] * a[i][k] for i in range(3)) for k in range(3)]
        return x

    def gap(self, G: Geometry, eta: Sequence[Any]) -> Any:
        """``g(θ + s a_3 + η_i a^i)`` on the geometry ``G`` (UFL, NumPy or SymPy, as ``G``)."""
        return self.value(G, self.point(G, eta))

    def c(self, G: Geometry, eta: Sequence[Any] | None = None) -> list[Any]:
        """``c_j = ∂g/∂η_j = ∇g·a^j`` at ``η`` (at ``η = 0`` if None)."""
        grad = self.gradient(G, self.point(G, eta))
        return [dot(grad, G.a_contra[j]) for j in range(3)]

    def c_norm(self, G: Geometry, eta: Sequence[Any] | None = None) -> Any:
        """``|c| = (Σ_j c_j²)^{1/2}``, the scale of the penalty term (:eq:`penalty-sum`)."""
        c = self.c(G, eta)
        return G.sqrt(dot(c, c))

    def reference_gap(self, G: Geometry) -> Any:
        """``g(θ + s a_3)``: the gap of the undeformed shell."""
        return self.value(G, self.point(G))

    def reference_gap_at(self, surface: Surface, points: np.ndarray) -> np.ndarray:
        """``g(θ + s a_3)`` at ``points`` of ω, shape ``(n,)``."""
        return self.at_points(surface, points).g0

    def at_points(
        self, surface: Surface, points: np.ndarray, eta: np.ndarray | None = None
    ) -> PointGap:
        """The gap's linearization at the displacement ``eta`` (shape ``(n, 3)``; 0 if None)
        at ``points`` of ω (shape ``(n, 2)`` or ``(n, 3)``): ``c = c(η)`` and
        ``g0 = g(η) − c(η)·η``, so that :meth:`PointGap.gap` is exact at ``η``."""
        n = points.shape[0]
        G = surface.geometry_numpy(points)
        lin = None if eta is None else [eta[:, i] for i in range(3)]
        full = lambda v: np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()  # noqa: E731
        g = full(self.value(G, self.point(G, lin)))
        c = np.column_stack([full(cj) for cj in self.c(G, lin)])
        if eta is not None:
            g = g - np.sum(c * eta, axis=1)
        return PointGap(g, c)
