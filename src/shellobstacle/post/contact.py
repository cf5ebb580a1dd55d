"""The contact of a solved problem: nodal gap, contact set and its area, displacements.

The contact set of a solution is where its gap ``g(ζ)`` (the obstacle's,
:mod:`shellobstacle.obstacle`) is ``≤ tol``, measured with the surface element ``√a dy`` and
projected (``dy``) at two sets of points (docs/model.md §7):

- where the solution's constraint acts
  (:func:`~shellobstacle.post.points.constraint_points`: the penalty's Gauss points for
  the Gauss penalty, P1 and P2; the vertices or P2 nodes for the vertex penalty and the exact
  solvers): ``contact_area``, ``max_violation``, ...; a penalty that acts is never reported
  as no contact;
- the nodes (the P1 vertices, the P2 nodes): ``contact_area_nodal``, ``max_violation_nodal``,
  ..., the figure the paper's batch 3 measures. Where the constraint acts at the nodes the
  two are the same.

Everything returned is global: the same on every rank.
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
from shellobstacle.post.points import NodePoints, constraint_points
from shellobstacle.post.sections import AXES, CrossSection, cross_section, line_tree

__all__ = ["POINTS", "Postprocessor", "contact_text"]

#: The contact points' names in words (``contact_points``, ``nodal_points``).
POINTS = {
    "quadrature points": "the penalty's Gauss points",
    "vertices": "the vertices",
    "nodes": "the P2 nodes",
}


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
        points: The :class:`~shellobstacle.post.points.ContactPoints` where the
            constraint acts.
        nodal: The :class:`~shellobstacle.post.points.NodePoints` of ``ζ``'s space (the
            nodal figure; ``points`` itself where the constraint acts at the nodes).
        P1: Scalar P1 space on the mesh (vertex values).
        gap: ``g(ζ)`` at the vertices (a P1 Function, refreshed by :meth:`nodal_gap`).
        contact_indicator: the contact flags on the vertices (refreshed by :meth:`indicator`).
        U: Cartesian displacement ``ζ_i a^i`` in the space of ``ζ`` (refreshed by
            :meth:`cartesian_displacement`).
        mass: the weights ``w_k √a(x_k)`` of the owned points where the constraint acts (P1
            vertices: the lumped masses ``∫ φ_i √a dy``, vertex rule).
        mass_projected: their weights ``w_k``.
        gap_scale: ``max |g(θ)|`` over the mesh vertices (scale of the contact tolerance).
    """

    def __init__(self, problem: PenalizedProblem, constraint: str = "penalty") -> None:
        self.problem = problem
        mesh = problem.mesh
        self.comm: MPI.Comm = mesh.comm
        self.points = constraint_points(problem, constraint)
        points = self.points
        self.nodal = points if isinstance(points, NodePoints) else NodePoints(problem)
        if self.nodal.kind == "vertices":  # the nodes are the P1 dofs: share their space
            self.P1 = self.nodal.space
            self.gap = self.nodal.values
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
        """The contact set ``{g(ζ) ≤ tol}`` where the constraint acts and at the nodes, and
        their measures (:meth:`~shellobstacle.post.points.ContactPoints.measure`;
        docs/model.md §7).

        Args:
            tol_rel: Tolerance relative to ``max |g(θ)|``.

        Returns:
            Where the constraint acts (:attr:`points`): ``contact_area`` (``Σ w_k √a(x_k)``
            over the contact points), ``contact_area_projected`` (``Σ w_k``),
            ``max_violation`` (``max {g}^-``), ``min_gap``, ``num_contact_points`` and
            ``contact_points`` (where: ``"quadrature points"``, ``"vertices"`` or
            ``"nodes"``); at the nodes (:attr:`nodal`): ``contact_area_nodal`` (P1: the
            lumped ``∫ φ_i √a dy`` of the contact vertices), ``contact_area_nodal_projected``,
            ``max_violation_nodal``, ``min_gap_nodal``, ``num_contact_nodes`` and
            ``nodal_points``; ``tol``. Global values.
        """
        tol = self.tolerance(tol_rel)
        acting = self.points.measure(tol)
        nodal = acting if self.nodal is self.points else self.nodal.measure(tol)
        return {
            "contact_area": acting.area,
            "contact_area_projected": acting.area_projected,
            "max_violation": acting.max_violation,
            "min_gap": acting.min_gap,
            "num_contact_points": acting.count,
            "contact_points": acting.points,
            "contact_area_nodal": nodal.area,
            "contact_area_nodal_projected": nodal.area_projected,
            "max_violation_nodal": nodal.max_violation,
            "min_gap_nodal": nodal.min_gap,
            "num_contact_nodes": nodal.count,
            "nodal_points": nodal.points,
            "tol": tol,
        }

    def indicator(self, tol_rel: float = 1e-12) -> dolfinx.fem.Function:
        """The contact indicator on the vertices (a P1 Function), which the pictures' outline,
        the ParaView files and the adaptive marking read: for P1 the vertices' own contact
        flags (1 or 0: a P1 solution's values), for P2 the flags of the points where the
        constraint acts, lumped (its ½ level line outlines the contact set)."""
        points = self.nodal if self.problem.disc.degree == 1 else self.points
        return points.indicator(self.tolerance(tol_rel), self.contact_indicator)

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
        """``(Σ_k w_k √a(x_k), Σ_k w_k)`` over the points where the constraint acts: the
        surface area and the domain area by their rule (P1 vertices: ``Σ_i ∫ φ_i √a dy``)."""
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


def contact_text(summary: dict[str, Any], fmt: str = ".5g", projected: bool = False) -> str:
    """``"contact area A at <points>"`` from a :meth:`Postprocessor.contact` (or a
    ``summary.json``), with the nodal figure beside it where the constraint acts elsewhere:
    ``"contact area 0.003 at the penalty's Gauss points (nodal 0 at the vertices)"``;
    ``projected`` adds the projected areas (``"A, projected P, at ..."``)."""

    def area(key: str) -> str:
        shown = f"{summary[key]:{fmt}}"
        return shown + (f", projected {summary[key + '_projected']:{fmt}}," if projected else "")

    where, nodal = summary["contact_points"], summary["nodal_points"]
    text = f"contact area {area('contact_area')} at {POINTS[where]}"
    if nodal != where:
        text += f" (nodal {area('contact_area_nodal')} at {POINTS[nodal]})"
    return text
