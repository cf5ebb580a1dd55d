"""Index sets on sparsity patterns: which dofs a zone holds and which points lie inside it."""

from __future__ import annotations

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

__all__ = ["columns", "csr", "dilate", "dofs_of", "inside", "union", "unique"]


def unique(a: np.ndarray) -> np.ndarray:
    """Sorted distinct values of an integer array.

    By sorting: NumPy 2.5's hash-based ``np.unique`` is far slower on millions of
    integers.
    """
    a = np.sort(a.ravel(), kind="stable")  # a merge of the sorted runs it may be made of
    return a[np.concatenate([[True], a[1:] != a[:-1]])] if a.size else a


def union(comm: MPI.Comm, local: np.ndarray) -> np.ndarray:
    """Sorted union over the ranks of global dof numbers."""
    return unique(np.concatenate(comm.allgather(unique(local))))


def csr(A: PETSc.Mat) -> tuple[np.ndarray, np.ndarray]:
    """Row pointers and (global) columns of ``A``'s owned rows.

    Fetched when a zone is built (rarely) rather than kept: the patterns of the stiffness
    and point matrices take ≈ 1.5 GB at 1.9 M dofs.
    """
    ip, ix, _ = A.getValuesCSR()
    return ip, ix


def columns(pattern: tuple[np.ndarray, np.ndarray], rows: np.ndarray) -> np.ndarray:
    """The columns of the given local rows of ``pattern``, concatenated."""
    ip, ix = pattern
    if rows.size == 0:
        return ix[:0]
    start, count = ip[rows], ip[rows + 1] - ip[rows]
    offsets = np.repeat(start - np.concatenate([[0], np.cumsum(count)[:-1]]), count)
    return ix[np.arange(offsets.size) + offsets]


def dofs_of(
    comm: MPI.Comm, points: np.ndarray, pattern: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """The dofs coupled to the given owned points (all ranks' points, on all ranks);
    ``pattern``: that of the point matrix."""
    return union(comm, columns(pattern, np.flatnonzero(points)))


def dilate(K: PETSc.Mat, Z: np.ndarray, target: int) -> np.ndarray:
    """``Z`` (sorted global dofs) grown by rings of neighbours in the graph of ``K`` until it
    has ``target`` dofs or stops growing (collective)."""
    comm = K.getComm().tompi4py()
    n = K.getSize()[0]
    r0, r1 = K.getOwnershipRange()
    pattern = csr(K)
    zone = np.zeros(n, dtype=np.uint8)
    zone[Z] = 1
    lo, hi = np.searchsorted(Z, [r0, r1])
    front = Z[lo:hi] - r0  # the owned rows added last
    size = Z.size
    for _ in range(50):
        if size >= target:
            break
        ring = np.zeros(n, dtype=np.uint8)
        ring[columns(pattern, front)] = 1
        comm.Allreduce(MPI.IN_PLACE, ring, op=MPI.BOR)
        ring &= 1 - zone
        grown = int(np.count_nonzero(ring))
        if grown == 0:
            break
        zone |= ring
        size += grown
        front = np.flatnonzero(ring[r0:r1])
    return np.flatnonzero(zone)


def inside(n: int, Z: np.ndarray, pattern: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Owned points all of whose dofs are in ``Z`` (``pattern``: of the point matrix with
    ``n`` columns)."""
    ip, ix = pattern
    in_zone = np.zeros(n, dtype=bool)
    in_zone[Z] = True
    outside = np.concatenate([[0], np.cumsum(~in_zone[ix])])
    return outside[ip[1:]] == outside[ip[:-1]]
