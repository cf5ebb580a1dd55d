"""The contact of a solved problem: nodal gap, contact set and its area, displacements.

The contact set of a penalized solution is ``{y : g(ζ)(y) ≤ 0}`` with the gap
``g(ζ) = (θ + ζ_i a^i)·q`` (docs/model.md §3). It is measured on the vertices (docs/model.md §7,
batch 3): the sign of ``g`` at quadrature points is noise of order ``h²`` for P1. Its area is
the sum of the lumped (vertex-rule) masses of the contact vertices, with the surface element
``√a dy`` and projected (``dy``). Everything returned is global: the same on every rank.
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.geometry
import dolfinx.la
import numpy as np
import ufl

from shellobstacle.models.problem import PenalizedProblem
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
    displacement) and the lumped masses are compiled/assembled here and reused for every ``κ``
    and load parameter; each method reads the current ``problem.zeta``.

    Attributes:
        problem: The problem.
        P1: Scalar P1 space on the mesh (vertex values).
        gap: ``g(ζ)`` at the vertices (a P1 Function, refreshed by :meth:`nodal_gap`).
        contact_indicator: 1 on contact vertices, 0 elsewhere (refreshed by :meth:`indicator`).
        U: Cartesian displacement ``ζ_i a^i`` in the space of ``ζ`` (refreshed by
            :meth:`cartesian_displacement`).
        mass: Lumped masses ``∫ φ_i √a dy`` of the owned vertices (vertex quadrature).
        mass_projected: Lumped masses ``∫ φ_i dy`` of the owned vertices.
        gap_scale: ``max θ·q`` over the mesh vertices (scale of the contact tolerance).
    """

    def __init__(self, problem: PenalizedProblem) -> None:
        self.problem = problem
        mesh = problem.mesh
        self.comm: MPI.Comm = mesh.comm
        self.P1 = dolfinx.fem.functionspace(mesh, ("Lagrange", 1))
        self.gap = dolfinx.fem.Function(self.P1, name="gap")
        self.contact_indicator = dolfinx.fem.Function(self.P1, name="contact")
        self.U = dolfinx.fem.Function(problem.V, name="U")
        self._gap_expr = dolfinx.fem.Expression(problem.g, self.P1.element.interpolation_points)
        zeta = problem.zeta
        U = ufl.as_vector(problem.G.cartesian([zeta[i] for i in range(3)]))
        self._U_expr = dolfinx.fem.Expression(U, problem.V.element.interpolation_points)

        # lumped masses m_i = ∫ φ_i √a dy and ∫ φ_i dy with the vertex rule (docs/model.md §7)
        dxv = ufl.Measure(
            "dx", domain=mesh, metadata={"quadrature_rule": "vertex", "quadrature_degree": 1}
        )
        phi = ufl.TestFunction(self.P1)
        self.mass = self._assemble_owned(phi * problem.G.sqrt_a * dxv)
        self.mass_projected = self._assemble_owned(phi * dxv)

        n_owned = self.P1.dofmap.index_map.size_local
        points = self.P1.tabulate_dof_coordinates()[:n_owned]
        theta = problem.shell.surface.theta_numpy(points)
        theta_q = sum(theta[k] * problem.q[k] for k in range(3))
        self.gap_scale = _global_max(self.comm, np.abs(theta_q), 0.0)
        self._trees: dict[tuple[str, float], dolfinx.geometry.BoundingBoxTree] = {}

    def _assemble_owned(self, linear_form: Any) -> np.ndarray:
        """Assemble a P1 linear form and return its owned entries (ghost contributions added)."""
        vec = dolfinx.fem.assemble_vector(dolfinx.fem.form(linear_form))
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        return vec.array[: self.P1.dofmap.index_map.size_local].copy()

    def nodal_gap(self) -> dolfinx.fem.Function:
        """``g(ζ) = (θ + ζ_i a^i)·q`` at the mesh vertices (docs/model.md §3), as a P1 Function.

        For P2 ``ζ`` these are still the vertex values (the P1 interpolation points).
        """
        self.gap.interpolate(self._gap_expr)
        self.gap.x.scatter_forward()
        return self.gap

    def tolerance(self, tol_rel: float = 1e-12) -> float:
        """The contact threshold ``tol_rel · max θ·q``: a vertex touches if ``g ≤`` this."""
        return tol_rel * self.gap_scale

    def _contact_mask(self, tol_rel: float) -> np.ndarray:
        """Contact flags of all local P1 dofs (owned and ghost), from a fresh nodal gap."""
        return self.nodal_gap().x.array <= self.tolerance(tol_rel)

    def contact(self, tol_rel: float = 1e-12) -> dict[str, float | int]:
        """The contact set ``{g(ζ) ≤ tol}`` at the vertices and its measures (docs/model.md §7).

        Args:
            tol_rel: Tolerance relative to ``max θ·q``.

        Returns:
            ``contact_area`` (``Σ`` lumped ``∫ φ_i √a dy`` over contact vertices),
            ``contact_area_projected`` (same with ``∫ φ_i dy``), ``max_violation``
            (``max {g}^-`` over vertices), ``min_gap``, ``num_contact_nodes`` and ``tol``;
            global values.
        """
        n_owned = self.P1.dofmap.index_map.size_local
        mask = self._contact_mask(tol_rel)[:n_owned]
        g = self.gap.x.array[:n_owned]
        comm = self.comm
        area = comm.allreduce(float(self.mass[mask].sum()), op=MPI.SUM)
        projected = comm.allreduce(float(self.mass_projected[mask].sum()), op=MPI.SUM)
        count = comm.allreduce(int(mask.sum()), op=MPI.SUM)
        min_gap = _global_min(comm, g)
        return {
            "contact_area": float(area),
            "contact_area_projected": float(projected),
            "max_violation": max(-min_gap, 0.0),
            "min_gap": min_gap,
            "num_contact_nodes": int(count),
            "tol": self.tolerance(tol_rel),
        }

    def indicator(self, tol_rel: float = 1e-12) -> dolfinx.fem.Function:
        """The contact indicator: a P1 Function, 1 on contact vertices, 0 elsewhere."""
        self.contact_indicator.x.array[:] = self._contact_mask(tol_rel).astype(float)
        return self.contact_indicator

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
