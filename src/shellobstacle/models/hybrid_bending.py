"""Koiter's bending energy with a facet multiplier: the hybrid interior-penalty form.

The C⁰ interior-penalty terms of :mod:`shellobstacle.models.koiter` couple the dofs of the two
cells of every facet directly. Here each cell instead meets a multiplier ``t_F`` of its
facets, the normal derivative ``∂ζ_3/∂n_F`` at the facet's midpoint (a Crouzeix–Raviart
function, single-valued there), and the facet terms are taken at the midpoints
(:eq:`koiter-hybrid`)::

    E_b(η, t) = ½ Σ_T ∫_T m^{αβ}(η) ρ_αβ(η) √a dy
                + Σ_T Σ_{F ⊂ ∂T} |F| ( −M_nn(η) e_T + ½ (σ / h_T) C_F e_T² )(m_F),
    e_T = ∂_{n_T} η_3 − (n_T · n_F) t_F,

with ``t_F = 0`` on the clamped boundary (where ``e_T = ∂_n η_3``) and no term on the
facets of a simply supported or free edge (:mod:`~shellobstacle.models.edges`). It
penalizes the jump of the normal derivative's mean over each facet, a stable choice for P2
(a continuous P2 function with zero broken Hessian and zero mean jumps is affine).

The method is consistent to O(h), not exactly (docs/model.md §8, :eq:`hybrid-consistency`).
For the exact solution and ``t_F = ∂_{n_F} ζ_3(m_F)`` every ``e_T`` vanishes and the
multipliers' equations hold, but a test displacement ``v`` meets the moment term
``−|F| M_nn(ζ)(m_F) ∂_{n_T} v_3(m_F)``, the midpoint rule of the ``−∫_F M_nn(ζ) ∂_{n_T} v_3 ds``
that integration by parts leaves. The rule's error on ``M_nn(ζ) [∂_n v_3]`` (linear jump for
P2) sums to ``|r(v)| ≤ C h ‖M_nn(ζ)‖_{W^{2,∞}} (Σ_F ‖[∂_n v_3]‖²_F / |F|)^{1/2}``: O(h) in the
energy norm, the order of P2's own error there, so the rate h is kept.

Each term lives on one cell and one facet: the stiffness::

    [[A, B], [Bᵀ, C]]  (ζ, t),   C diagonal,

has the stencil of P2 Lagrange plus one unknown per facet, and the stiffness in ζ alone is
its Schur complement ``K = A − B C⁻¹ Bᵀ`` (:class:`CondensedStiffness`). A Cholesky factor of
the block matrix takes a fifth of the flops of one of the interior penalty's stiffness at
equal dofs (``benchmarks/koiter_factor.py``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

from mpi4py import MPI  # noqa: F401  (before PETSc: the MPI runtime PETSc links to)
from petsc4py import PETSc

import basix.ufl
import dolfinx
import dolfinx.fem.petsc
import numpy as np
import ufl

from shellobstacle.geometry.surface import Geometry
from shellobstacle.models.koiter import (
    bending_moment,
    change_of_curvature,
    facet_stiffness,
    normal_normal,
)
from shellobstacle.models.membrane import elastic_product

__all__ = [
    "DEFAULT_HYBRID_PENALTY",
    "CondensedStiffness",
    "FacetMidpoints",
    "drop_zeros",
    "facet_midpoints",
    "facet_normals",
    "hybrid_bending_energy",
]

DEFAULT_HYBRID_PENALTY = 16.0
"""``σ`` of the hybrid form with ``h_T`` the cell's diameter: with the multiplier eliminated
from two equal cells it penalizes the mean jump as the interior-penalty form's σ = 8 does."""


def facet_normals(mesh: dolfinx.mesh.Mesh) -> dolfinx.fem.Function:
    """``n_F``: a unit normal of every facet, oriented the same way on every rank (towards
    the half-plane of a fixed direction), as a vector Crouzeix–Raviart function (exact at
    the midpoints)."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim, tdim - 1)
    mesh.topology.create_connectivity(tdim - 1, tdim)
    N = dolfinx.fem.Function(dolfinx.fem.functionspace(mesh, ("CR", 1, (tdim,))))
    cell_map, facet_map = mesh.topology.index_map(tdim), mesh.topology.index_map(tdim - 1)
    num_cells = cell_map.size_local + cell_map.num_ghosts
    c2f = mesh.topology.connectivity(tdim, tdim - 1).array.reshape(num_cells, -1)
    facets = np.arange(facet_map.size_local + facet_map.num_ghosts, dtype=np.int32)
    nodes = dolfinx.mesh.entities_to_geometry(mesh, tdim - 1, facets)
    x = mesh.geometry.x[nodes][:, :, :2]
    tangent = x[:, 1] - x[:, 0]
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    normal[normal @ _ORIENTATION < 0] *= -1
    dofs = N.function_space.dofmap.list[:num_cells]
    N.x.array.reshape(-1, tdim)[dofs.ravel()] = normal[c2f.ravel()]
    return N


_ORIENTATION = np.array([1.0, np.sqrt(2.0) / 3.0])  # no mesh facet is normal to it


class FacetMidpoints(NamedTuple):
    """The midpoints of each cell's facets as a quadrature rule of cell integrals, and the
    cell's outward unit normal ``n_T`` and the facet's length ``|F|`` there."""

    dx: ufl.Measure  #: ``Σ_T Σ_{F ⊂ ∂T} |det J_T| f(m_F)`` (weight 1 per midpoint)
    normal: dolfinx.fem.Function  #: ``n_T``, a broken vector Crouzeix–Raviart function
    length: dolfinx.fem.Function  #: ``|F|``, a broken Crouzeix–Raviart function


def facet_midpoints(mesh: dolfinx.mesh.Mesh, dropped: np.ndarray | None = None) -> FacetMidpoints:
    """:class:`FacetMidpoints` of an affine triangle mesh.

    Each cell integrates its facet terms in its own kernel (one matrix insertion per cell,
    where a facet measure inserts once per facet of each cell). Broken Crouzeix–Raviart
    functions hold a value per cell and facet, exact at the facet's midpoint. ``dropped``:
    boundary facets (local, owned and ghost) whose rotation is free (simply supported or free
    edges, :func:`~shellobstacle.models.edges.free_rotation_facets`): their ``|F|`` is 0, so
    the form has no facet term there."""
    if mesh.topology.cell_type != dolfinx.mesh.CellType.triangle:
        raise ValueError("the hybrid bending form needs a triangle mesh")
    if mesh.geometry.cmaps[0].degree != 1:
        raise ValueError("the hybrid bending form needs an affine mesh (degree 1 geometry)")
    # reference facet k joins the vertices other than k; its midpoint
    ends = np.array([[1, 2], [0, 2], [0, 1]])
    points = np.array([[0.5, 0.5], [0.0, 0.5], [0.5, 0.0]])
    tdim = mesh.topology.dim
    cells = mesh.topology.index_map(tdim)
    num_cells = cells.size_local + cells.num_ghosts
    x = mesh.geometry.x[mesh.geometry.dofmaps[0][:num_cells]][:, :, :2]  # (cell, vertex, xy)
    tangent = x[:, ends[:, 1]] - x[:, ends[:, 0]]  # (cell, facet, xy)
    length = np.linalg.norm(tangent, axis=2)
    normal = np.stack([tangent[..., 1], -tangent[..., 0]], axis=2) / length[..., None]
    inward = x[:, [0, 1, 2]] - x[:, ends[:, 0]]  # from the facet to the opposite vertex
    normal[np.einsum("cfi,cfi->cf", normal, inward) > 0] *= -1
    if dropped is not None and len(dropped):
        mesh.topology.create_connectivity(tdim, tdim - 1)
        c2f = mesh.topology.connectivity(tdim, tdim - 1).array.reshape(-1, 3)[:num_cells]
        length[np.isin(c2f, dropped)] = 0.0
    out = []
    for shape, values in (((2,), normal), ((), length)):
        element = basix.ufl.element("CR", mesh.basix_cell(), 1, shape=shape, discontinuous=True)
        u = dolfinx.fem.Function(dolfinx.fem.functionspace(mesh, element))
        dofs = u.function_space.dofmap.list[:num_cells]
        u.x.array.reshape(-1, *shape)[dofs.ravel()] = values.reshape(-1, *shape)
        out.append(u)
    rule = {"quadrature_rule": "custom", "quadrature_points": points,
            "quadrature_weights": np.ones(3)}  # fmt: skip
    return FacetMidpoints(ufl.Measure("dx", domain=mesh, metadata=rule), *out)


def hybrid_bending_energy(
    G: Geometry,
    epsilon: Any,
    lam: Any,
    mu: Any,
    zeta: Any,
    t: Any,
    n_F: Any,
    dx: ufl.Measure,
    midpoints: FacetMidpoints,
    sigma: Any,
) -> ufl.Form:
    """The hybrid bending energy ``E_b(ζ, t)`` of the module docstring (UFL).

    Args:
        G: UFL geometry of θ (with third derivatives).
        epsilon, lam, mu: half-thickness and Lamé constants.
        zeta: the displacement, a vector Lagrange function (covariant components).
        t: the facet multiplier, a Crouzeix–Raviart function (``∂ζ_3/∂n_F`` at midpoints,
            0 on the clamped boundary).
        n_F: the facets' normals (:func:`facet_normals`).
        dx: cell measure; midpoints: :func:`facet_midpoints`.
        sigma: the penalty ``σ`` (a number or a ``Constant``).
    """
    mesh = zeta.function_space.mesh
    eta = [zeta[i] for i in range(3)]
    grad = ufl.grad(zeta)
    grad_eta = [[grad[i, a] for a in range(2)] for i in range(3)]
    hess = ufl.grad(ufl.grad(zeta[2]))
    rho = change_of_curvature(G, eta, grad_eta, [[hess[a, b] for b in range(2)] for a in range(2)])
    m = bending_moment(G, epsilon, lam, mu, rho)
    cells = 0.5 * (epsilon**3 / 3) * elastic_product(G, lam, mu, rho, rho) * G.sqrt_a * dx

    n = midpoints.normal
    h = ufl.CellDiameter(mesh)
    e = ufl.dot(ufl.grad(zeta[2]), n) - ufl.dot(n, n_F) * t  # ∂_{n_T} η_3 − (n_T·n_F) t_F
    M_nn = G.sqrt_a * normal_normal(m, n)
    C_F = facet_stiffness(G, epsilon, lam, mu, n)
    weight = midpoints.length / abs(ufl.JacobianDeterminant(mesh))  # |F| per midpoint
    return cells + weight * (-M_nn * e + 0.5 * (sigma / h) * C_F * e * e) * midpoints.dx


def drop_zeros(A: PETSc.Mat) -> PETSc.Mat:
    """A new assembled AIJ matrix with the nonzero entries of ``A`` (its owned rows, the
    same layout) and block size 1.

    DOLFINx gives ``B`` the pattern of every dof of a cell against the multipliers of all
    its facets; a term of the hybrid form reads one facet's midpoint, where the other facets'
    Crouzeix–Raviart functions vanish, so the rest of that pattern holds exact zeros, which
    would cost a factorization fill."""
    indptr, cols, values = A.getValuesCSR()
    keep = values != 0
    kept = np.concatenate(([0], np.cumsum(keep, dtype=PETSc.IntType)))
    B = PETSc.Mat().createAIJ(
        size=A.getSizes(),
        csr=(kept[indptr].astype(PETSc.IntType), cols[keep], values[keep]),
        comm=A.comm,
    )
    B.assemble()
    return B


class CondensedStiffness:
    """The blocks ``A`` (ζ, ζ), ``B`` (ζ, t) and ``C`` (t, t, diagonal) of a hybrid stiffness
    and its Schur complement ``K = A − B C⁻¹ Bᵀ`` in ζ (Dirichlet rows and columns of the
    identity, from ``A``).

    ``A`` has the pattern of the cells (the penalty's Hessian, added to ``K`` later, lives
    there), ``B`` its nonzeros only, ``K`` the pattern of the two cells of each facet.

    Args:
        forms: the compiled bilinear forms ``a_zz``, ``a_zt`` and ``a_tt``, by those names.
        bcs: Dirichlet conditions of ζ; bcs_t: those of ``t`` (the clamped boundary's facets).
    """

    def __init__(
        self,
        forms: dict[str, dolfinx.fem.Form],
        bcs: list[dolfinx.fem.DirichletBC],
        bcs_t: list[dolfinx.fem.DirichletBC],
    ) -> None:
        self.A = dolfinx.fem.petsc.assemble_matrix(forms["a_zz"], bcs=bcs)
        self.A.assemble()
        B = dolfinx.fem.petsc.assemble_matrix(forms["a_zt"], bcs=bcs + bcs_t)
        B.assemble()
        self.B = drop_zeros(B)
        C = dolfinx.fem.petsc.assemble_matrix(forms["a_tt"], bcs=bcs_t)
        C.assemble()
        self.c = C.getDiagonal()  # C is diagonal: each t_F meets only itself, at m_F
        C.destroy()
        root = self.c.copy()
        root.reciprocal()
        root.sqrtabs()
        scaled = B.transpose(PETSc.Mat())
        B.destroy()
        scaled.diagonalScale(L=root)  # C^{-1/2} Bᵀ
        # B C⁻¹ Bᵀ from DOLFINx's pattern of B (every dof of a cell against each of its
        # facets): its pattern holds every cell's, so A adds into it
        self.K = scaled.transposeMatMult(scaled)
        self.K.scale(-1.0)
        self.K.axpy(1.0, self.A, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        for obj in (scaled, root):
            obj.destroy()

    def multiplier(self, zeta: PETSc.Vec, t: PETSc.Vec) -> None:
        """``t ← −C⁻¹ Bᵀ ζ``: the multiplier that minimizes the energy at ``ζ``."""
        self.B.multTranspose(zeta, t)
        t.pointwiseDivide(t, self.c)
        t.scale(-1.0)

    def destroy(self) -> None:
        for obj in (self.A, self.B, self.c, self.K):
            obj.destroy()
