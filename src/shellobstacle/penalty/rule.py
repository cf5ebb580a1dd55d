"""The penalty's quadrature rule (docs/model.md §5): the Gauss rule of the membrane integrals
(degree ``Discretization.qdegree``, the paper's) or the vertex rule (nodal, mass-lumped; P1),
as a UFL measure for the forms and as reference points and weights for the point operators
(:mod:`~shellobstacle.solvers.quadrature_penalty`)."""

from __future__ import annotations

from typing import Any

from mpi4py import MPI  # noqa: F401  (MPI before DOLFINx)

import basix
import basix.ufl
import dolfinx
import dolfinx.fem
import numpy as np
import ufl

from shellobstacle.spec import Discretization

__all__ = ["penalty_measure", "penalty_rule", "quadrature_space", "reference_rule"]


def penalty_measure(mesh: dolfinx.mesh.Mesh, disc: Discretization, dx: ufl.Measure) -> ufl.Measure:
    """The measure of the penalty integral on ``mesh``: the vertex rule, or ``dx`` (the
    membrane's Gauss rule of degree ``disc.qdegree``) itself."""
    if disc.penalty_quadrature == "vertex":
        return ufl.Measure(
            "dx", domain=mesh, metadata={"quadrature_rule": "vertex", "quadrature_degree": 1}
        )
    return dx


def reference_rule(cell: basix.CellType, disc: Discretization) -> tuple[np.ndarray, np.ndarray]:
    """The reference points and weights of the rule :func:`penalty_measure` integrates with:
    the vertices with equal weights, or the Gauss rule of degree ``disc.qdegree``."""
    if disc.penalty_quadrature == "vertex":
        points = basix.geometry(cell)
        volume = basix.cell.volume(cell)
        return points, np.full(points.shape[0], volume / points.shape[0])
    return basix.make_quadrature(cell, disc.qdegree)


def penalty_rule(problem: Any) -> tuple[np.ndarray, np.ndarray]:
    """The reference points and weights of the problem's penalty rule
    (:func:`~shellobstacle.penalty.rule.reference_rule`)."""
    return reference_rule(problem.mesh.basix_cell(), problem.disc)


def quadrature_space(problem: Any) -> dolfinx.fem.FunctionSpace:
    """Scalar quadrature space whose points are those of the problem's penalty rule."""
    points, weights = penalty_rule(problem)
    element = basix.ufl.quadrature_element(
        problem.mesh.basix_cell(), points=points, weights=weights
    )
    return dolfinx.fem.functionspace(problem.mesh, element)
