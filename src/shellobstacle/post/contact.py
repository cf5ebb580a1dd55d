"""The contact of a solved problem: nodal gap, contact set and its area, displacements.

The contact set of a solution is where its gap ``g(ζ)`` (the obstacle's,
:mod:`shellobstacle.obstacle`) is ``≤ tol``, measured at the points where the solution's
constraint acts (:func:`~shellobstacle.obstacle.points.constraint_points`: the vertices for
P1, the P2 nodes for the exact solvers, the penalty's Gauss points for P2), with the surface
element ``√a dy`` and projected (``dy``). Everything returned is global: the same on every
rank.
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.geometry
import numpy as np
import ufl

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.obstacle.points import constraint_points
from shellobstacle.post.sections import AXES, CrossSection, cross_section, line_tree

__all__ = ["Postprocessor"]


def _owned(f: dolfinx.fem.Function) -> np.ndarray:
    """Values of the owned dofs of ``f``, shape ``(size_local, block size)``."""
    im, bs = f.function_space.dofmap.index_map, f.function_space.dofmap.index_map_bs
    return f.x.array.reshape(-1, bs)[: im.size_local]


def _global_max(comm: MPI.Comm, values: np.ndarray, initial: float = -np.inf) -> float:
    return float(comm.allreduce(float(np.max(values, initial=initial)), op=MPI.MAX))


def _global_min(comm: MPI.Comm, values: np.ndarray, initial: float = np.inf) -> float:
    return float(comm.allreduce(float(np.min(values, initial=initial)), op=MPI.MIN))


class Postprocessor:
    """Nodal gap, contact set and areas, Cartesian displacement of one :class:`PenalizedProblem`.

    Built once per problem: the ``dolfinx.fem.Expression`` objects (gap, Cartesian
    displacement) and the points' weights are compiled/assembled here and reused for every
    ``κ`` and load parameter; each method reads the current ``problem.zeta``.

    Args:
        problem: The problem.
        constraint: ``"penalty"`` (``problem.zeta`` is a penalized solution) or ``"nodes"``
            (a solution of the exact nodal problem): where contact is measured.

    Attributes:
        points: The :class:`~shellobstacle.obstacle.points.ContactPoints` of the constraint.
        P1: Scalar P1 space on the mesh (vertex values).
        gap: ``g(ζ)`` at the vertices (a P1 Function, refreshed by :meth:`nodal_gap`).
        contact_indicator: the contact flags of the points lumped onto the vertices (1 on
            contact vertices for P1; refreshed by :meth:`indicator`).
        U: Cartesian displacement ``ζ_i a^i`` in the space of ``ζ`` (refreshed by
            :meth:`cartesian_displacement`).
        mass: the weights ``w_k √a(x_k)`` of the owned points (P1: the lumped masses
            ``∫ φ_i √a dy`` of the owned vertices, vertex rule).
        mass_projected: the weights ``w_k`` of the owned points.
        gap_scale: ``max |g(θ)|`` over the mesh vertices (scale of the contact tolerance).
    """

    def __init__(self, problem: PenalizedProblem, constraint: str = "penalty") -> None:
        self.problem = problem
        mesh = problem.mesh
        self.comm: MPI.Comm = mesh.comm
        self.points = constraint_points(problem, constraint)
        if self.points.kind == "vertices":  # the points are the P1 dofs: share their space
            self.P1 = self.points.space
            self.gap = self.points.values
        else:
            self.P1 = dolfinx.fem.functionspace(mesh, ("Lagrange", 1))
            self.gap = dolfinx.fem.Function(self.P1, name="gap")
        self.contact_indicator = dolfinx.fem.Function(self.P1, name="contact")
        self.U = dolfinx.fem.Function(problem.V, name="U")
        self._gap_expr = dolfinx.fem.Expression(problem.g, self.P1.element.interpolation_points)
        zeta = problem.zeta
        U = ufl.as_vector(problem.G.cartesian([zeta[i] for i in range(3)]))
        self._U_expr = dolfinx.fem.Expression(U, problem.V.element.interpolation_points)
        self.mass = self.points.mass
        self.mass_projected = self.points.mass_projected

        n_owned = self.P1.dofmap.index_map.size_local
        vertices = self.P1.tabulate_dof_coordinates()[:n_owned]
        g0 = problem.obstacle.reference_gap_at(problem.shell.surface, vertices)
        self.gap_scale = _global_max(self.comm, np.abs(g0), 0.0)
        self._trees: dict[tuple[str, float], dolfinx.geometry.BoundingBoxTree] = {}

    def nodal_gap(self) -> dolfinx.fem.Function:
        """``g(ζ)`` at the mesh vertices (docs/model.md §3), as a P1 Function.

        For P2 ``ζ`` these are the vertex values (the P1 interpolation points): the colours of
        the pictures; the contact is measured by :meth:`contact`.
        """
        self.gap.interpolate(self._gap_expr)
        self.gap.x.scatter_forward()
        return self.gap

    def tolerance(self, tol_rel: float = 1e-12) -> float:
        """The contact threshold ``tol_rel · max |g(θ)|``: a point touches if ``g ≤`` this."""
        return tol_rel * self.gap_scale

    def contact(self, tol_rel: float = 1e-12) -> dict[str, Any]:
        """The contact set ``{g(ζ) ≤ tol}`` at the constraint's points and its measures
        (:meth:`~shellobstacle.obstacle.points.ContactPoints.measure`; docs/model.md §7).

        Args:
            tol_rel: Tolerance relative to ``max |g(θ)|``.

        Returns:
            ``contact_area`` (``Σ w_k √a(x_k)`` over contact points; P1: the lumped
            ``∫ φ_i √a dy`` of the contact vertices), ``contact_area_projected`` (``Σ w_k``),
            ``max_violation`` (``max {g}^-`` over the points), ``min_gap``,
            ``num_contact_nodes`` (contact points), ``tol`` and ``contact_points`` (where:
            ``"vertices"``, ``"nodes"`` or ``"quadrature points"``); global values.
        """
        return self.points.measure(self.tolerance(tol_rel))

    def indicator(self, tol_rel: float = 1e-12) -> dolfinx.fem.Function:
        """The contact indicator on the vertices (a P1 Function): the points' contact flags
        lumped (for P1, 1 on contact vertices and 0 elsewhere; its ½ level line outlines the
        contact set)."""
        return self.points.indicator(self.tolerance(tol_rel), self.contact_indicator)

    def cartesian_displacement(self) -> dolfinx.fem.Function:
        """``U = ζ_i a^i``: Cartesian components of the displacement, in the space of ``ζ``."""
        self.U.interpolate(self._U_expr)
        self.U.x.scatter_forward()
        return self.U

    def zeta3_range(self) -> tuple[float, float]:
        """Global ``(min, max)`` of the dofs of the transverse component ``ζ_3``."""
        z3 = _owned(self.problem.zeta)[:, 2]
        return _global_min(self.comm, z3), _global_max(self.comm, z3)

    def total_mass(self) -> tuple[float, float]:
        """``(Σ_i ∫ φ_i √a dy, Σ_i ∫ φ_i dy)``: the lumped surface area and the domain area."""
        return (
            float(self.comm.allreduce(float(self.mass.sum()), op=MPI.SUM)),
            float(self.comm.allreduce(float(self.mass_projected.sum()), op=MPI.SUM)),
        )

    def summary(self, tol_rel: float = 1e-12) -> dict[str, float | int]:
        """Contact measures, range of ``ζ_3`` and energies (``problem.energies()``) in one dict."""
        out: dict[str, float | int] = dict(self.contact(tol_rel))
        out["zeta3_min"], out["zeta3_max"] = self.zeta3_range()
        out |= self.problem.energies()
        return out

    def cross_section(self, n: int = 401, axis: str = "y1", at: float = 0.0) -> CrossSection:
        """:func:`cross_section` of the current ``ζ``, reusing the line's bounding-box tree."""
        if axis not in AXES:
            raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
        key = (axis, float(at))
        if key not in self._trees:
            self._trees[key] = line_tree(self.problem.mesh, axis, at)
        return cross_section(self.problem, n=n, axis=axis, at=at, tree=self._trees[key])
