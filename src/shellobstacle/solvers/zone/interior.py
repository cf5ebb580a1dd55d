"""Solves with ``K_II``, the stiffness outside the contact zone, from one factorization."""

from __future__ import annotations

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers.base import direct_solver, factorize
from shellobstacle.solvers.zone.mumps import in_blocks, inverse_block

__all__ = ["InteriorFactor"]


class InteriorFactor:
    """A factorization of ``K_II`` (``isI``: the owned rows of ``I``, in ``K``'s numbering).

    Args:
        K: the stiffness (parallel).
        isI: the owned rows of ``I``.
        factorization: MUMPS ``"lu"`` or ``"cholesky"``.
        blocks: sizes of the blocks of consecutive rows of ``K_II`` that MUMPS orders as one
            node each (:func:`~shellobstacle.solvers.zone.mumps.in_blocks`), or None:
            those of ``K``'s block size.
    """

    def __init__(
        self,
        K: PETSc.Mat,
        isI: PETSc.IS,
        factorization: str,
        blocks: np.ndarray | None = None,
    ) -> None:
        self.comm: MPI.Comm = K.getComm().tompi4py()
        M = K.createSubMatrix(isI, isI)
        self.size = M.getSize()[0]
        ksp = direct_solver(M, factorization, "zone")
        factorize(ksp, "K_II", prepare=None if blocks is None else in_blocks(blocks))
        self.F = ksp.getPC().getFactorMatrix()
        # Only a serial LU leaves the matrix entries in the matrix' own arrays (PETSc's MUMPS
        # interface copies them for Cholesky and for distributed matrices): otherwise the
        # matrix is not needed once factorized
        self._kept: list = []
        if factorization == "lu" and self.comm.size == 1:
            self._kept = [M, ksp]
        else:
            ksp.destroy()
            M.destroy()

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """``x ← K_II⁻¹ b``."""
        self.F.solve(b, x)

    def inverse_block(self, rows: np.ndarray) -> np.ndarray | None:
        """``[K_II⁻¹]_{rows, rows}`` (sorted global rows of ``K_II``, the same on every rank)
        on rank 0, None elsewhere (collective)."""
        return inverse_block(self.F, rows, self.size)

    def destroy(self) -> None:
        for obj in self._kept:
            obj.destroy()
        self._kept = []
        self.F = None
