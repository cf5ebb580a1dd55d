"""A cheap approximate solve with the stiffness: Galerkin on a coarse background grid.

The contact zone (:mod:`shellobstacle.solvers.zone`) must be known before its
factorization; before any contact it is where the first Newton step ``δ = K⁻¹ r`` would
penetrate the obstacle. That set needs only an approximation of ``δ``: the Galerkin
projection onto the piecewise-linear functions of a uniform triangle grid over the bounding
box of the domain, ``H ≈ 4h`` (about 1/16 of the nodes, and at most ``max_nodes`` grid nodes:
the grid must resolve the contact region, not the mesh),

    δ̃ = P (Pᵀ K P)⁻¹ Pᵀ r,

where ``P`` interpolates the grid's nodal values at the dofs of the displacement space (its
rows zero at the Dirichlet dofs, so ``P`` maps into the discrete space). For Koiter's model
the grid functions are C¹ quadratic B-splines instead: the interior penalty of its bending
energy makes the kinks of P1 hats so stiff that ``δ̃`` comes out far too small. ``δ̃`` is the best
approximation of ``δ`` in the energy norm from that subspace; it works for any mesh, domain
and degree, serially and in parallel, and costs one product ``PᵀKP`` and a Cholesky
factorization of a matrix about 1/16 the size of ``K``.
"""

from __future__ import annotations

import math

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np

from shellobstacle.solvers.base import direct_solver, factorize

__all__ = ["CoarseSpace"]


class CoarseSpace:
    """Galerkin approximation of ``K⁻¹`` on the P1 functions of a uniform background grid.

    Args:
        V: The displacement space (blocked, its dofs at points of the plane).
        K: The membrane stiffness on ``V`` (Dirichlet rows and columns identity).
        bcs: The homogeneous Dirichlet conditions of ``V``.
        ratio: About how many nodes of ``V`` per grid node (16: ``H ≈ 4h`` for P1).
        max_nodes: About the most grid nodes, whatever the mesh (the default, 10,000, makes
            ``H ≈ 0.01`` on the unit square and keeps the seed cheap on large meshes without
            changing the zone; meshes under 160,000 nodes keep ``H ≈ 4h``).
        smooth: tensor-product quadratic B-splines (C¹) instead of the grid's P1 hat
            functions: for Koiter's ``K``, whose interior penalty makes the hats' kinks stiff.
    """

    def __init__(
        self,
        V: dolfinx.fem.FunctionSpace,
        K: PETSc.Mat,
        bcs: list,
        ratio: float = 16.0,
        max_nodes: int = 10_000,
        smooth: bool = False,
    ) -> None:
        comm = V.mesh.comm
        imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
        n_own = imap.size_local
        x = V.tabulate_dof_coordinates()[:n_own, :2]
        lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
        if n_own:
            lo, hi = x.min(axis=0), x.max(axis=0)
        comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
        comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
        extent = np.maximum(hi - lo, 1e-300)
        nodes = max(imap.size_global, 1)
        ratio = max(ratio, nodes / max_nodes)
        spacing = math.sqrt(extent[0] * extent[1] * ratio / nodes)
        nx, ny = (max(1, math.ceil(e / spacing)) for e in extent)
        u = (x - lo) / extent * [nx, ny]
        if smooth:
            columns, weights, width = _quadratic_bsplines(u, nx, ny)
        else:
            columns, weights, width = _hats(u, nx, ny)
        # one row per owned dof (node b, component c: local row b·bs + c), zero where Dirichlet
        free = K.createVecLeft()
        free.set(1.0)
        dolfinx.fem.petsc.set_bc(free, bcs)  # (homogeneous conditions: 0 at the Dirichlet dofs)
        keep = free.array_r.reshape(n_own, bs) != 0.0
        free.destroy()
        rows = np.repeat(np.arange(n_own * bs, dtype=np.int64), columns.shape[1])
        cols = np.repeat(columns, bs, axis=0) * bs + np.tile(np.arange(bs), n_own)[:, None]
        vals = np.repeat(weights, bs, axis=0) * keep.reshape(-1, 1)
        cols, vals = cols.ravel(), vals.ravel()
        # grid functions used: those with weight (≥ 1/2 in all) at free dofs; renumbered
        mass = np.bincount(cols, weights=vals, minlength=width * bs)
        comm.Allreduce(MPI.IN_PLACE, mass, op=MPI.SUM)
        used = mass >= 0.5
        number = np.cumsum(used) - 1
        ok = used[cols] & (vals > 0.0)
        rows, cols, vals = rows[ok], number[cols[ok]], vals[ok]
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n_own * bs))])
        order = np.lexsort((cols, rows))
        self.size = int(used.sum())
        self.P = PETSc.Mat().createAIJ(
            ((n_own * bs, K.getSize()[0]), (PETSc.DECIDE, self.size)),
            csr=(
                indptr.astype(PETSc.IntType),
                cols[order].astype(PETSc.IntType),
                vals[order],
            ),
            comm=K.getComm(),
        )
        self.Kc = K.ptap(self.P)
        # PᵀKP is symmetric positive definite whenever it is nonsingular (K is): Cholesky
        self.ksp = direct_solver(self.Kc, "cholesky", "coarse")
        factorize(self.ksp, "the coarse grid's stiffness")
        self._rc = self.Kc.createVecRight()
        self._yc = self.Kc.createVecRight()

    def solve(self, r: PETSc.Vec, out: PETSc.Vec) -> None:
        """``out ← P (PᵀKP)⁻¹ Pᵀ r``."""
        self.P.multTranspose(r, self._rc)
        self.ksp.solve(self._rc, self._yc)
        self.P.mult(self._yc, out)

    def destroy(self) -> None:
        for obj in (self.P, self.Kc, self.ksp, self._rc, self._yc):
            obj.destroy()


def _hats(u: np.ndarray, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The P1 hat functions of the grid (cells split along the diagonal from ``(i, j)`` to
    ``(i+1, j+1)``) at the points ``u`` (grid units): their numbers and values, 3 per point,
    and how many there are."""
    i = np.clip(np.floor(u[:, 0]).astype(np.int64), 0, nx - 1)
    j = np.clip(np.floor(u[:, 1]).astype(np.int64), 0, ny - 1)
    s, t = u[:, 0] - i, u[:, 1] - j
    upper = s < t
    node = j * (nx + 1) + i
    corners = np.stack([node, np.where(upper, node + nx + 1, node + 1), node + nx + 2], 1)
    weights = np.stack(
        [np.where(upper, 1 - t, 1 - s), np.where(upper, t - s, s - t), np.where(upper, s, t)], 1
    )
    return corners, weights, (nx + 1) * (ny + 1)


def _quadratic_bsplines(u: np.ndarray, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The uniform quadratic B-splines ``B_k(u_1) B_l(u_2)`` (``nx + 2`` by ``ny + 2``, a
    partition of unity on the box) at the points ``u``: 9 numbers and values per point, and
    how many functions there are. In cell ``i`` with ``s = u − i`` the three nonzero
    B-splines of one direction are ``(1 − s)²/2``, ``(1 + 2s − 2s²)/2`` and ``s²/2``."""

    def one(v: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        i = np.clip(np.floor(v).astype(np.int64), 0, n - 1)
        s = v - i
        values = np.stack([(1 - s) ** 2 / 2, (1 + 2 * s - 2 * s**2) / 2, s**2 / 2], 1)
        return i[:, None] + np.arange(3), values

    kx, bx = one(u[:, 0], nx)
    ky, by = one(u[:, 1], ny)
    numbers = (ky[:, :, None] * (nx + 2) + kx[:, None, :]).reshape(-1, 9)
    values = (by[:, :, None] * bx[:, None, :]).reshape(-1, 9)
    return numbers, values, (nx + 2) * (ny + 2)
