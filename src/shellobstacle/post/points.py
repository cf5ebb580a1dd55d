"""Where a discretization enforces ``g ≥ 0``, and the contact measured there (docs/model.md
§7).

The contact of a solution is measured at the points where its constraint acts, each with a
weight ``w_k`` of a rule on ω (``Σ_k w_k φ(x_k) ≈ ∫ φ dy``) (:func:`constraint_points`):

- the Lagrange nodes (:class:`NodePoints`): the exact nodal solvers' constraint and the
  vertex penalty's (P1: the vertices with the vertex rule, ``w_i = ∫ φ_i dy`` lumped; P2: the
  vertices and edge midpoints, each cell's measure shared ``1/12`` per vertex and ``1/4`` per
  edge midpoint, the vertex rule of the cell's uniform refinement);
- the Gauss points of the penalty's rule (:class:`QuadraturePoints`), for the Gauss penalty
  (P1 and P2).

The contact set is ``{x_k : g(x_k) ≤ tol}``; its area is the weight of its points, with the
surface element (``Σ w_k √a(x_k)``) and projected (``Σ w_k``): for P1 at the vertices that is
the sum of the lumped masses ``∫ φ_i √a dy`` of the contact vertices.

The Gauss penalty's contact is measured at its Gauss points for P1 too, where it acts: its
vertices can all stay off an obstacle that its Gauss points touch (a ball a few cells wide,
between the vertices, docs/model.md §7). The nodal figure (:class:`NodePoints`: the
P1 vertices, the P2 nodes), which the paper's batch 3 measures, is reported beside it
(:meth:`~shellobstacle.post.contact.Postprocessor.contact`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.la
import numpy as np
import ufl

from shellobstacle.penalty.rule import quadrature_space

__all__ = [
    "CONSTRAINTS",
    "ContactMeasure",
    "ContactPoints",
    "NodePoints",
    "QuadraturePoints",
    "constraint_points",
    "lumped_mass_p2",
]

CONSTRAINTS = ("penalty", "nodes")
"""``"penalty"``: the penalty's rule (a penalized solution); ``"nodes"``: the Lagrange nodes
(a solution of the exact nodal problem)."""


def constraint_points(problem: Any, constraint: str = "penalty") -> ContactPoints:
    """The points where ``problem``'s constraint acts, for measuring its contact.

    Args:
        problem: a :class:`~shellobstacle.models.problem.PenalizedProblem`.
        constraint: ``"penalty"`` (``problem.zeta`` is a penalized solution) or ``"nodes"``
            (a solution of the exact nodal problem).

    Returns:
        The Lagrange nodes for ``"nodes"`` and for the vertex penalty; the penalty's Gauss
        points otherwise (P1 and P2).
    """
    if constraint not in CONSTRAINTS:
        raise ValueError(f"constraint must be one of {CONSTRAINTS}, got {constraint!r}")
    if constraint == "nodes" or problem.disc.penalty_quadrature == "vertex":
        return NodePoints(problem)
    return QuadraturePoints(problem)


@dataclass(frozen=True)
class ContactMeasure:
    """The contact set ``{g ≤ tol}`` at a set of points ``x_k`` with weights ``w_k``.

    Attributes:
        area: ``Σ w_k √a(x_k)`` over the contact points.
        area_projected: ``Σ w_k`` over them.
        max_violation: ``max_k {g(x_k)}^-``.
        min_gap: ``min_k g(x_k)``.
        count: the number of contact points.
        points: where: ``"vertices"``, ``"nodes"`` or ``"quadrature points"``.
    """

    area: float
    area_projected: float
    max_violation: float
    min_gap: float
    count: int
    points: str


class ContactPoints:
    """The gap of ``problem.zeta`` at a set of points with weights, and the contact there.

    Attributes:
        kind: ``"vertices"``, ``"nodes"`` or ``"quadrature points"``.
        values: the gap at the points (a Function, refreshed by :meth:`gap`).
        mass: ``w_k √a(x_k)`` at the owned points (P1 vertices: ``∫ φ_i √a dy``, vertex rule).
        mass_projected: ``w_k`` at the owned points.
    """

    kind: str
    values: dolfinx.fem.Function
    mass: np.ndarray
    mass_projected: np.ndarray

    def __init__(self, problem: Any, space: dolfinx.fem.FunctionSpace) -> None:
        self.problem = problem
        self.comm: MPI.Comm = problem.mesh.comm
        self.space = space
        self.n = space.dofmap.index_map.size_local
        self.values = dolfinx.fem.Function(space, name="gap")
        self._expr = dolfinx.fem.Expression(problem.g, space.element.interpolation_points)

    def gap(self) -> np.ndarray:
        """``g(ζ)`` at the owned points, from the current ``problem.zeta``."""
        self.values.interpolate(self._expr)
        self.values.x.scatter_forward()
        return self.values.x.array[: self.n]

    def measure(self, tol: float) -> ContactMeasure:
        """The contact set ``{g ≤ tol}`` at the points and its measures (global values)."""
        g = self.gap()
        mask = g <= tol
        comm = self.comm
        area = comm.allreduce(float(self.mass[mask].sum()), op=MPI.SUM)
        projected = comm.allreduce(float(self.mass_projected[mask].sum()), op=MPI.SUM)
        count = comm.allreduce(int(mask.sum()), op=MPI.SUM)
        min_gap = float(comm.allreduce(float(np.min(g, initial=np.inf)), op=MPI.MIN))
        return ContactMeasure(
            float(area), float(projected), max(-min_gap, 0.0), min_gap, int(count), self.kind
        )

    def indicator(self, tol: float, out: dolfinx.fem.Function) -> dolfinx.fem.Function:
        """``out`` (a P1 Function) ← the contact flags ``g ≤ tol`` of the points, lumped onto
        the vertices: ``Σ_k w_k φ_i(x_k) [g_k ≤ tol] / Σ_k w_k φ_i(x_k)`` (1 or 0 at the P1
        vertices; its ½ level line is the contact set's outline)."""
        self.gap()
        self._lump((self.values.x.array <= tol).astype(float), out)
        return out

    def _lump(self, flags: np.ndarray, out: dolfinx.fem.Function) -> None:
        """:meth:`indicator`'s lumping of the point ``flags`` (local, ghosts included) onto
        ``out``'s vertices."""
        P1 = out.function_space
        mesh = self.problem.mesh
        cells = mesh.topology.index_map(mesh.topology.dim).size_local
        point_dofs = self.space.dofmap.list[:cells]
        chi = flags[point_dofs]
        w = self._cell_weights(point_dofs)
        X = self.space.element.interpolation_points  # the points on the reference triangle
        phi = np.column_stack([1.0 - X[:, 0] - X[:, 1], X[:, 0], X[:, 1]])  # φ_j(x_k)
        vertex_dofs = P1.dofmap.list[:cells]
        num, den = dolfinx.la.vector(P1.dofmap.index_map), dolfinx.la.vector(P1.dofmap.index_map)
        np.add.at(num.array, vertex_dofs.ravel(), ((w * chi) @ phi).ravel())
        np.add.at(den.array, vertex_dofs.ravel(), (w @ phi).ravel())
        for vec in (num, den):
            vec.scatter_reverse(dolfinx.la.InsertMode.add)
            vec.scatter_forward()
        out.x.array[:] = np.divide(
            num.array, den.array, out=np.zeros_like(num.array), where=den.array > 0
        )

    def _cell_weights(self, point_dofs: np.ndarray) -> np.ndarray:
        """The weights ``w_k √a(x_k)`` of each owned cell's points, shape of ``point_dofs``."""
        raise NotImplementedError


class NodePoints(ContactPoints):
    """The Lagrange nodes of ``problem.zeta``'s space with their lumped masses."""

    def __init__(self, problem: Any) -> None:
        mesh = problem.mesh
        degree = problem.disc.degree
        super().__init__(problem, dolfinx.fem.functionspace(mesh, ("Lagrange", degree)))
        self.kind = "vertices" if degree == 1 else "nodes"
        sqrt_a = problem.G.sqrt_a
        if degree == 1:  # m_i = ∫ φ_i √a dy and ∫ φ_i dy with the vertex rule (docs/model.md §7)
            dxv = ufl.Measure(
                "dx", domain=mesh, metadata={"quadrature_rule": "vertex", "quadrature_degree": 1}
            )
            phi = ufl.TestFunction(self.space)
            self.mass = self._assemble_owned(phi * sqrt_a * dxv)
            self.mass_projected = self._assemble_owned(phi * dxv)
        else:
            self.mass = lumped_mass_p2(self.space, sqrt_a)[: self.n]
            self.mass_projected = lumped_mass_p2(self.space, 1.0)[: self.n]

    def _assemble_owned(self, linear_form: Any) -> np.ndarray:
        vec = dolfinx.fem.assemble_vector(dolfinx.fem.form(linear_form))
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        return vec.array[: self.n].copy()

    def indicator(self, tol: float, out: dolfinx.fem.Function) -> dolfinx.fem.Function:
        if self.kind == "vertices":  # the points are out's own dofs
            self.gap()
            out.x.array[:] = (self.values.x.array <= tol).astype(float)
            return out
        return super().indicator(tol, out)

    def _cell_weights(self, point_dofs: np.ndarray) -> np.ndarray:
        """Each cell's share of ``∫_T √a dy`` at its nodes (:func:`lumped_mass_p2`)."""
        return _cell_integrals(self.problem.mesh, self.problem.G.sqrt_a)[:, None] * P2_SHARE


class QuadraturePoints(ContactPoints):
    """The Gauss points of the penalty's rule, ``w_k`` the rule's weights times ``|det J|``."""

    kind = "quadrature points"

    def __init__(self, problem: Any) -> None:
        super().__init__(problem, quadrature_space(problem))
        r = ufl.TestFunction(self.space)
        dxq = problem.dx_penalty
        self.mass = self._assemble_owned(problem.G.sqrt_a * r * dxq)
        self.mass_projected = self._assemble_owned(r * dxq)

    def _assemble_owned(self, linear_form: Any) -> np.ndarray:
        return dolfinx.fem.assemble_vector(dolfinx.fem.form(linear_form)).array[: self.n].copy()

    def _cell_weights(self, point_dofs: np.ndarray) -> np.ndarray:
        local = np.zeros(self.values.x.array.size)
        local[: self.n] = self.mass
        return local[point_dofs]


P2_SHARE = np.array([1 / 12] * 3 + [1 / 4] * 3)
"""The share of a triangle's measure at its P2 nodes (basix: the vertices, then the edges)."""


def _cell_integrals(mesh: dolfinx.mesh.Mesh, f: Any) -> np.ndarray:
    """``∫_T f dy`` of the owned cells."""
    DG0 = dolfinx.fem.functionspace(mesh, ("DG", 0))
    w = dolfinx.fem.assemble_vector(
        dolfinx.fem.form(ufl.TestFunction(DG0) * f * ufl.dx(domain=mesh))
    ).array
    cells = np.arange(mesh.topology.index_map(mesh.topology.dim).size_local)
    return w[DG0.dofmap.list[cells, 0]]


def lumped_mass_p2(S: dolfinx.fem.FunctionSpace, f: Any) -> np.ndarray:
    """Positive lumped masses of the P2 nodes of ``S`` (local, ghosts included) for the
    density ``f`` (``√a``: the surface's; 1: the projected).

    The P2 nodes of a triangle are the vertices of its uniform refinement into four
    triangles, so the P1 lumping on that refinement gives each vertex ``1/12`` and each edge
    midpoint ``1/4`` of ``∫_T f dy`` (whereas ``∫ φ_i f dy`` vanishes or is negative at
    the vertices for P2's own basis, no divisor for a pressure).
    """
    mesh = S.mesh
    per_cell = _cell_integrals(mesh, f)
    dofs = S.dofmap.list[: per_cell.size]
    mass = dolfinx.la.vector(S.dofmap.index_map)
    np.add.at(mass.array, dofs.reshape(-1), (per_cell[:, None] * P2_SHARE[None, :]).reshape(-1))
    mass.scatter_reverse(dolfinx.la.InsertMode.add)
    mass.scatter_forward()
    return mass.array.copy()
