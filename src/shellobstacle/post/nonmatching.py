"""Norms of the difference of two solutions on unrelated meshes (docs/model.md §2: ``V_M``).

An adapted reference mesh is neither a refinement of a uniform mesh nor refined by it, so a
solution on one cannot be interpolated exactly into the other's space. :class:`SampledNorms`
integrates on the reference mesh with a Gauss rule instead: the other solution's values and
(cellwise constant, for P1) gradients are evaluated at the rule's points of every reference
cell. Where the other mesh is coarser around a point (the reference is locally a
refinement of it) the integrand is a polynomial on the reference cell and the rule is exact;
elsewhere the rule samples a function with kinks inside the cell, an error of the rule's
order in the size of the reference cell.
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import basix.ufl
import dolfinx
import dolfinx.fem
import numpy as np
import ufl

from shellobstacle.mesh.transfer import Interpolation

__all__ = ["SampledNorms"]


class SampledNorms:
    """``‖u − u_ref‖`` in ``V_M``, full ``H¹`` and ``L²`` for ``u`` on any mesh of the same
    domain, integrated on the mesh of ``u_ref`` (collective).

    Args:
        reference: a vector Function (three components) on the reference mesh.
        quadrature_degree: degree of the Gauss rule on the reference cells.
    """

    def __init__(self, reference: dolfinx.fem.Function, quadrature_degree: int = 2) -> None:
        self.reference = reference
        mesh = reference.function_space.mesh
        self.mesh = mesh
        cell = mesh.basix_cell()
        self.Qv = dolfinx.fem.functionspace(
            mesh, basix.ufl.quadrature_element(cell, value_shape=(3,), degree=quadrature_degree)
        )
        self.Qg = dolfinx.fem.functionspace(
            mesh, basix.ufl.quadrature_element(cell, value_shape=(3, 2), degree=quadrature_degree)
        )
        self.values = dolfinx.fem.Function(self.Qv)
        self.gradients = dolfinx.fem.Function(self.Qg)
        dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": quadrature_degree})
        e = self.values - reference
        de = self.gradients - ufl.grad(reference)
        values = [e[i] ** 2 for i in range(3)]
        grads = [de[i, 0] ** 2 + de[i, 1] ** 2 for i in range(3)]
        self.forms = {
            "l2": dolfinx.fem.form(sum(values) * dx),
            "h1": dolfinx.fem.form((sum(values) + sum(grads)) * dx),
            "vm": dolfinx.fem.form((sum(values) + grads[0] + grads[1]) * dx),
        }
        self._into = Interpolation(self.Qv)  # the Gauss points located in each source mesh
        self._source: tuple[Any, ...] | None = None  # the last sampled u, its gradient's space

    def _sample(self, u: dolfinx.fem.Function) -> None:
        """Fill the point values and gradients of ``u`` on the reference's Gauss points."""
        V = u.function_space
        if self._source is None or self._source[0] is not u:
            degree = V.ufl_element().embedded_superdegree
            G = dolfinx.fem.functionspace(V.mesh, ("DG", max(degree - 1, 0), (3, 2)))
            expr = dolfinx.fem.Expression(ufl.grad(u), G.element.interpolation_points)
            self._source = (u, dolfinx.fem.Function(G), expr)
            self._into.forget()  # only the last source is kept
        _, grad, expr = self._source
        grad.interpolate(expr)
        grad.x.scatter_forward()
        # the values and gradients share the points (one rule), hence their owners
        data = self._into.data(V)
        self.values.interpolate_nonmatching(u, self._into.cells, data)
        self.gradients.interpolate_nonmatching(grad, self._into.cells, data)

    def __call__(self, u: dolfinx.fem.Function) -> dict[str, float]:
        """The norms of ``u − u_ref`` (global; the same on every rank)."""
        self._sample(u)
        out = {}
        for name, form in self.forms.items():
            local = dolfinx.fem.assemble_scalar(form)
            out[name] = float(np.sqrt(max(self.mesh.comm.allreduce(local, op=MPI.SUM), 0.0)))
        return out
