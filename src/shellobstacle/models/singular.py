"""Where a curved obstacle's gradient is undefined: an error that names it, not ``0/0`` in the
forms.

``∇g`` of a ball is ``±(x − centre)/|x − centre|``, of a cylinder the same with the radial
part: ``0/0`` at the centre or on the axis, and a user's ``g`` can have such points too
(:attr:`~shellobstacle.obstacle.base.Obstacle.singular_set`). The constraint's derivative
``c_j = ∇g·a^j`` (docs/model.md :eq:`gap`) is taken at the displacement ``ζ̄`` that a curved
obstacle's gap is linearized at; a constraint point of the contact face there would put NaN
into every form and operator, inactive points included, and the solvers would fail far from
the cause. :class:`GradientCheck` evaluates ``c(ζ̄)`` at every point where a constraint may
act (the penalty rule's points and the Lagrange nodes) and raises
:class:`SingularGradientError` naming the set and the point.
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import numpy as np
import ufl

from shellobstacle.penalty.rule import reference_rule

__all__ = ["GradientCheck", "SingularGradientError"]


class SingularGradientError(ArithmeticError):
    """A constraint point of the contact face lies where ``∇g`` is undefined."""


SINGULAR = 1e-8
"""A constraint point within ``SINGULAR · R`` of a ball's centre (a cylinder's axis) has a
``∇g`` whose computed direction is off by more than about ``1e-8`` (the coordinates'
round-off over the distance)."""


class GradientCheck:
    """``c(ζ̄)`` defined at the constraint's points of a linearized problem, or an error.

    Built once per problem (the expressions are compiled here, the obstacle's parameters as
    Constants); each call reads the current ``problem.zeta_lin``. Collective.
    """

    def __init__(self, problem: Any) -> None:
        self.problem = problem
        mesh = problem.mesh
        owned = mesh.topology.index_map(mesh.topology.dim).size_local
        self.cells = np.arange(owned, dtype=np.int32)
        obstacle = problem.obstacle.on_mesh(mesh)
        G = problem.G
        lin = [problem.zeta_lin[i] for i in range(3)]
        c = obstacle.c(G, lin)
        distance = obstacle.singular_distance(G, obstacle.point(G, lin))
        # Σ|c_j| ≥ 0 where ∇g is defined; NaN or ∞ where it is not; −1 on the singular set
        measure = abs(c[0]) + abs(c[1]) + abs(c[2])
        if distance is not None:
            measure = ufl.conditional(ufl.gt(distance, SINGULAR), measure, -1.0)
        y = ufl.SpatialCoordinate(mesh)
        points = [
            reference_rule(mesh.basix_cell(), problem.disc)[0],
            problem.V.element.interpolation_points,
        ]
        self.exprs = [
            (dolfinx.fem.Expression(measure, X), dolfinx.fem.Expression(y, X)) for X in points
        ]

    def __call__(self) -> None:
        """Raise :class:`SingularGradientError` if a point is on the singular set."""
        mesh = self.problem.mesh
        where: list[float] = []
        for measure, y_expr in self.exprs:
            values = measure.eval(mesh, self.cells).reshape(self.cells.size, -1)
            bad = ~(np.isfinite(values) & (values >= 0))
            if bad.any():
                cell, k = np.argwhere(bad)[0]
                y = y_expr.eval(mesh, self.cells[cell : cell + 1]).reshape(-1, mesh.geometry.dim)
                where = [float(v) for v in y[k, :2]]
                break
        found = [w for w in mesh.comm.allgather(where) if w]
        if found:
            y1, y2 = found[0]
            raise SingularGradientError(
                f"the shell's contact face reaches {self.problem.obstacle.singular_set} at "
                f"y = ({y1:.4g}, {y2:.4g}) " + self._fix()
            )

    def _fix(self) -> str:
        """What to change: the obstacle for the reference shell, the load for a deformed one."""
        moved = bool(np.any(self.problem.zeta_lin.x.array))
        if not self.problem.mesh.comm.allreduce(moved, op=MPI.LOR):
            return (
                "of the undeformed shell: the constraint has no direction there; move the "
                "obstacle (its centre or axis) off the shell"
            )
        return (
            "of the deformed shell: the constraint has no direction there; the shell went "
            "through the obstacle (reduce the load, or decrease κ with a larger "
            "penalty.exponent) or, for side = 'inside', move the centre or axis off the shell"
        )
