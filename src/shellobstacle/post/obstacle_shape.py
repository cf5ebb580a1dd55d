"""The obstacle's surface ``{g = 0}`` near a shell, sampled for drawing (docs/model.md :eq:`gap`).

The plane is drawn exactly (a square in the 3D pictures, the line at height 0 in the
cross-sections); a curved obstacle (a ball, a cylinder, a formula) is sampled with its own
NumPy values :meth:`~shellobstacle.obstacle.base.Obstacle.value` and
:meth:`~shellobstacle.obstacle.base.Obstacle.gradient`:

- :func:`level_box`: ``g`` on a uniform grid of a box of space (the 3D pictures contour it at 0);
- :func:`onto`: points moved onto ``{g = 0}`` by Newton steps along ``∇g`` (the contact
  zone's outline drawn on the obstacle);
- :func:`profile_below`: the height of the obstacle's upper surface under points of a line
  (the cross-sections' obstacle profile).

``G`` is a NumPy :class:`~shellobstacle.geometry.surface.Geometry` (any
``surface.geometry_numpy(points)``): ``g`` is a function of space, ``G`` only names the backend.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shellobstacle.geometry.surface import Geometry
from shellobstacle.obstacle.base import Obstacle

__all__ = ["gradients", "level_box", "onto", "profile_below", "values"]


def values(obstacle: Obstacle, G: Geometry, x: np.ndarray) -> np.ndarray:
    """``g(x)`` at the points ``x`` (shape ``(n, 3)``), shape ``(n,)``."""
    x = np.asarray(x, dtype=float)
    g = obstacle.value(G, [x[:, 0], x[:, 1], x[:, 2]])
    return np.broadcast_to(np.asarray(g, dtype=float), (len(x),)).copy()


def gradients(obstacle: Obstacle, G: Geometry, x: np.ndarray) -> np.ndarray:
    """``∇g(x)`` at the points ``x`` (shape ``(n, 3)``), shape ``(n, 3)``."""
    x = np.asarray(x, dtype=float)
    grad = obstacle.gradient(G, [x[:, 0], x[:, 1], x[:, 2]])
    return np.column_stack([np.broadcast_to(np.asarray(d, float), (len(x),)) for d in grad])


def level_box(
    obstacle: Obstacle, G: Geometry, lo: Sequence[float], hi: Sequence[float], cells: int = 96
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``g`` at the nodes of a uniform grid of the box ``[lo, hi]``.

    The grid's spacing is the same along every axis, ``cells`` intervals along the box's
    longest side (the box grows to a whole number of intervals).

    Returns:
        ``(origin, spacing, g)``: the grid's corner ``lo`` and spacing (shape ``(3,)``) and
        ``g`` at the node ``origin + (i, j, k) · spacing`` as ``g[i, j, k]``.
    """
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    h = float(np.max(hi - lo)) / cells
    n = np.maximum(np.ceil((hi - lo) / h - 1e-9).astype(int), 1) + 1
    axes = [lo[k] + h * np.arange(n[k]) for k in range(3)]
    X = np.meshgrid(*axes, indexing="ij")
    g = values(obstacle, G, np.column_stack([c.ravel() for c in X])).reshape(X[0].shape)
    return lo, np.full(3, h), g


def onto(
    obstacle: Obstacle, G: Geometry, x: np.ndarray, steps: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """The points ``x`` (shape ``(n, 3)``) moved onto ``{g = 0}`` and the unit normals there.

    Each of the ``steps`` Newton steps ``x ← x − g ∇g/|∇g|²`` moves along the gradient to the
    zero of ``g``'s linearization: exact in one step for a plane and for a ball's or a
    cylinder's signed distance, quadratically convergent for a smooth formula near its zero set.

    Returns:
        ``(points, normals)``: the points on the surface and ``∇g/|∇g|`` there (pointing to
        ``g > 0``, the shell's side).
    """
    x = np.array(x, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):  # ∇g = 0: NaN, drawn nowhere
        for _ in range(steps):
            grad = gradients(obstacle, G, x)
            x -= (values(obstacle, G, x) / np.sum(grad * grad, axis=1))[:, None] * grad
        grad = gradients(obstacle, G, x)
        return x, grad / np.linalg.norm(grad, axis=1)[:, None]


def profile_below(
    obstacle: Obstacle,
    G: Geometry,
    base: np.ndarray,
    up: Sequence[float],
    top: float,
    bottom: float,
    samples: int = 801,
) -> np.ndarray:
    """The height of the obstacle's upper surface on the vertical lines ``base + z · up``.

    Along each line ``g`` is sampled at ``samples`` heights from ``top`` down to ``bottom``;
    the surface is the first place where ``g`` turns from ``≥ 0`` (the shell's side) to
    ``< 0`` going down, located by bisection to round-off: the top of a ball below, the bottom
    of a ball the shell is inside.

    Args:
        base: the lines' points at height 0, shape ``(n, 3)``.
        up: the unit vertical direction (the normal ``q`` of the pictures' frame).
        top: the height the search starts at.
        bottom: the height it ends at.
        samples: the number of heights sampled (a surface thinner than their spacing may be
            missed).

    Returns:
        The heights ``z`` with ``g(base + z · up) = 0``, shape ``(n,)``; NaN on a line that
        meets no such surface between ``bottom`` and ``top``.
    """
    base = np.asarray(base, dtype=float)
    up = np.asarray(up, dtype=float)
    n = len(base)
    z = np.linspace(top, bottom, samples)
    at = lambda heights: base + heights[..., None] * up  # noqa: E731
    g = values(obstacle, G, at(np.repeat(z[:, None], n, axis=1)).reshape(-1, 3))
    g = g.reshape(samples, n)
    turns = (g[:-1] >= 0) & (g[1:] < 0)
    found = turns.any(axis=0)
    first = np.argmax(turns, axis=0)
    hi, lo = z[first].copy(), z[first + 1].copy()  # g(hi) ≥ 0 > g(lo)
    for _ in range(60):
        mid = 0.5 * (hi + lo)
        above = values(obstacle, G, at(mid)) >= 0
        hi, lo = np.where(above, mid, hi), np.where(above, lo, mid)
    return np.where(found, 0.5 * (hi + lo), np.nan)
