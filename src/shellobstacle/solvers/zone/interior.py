"""Solves with ``K_II``, the stiffness outside the contact zone, from one factorization.

For the hybrid bending form (:mod:`shellobstacle.hybrid_bending`) the stiffness is the
Schur complement ``K = A − B C⁻¹ Bᵀ`` of a block matrix in ``(ζ, t)`` with ``C`` diagonal, and
so is ``K_II`` of ``H_I = [[A_II, B_I], [B_Iᵀ, C]]`` (``B_I``: the rows I of ``B``, every
multiplier). ``H_I`` is factorized instead of ``K_II``: the same solves (``t``'s right-hand
side zero, its part of the solution dropped) and the same selected inverse entries
(``[K_II⁻¹]`` is the ``(ζ, ζ)`` block of ``H_I⁻¹``), at a fraction of the fill, because each
row of ``H_I`` couples one cell's dofs and its facets' multipliers, where ``K``'s rows reach
across the facets.
"""

from __future__ import annotations

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.hybrid_bending import CondensedStiffness
from shellobstacle.solvers.base import direct_solver, factorize
from shellobstacle.solvers.mumps import inverse_block

__all__ = ["InteriorFactor", "block_matrix"]


def block_matrix(hybrid: CondensedStiffness, isI: PETSc.IS) -> tuple[PETSc.Mat, PETSc.IS]:
    """``H_I = [[A_II, B_I], [B_Iᵀ, C]]`` as one AIJ matrix (each rank's rows: its rows of I,
    then its multipliers) and the rows of ``ζ_I`` in it."""
    comm = hybrid.B.getComm()
    t0, t1 = hybrid.B.getOwnershipRangeColumn()
    isT = PETSc.IS().createStride(t1 - t0, t0, 1, comm=comm)
    A_II = hybrid.A.createSubMatrix(isI, isI)
    B_I = hybrid.B.createSubMatrix(isI, isT)
    Bt_I = B_I.transpose(PETSc.Mat())
    C = PETSc.Mat().createAIJ(((t1 - t0, None), (t1 - t0, None)), nnz=(1, 0), comm=comm)
    C.setDiagonal(hybrid.c)
    C.assemble()
    nest = PETSc.Mat().createNest([[A_II, B_I], [Bt_I, C]], comm=comm)
    rows = nest.getNestISs()[0][0].duplicate()
    H = nest.convert("aij", PETSc.Mat())
    for obj in (nest, A_II, B_I, Bt_I, C, isT):
        obj.destroy()
    return H, rows


class InteriorFactor:
    """A factorization that solves with ``K_II`` (``isI``: the owned dofs of I).

    Args:
        K: the stiffness (parallel).
        isI: the owned rows of ``I``, in ``K``'s numbering.
        factorization: MUMPS ``"lu"`` or ``"cholesky"``.
        hybrid: the blocks of a hybrid stiffness (None: factorize ``K_II`` itself).
    """

    def __init__(
        self,
        K: PETSc.Mat,
        isI: PETSc.IS,
        factorization: str,
        hybrid: CondensedStiffness | None = None,
    ) -> None:
        self.comm: MPI.Comm = K.getComm().tompi4py()
        self._kept: list = []
        if hybrid is None:
            M = K.createSubMatrix(isI, isI)
            self.size = M.getSize()[0]
            self.isZeta = None
        else:
            M = self._block_matrix(hybrid, isI)
        ksp = direct_solver(M, factorization, "zone")
        factorize(ksp, "K_II")
        self.F = ksp.getPC().getFactorMatrix()
        self.n = M.getSize()[0]
        # Only a serial LU leaves the matrix entries in the matrix' own arrays (PETSc's MUMPS
        # interface copies them for Cholesky and for distributed matrices): otherwise the
        # matrix is not needed once factorized
        if factorization == "lu" and self.comm.size == 1:
            self._kept = [M, ksp]
        else:
            ksp.destroy()
            M.destroy()
        if self.isZeta is not None:
            self.b, self.x = self.F.createVecRight(), self.F.createVecLeft()
            self._kept += [self.b, self.x, self.isZeta]

    def _block_matrix(self, hybrid: CondensedStiffness, isI: PETSc.IS) -> PETSc.Mat:
        """``H_I``, and where ``K_II``'s rows are in it."""
        H, self.isZeta = block_matrix(hybrid, isI)
        self.size = isI.getSizes()[1]
        # K_II's global row g, owned by rank r from start_r, is H's row first_r + g − start_r
        local = isI.getLocalSize()
        first = int(self.isZeta.getIndices()[0]) if local else -1
        sizes_first = self.comm.allgather((local, first))
        start_I = np.cumsum([0] + [n for n, _ in sizes_first])[:-1]
        nonempty = [r for r, (n, _) in enumerate(sizes_first) if n]
        self._starts = (start_I[nonempty], np.array([sizes_first[r][1] for r in nonempty]))
        return H

    def _rows_of_H(self, rows: np.ndarray) -> np.ndarray:
        """``H_I``'s rows of ``K_II``'s global rows."""
        start_I, start_H = self._starts
        owner = np.searchsorted(start_I, rows, side="right") - 1
        return (start_H[owner] + rows - start_I[owner]).astype(PETSc.IntType)

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """``x ← K_II⁻¹ b`` (vectors of ``K_II``'s layout)."""
        if self.isZeta is None:
            self.F.solve(b, x)
            return
        self.b.zeroEntries()
        part = self.b.getSubVector(self.isZeta)
        b.copy(part)
        self.b.restoreSubVector(self.isZeta, part)
        self.F.solve(self.b, self.x)
        part = self.x.getSubVector(self.isZeta)
        part.copy(x)
        self.x.restoreSubVector(self.isZeta, part)

    def inverse_block(self, rows: np.ndarray) -> np.ndarray | None:
        """``[K_II⁻¹]_{rows, rows}`` (sorted global rows of ``K_II``, the same on every rank)
        on rank 0, None elsewhere (collective)."""
        if self.isZeta is None:
            return inverse_block(self.F, rows, self.n)
        return inverse_block(self.F, self._rows_of_H(rows), self.n)

    def destroy(self) -> None:
        for obj in self._kept:
            obj.destroy()
        self._kept = []
        self.F = None
