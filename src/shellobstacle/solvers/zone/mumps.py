"""What the contact zone needs of MUMPS beyond petsc4py: selected entries of an inverse, and a
factorization of a matrix every rank holds whole, made by all ranks together.

**Selected inverse entries.** The zone's Schur complement needs the entries
``[K_II⁻¹]_{I'I'}`` on the few hundred to few thousand dofs ``I'`` that couple to the zone.
MUMPS computes exactly those (ICNTL(30)) far faster than as many solves, exploiting the
sparsity of the right-hand sides and of the entries asked. PETSc offers it as
``MatMumpsGetInverse``, which petsc4py does not wrap (:mod:`shellobstacle.solvers.libpetsc`
calls it). Where PETSc lacks it, :func:`selected_inverse_available` says so and the caller
uses another strategy.

**Variable blocks.** MUMPS orders a matrix on its graph with each block of variables as one
node (ICNTL(15)); PETSc passes a matrix' block size as such blocks, and
:func:`set_variable_blocks` passes blocks of several sizes (``MatMumpsSetBlk``, through
:mod:`~shellobstacle.solvers.libpetsc` too; without it MUMPS orders single variables).
"""

from __future__ import annotations

from collections.abc import Callable

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers import libpetsc
from shellobstacle.solvers.base import ConvergenceError, direct_solver, factorize

__all__ = [
    "INVERSE_BLOCK",
    "ReplicatedFactor",
    "in_blocks",
    "inverse_block",
    "selected_inverse_available",
    "set_variable_blocks",
]

#: right-hand sides per block when MUMPS computes selected inverse entries (ICNTL(27)):
#: larger blocks than MUMPS' default (32) compute the entries faster, with the same peak
#: memory
INVERSE_BLOCK = 256


def selected_inverse_available() -> str | None:
    """None when ``MatMumpsGetInverse`` can be called, else why not."""
    return libpetsc.missing("MatMumpsGetInverse")


def set_variable_blocks(F: PETSc.Mat, sizes: np.ndarray) -> np.ndarray | None:
    """Make MUMPS order the factor ``F`` (not yet analysed) on the graph whose nodes are the
    blocks of consecutive variables of the given sizes (ICNTL(15) = 1).

    The factor is the same up to the order; METIS runs on a graph a block size smaller (on
    the hybrid form's block matrix, its nodes' three displacements one node: a shorter
    analysis). Returns the block pointers handed over (keep them until ``F`` is
    analysed), or None, leaving ``F`` as it was, where PETSc has no ``MatMumpsSetBlk``.
    """
    function = libpetsc.function("MatMumpsSetBlk")
    if function is None:
        return None
    pointers = np.concatenate([[1], 1 + np.cumsum(sizes)]).astype(PETSc.IntType)
    F.setMumpsIcntl(15, 1)
    if function(F.handle, sizes.size, None, pointers.ctypes.data) != 0:
        raise RuntimeError("MatMumpsSetBlk failed")
    return pointers


def in_blocks(sizes: np.ndarray, ordering: int = 5) -> Callable[[PETSc.PC], np.ndarray | None]:
    """A ``prepare`` of :func:`~shellobstacle.solvers.base.factorize`: the factor of the PC
    ordered in these variable blocks (:func:`set_variable_blocks`) by ``ordering`` (ICNTL(7)),
    on every attempt.

    METIS by default: MUMPS' automatic choice takes AMF for small matrices (below about 10k
    unknowns), whose factor of the hybrid block matrix costs 7× METIS's flops
    (``docs/perf/koiter/factor.jsonl``). On several ranks MUMPS' working space
    estimate with blocks falls short (INFOG(1) = −9 on the first attempt on 2 ranks): 50 %
    more from the start (ICNTL(14)).
    """

    def prepare(pc: PETSc.PC) -> np.ndarray | None:
        pc.setFactorSetUpSolverType()
        F = pc.getFactorMatrix()
        F.setMumpsIcntl(7, ordering)
        if F.getComm().getSize() > 1:
            F.setMumpsIcntl(14, max(F.getMumpsIcntl(14), 50))
        return set_variable_blocks(F, sizes)

    return prepare


def inverse_block(F: PETSc.Mat, rows: np.ndarray, size: int) -> np.ndarray | None:
    """``[A⁻¹]_{rows, rows}`` from the MUMPS factor ``F`` of a parallel ``size × size`` matrix
    ``A`` (collective; ``rows``: sorted global rows, the same on every rank).

    Returns the dense block on rank 0, None elsewhere.

    Raises:
        ConvergenceError: MUMPS failed.
    """
    get_inverse = libpetsc.function("MatMumpsGetInverse")
    if get_inverse is None:  # callers check selected_inverse_available() first
        raise RuntimeError(selected_inverse_available())
    comm = F.getComm()
    root = comm.tompi4py().rank == 0
    # the request: a parallel matrix whose rows and columns all live on rank 0 (MUMPS takes
    # the sparse right-hand sides from the diagonal block of rank 0); MUMPS returns the
    # entries asked in its transpose
    k = rows.size
    counts = np.zeros(size if root else 0, dtype=PETSc.IntType)
    if root:
        counts[rows] = k
    indptr = np.concatenate([[0], np.cumsum(counts)]).astype(PETSc.IntType)
    indices = np.tile(rows, k if root else 0).astype(PETSc.IntType)
    local = size if root else 0
    transposed = PETSc.Mat().createAIJ(
        ((local, size), (local, size)), csr=(indptr, indices, np.zeros(indices.size)), comm=comm
    )
    request = PETSc.Mat().createTranspose(transposed)
    saved = {i: F.getMumpsIcntl(i) for i in (20, 21, 27, 30)}
    F.setMumpsIcntl(27, INVERSE_BLOCK)
    err = get_inverse(F.handle, request.handle)
    for i, value in saved.items():  # back to ordinary solves
        F.setMumpsIcntl(i, value)
    if comm.tompi4py().allreduce(err, op=MPI.MAX) != 0:
        raise ConvergenceError(f"MatMumpsGetInverse failed (PETSc error {err})")
    block = None
    if root:
        ipT, _, vT = transposed.getValuesCSR()
        # row rows[a] of the transposed request holds (A⁻¹)[rows[b], rows[a]]
        block = np.stack([vT[ipT[r] : ipT[r + 1]] for r in rows]).T
        assert block.shape == (k, k)
    transposed.destroy()
    request.destroy()
    return block


class _Preconditioner:
    """A PETSc ``python`` preconditioner that solves with a kept factorization."""

    def __init__(self, factor: ReplicatedFactor) -> None:
        self.factor = factor

    def apply(self, pc: PETSc.PC, x: PETSc.Vec, y: PETSc.Vec) -> None:
        self.factor.solve(x, y)


class ReplicatedFactor:
    """A MUMPS factorization of a sequential matrix that every rank holds whole.

    Serially the matrix is factorized as it is. On several ranks a distributed copy (rows in
    contiguous blocks, the same pattern) is factorized by MUMPS on all ranks together instead
    of the whole matrix on each of them; :meth:`solve` takes and returns sequential vectors
    that are the same on every rank. ``icntl``: MUMPS controls.
    """

    def __init__(
        self, comm: MPI.Comm, A: PETSc.Mat, factorization: str, icntl: dict[int, int]
    ) -> None:
        self.parallel = comm.size > 1
        if not self.parallel:
            self.ksp = direct_solver(A, factorization, "zone", icntl=icntl)
            return
        m = A.getSize()[0]
        self.lo, self.hi = (m * comm.rank) // comm.size, (m * (comm.rank + 1)) // comm.size
        ip, ix, _ = A.getValuesCSR()
        self._values = slice(int(ip[self.lo]), int(ip[self.hi]))
        self._csr = (ip[self.lo : self.hi + 1] - ip[self.lo], ix[self._values])
        n = self.hi - self.lo
        self.D = PETSc.Mat().createAIJ(
            ((n, m), (n, m)), csr=(*self._csr, np.zeros(self._csr[1].size)), comm=comm
        )
        # MUMPS' working space estimate falls short for a dense front split over the ranks:
        # 50 % more from the start (factorize() would retry), no measurable change of the peak
        self.ksp = direct_solver(self.D, factorization, "zone", icntl={**icntl, 14: 50})
        self.b, self.x = self.D.createVecRight(), self.D.createVecLeft()
        self.to_all, x_all = PETSc.Scatter.toAll(self.x)  # (into any sequential vector)
        x_all.destroy()

    def factorize(self, A: PETSc.Mat) -> None:
        """Factorize ``A`` (the pattern given at construction)."""
        if self.parallel:
            _, _, values = A.getValuesCSR()
            self.D.setValuesCSR(*self._csr, values[self._values])
            self.D.assemble()
            self.ksp.setOperators(self.D)
        else:
            self.ksp.setOperators(A)
        factorize(self.ksp, "the contact zone's Schur complement S")

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """``x ← A⁻¹ b`` (sequential vectors, the same on every rank)."""
        if not self.parallel:
            self.ksp.solve(b, x)
            return
        self.b.array[:] = b.array_r[self.lo : self.hi]
        self.ksp.solve(self.b, self.x)
        self.to_all.scatter(self.x, x, PETSc.InsertMode.INSERT)

    def preconditioner(self) -> _Preconditioner:
        """A ``python`` PC context that solves with this factorization."""
        return _Preconditioner(self)

    def destroy(self) -> None:
        self.ksp.destroy()
        if self.parallel:
            for obj in (self.D, self.b, self.x, self.to_all):
                obj.destroy()
