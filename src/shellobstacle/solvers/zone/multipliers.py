"""The hybrid stiffness as the contact zone condenses it: the block matrix in ``(ζ, t)``.

For the hybrid bending form (:mod:`shellobstacle.models.hybrid_bending`) the stiffness in ζ is the
Schur complement ``K = A − B C⁻¹ Bᵀ`` of

    H = [[A, B], [Bᵀ, C]]   in (ζ, t),   C diagonal,

whose rows couple one cell's dofs and its facets' multipliers, where ``K``'s reach across
the facets. The contact zone is condensed in ``H`` instead
(:mod:`~shellobstacle.solvers.zone.condensation`): its unknowns are the zone's dofs and the
multipliers of the facets all of whose cells hold a zone dof (:meth:`HybridBlocks.zone`).
Its interface then is one cell wide, as for a Lagrange stiffness, and its Schur complement
keeps the cells' block structure: half the flops of that of ``K`` at the same dofs. The
zone's problem in ``(ζ_Z, t_Z)`` minimized over ``t_Z`` is the one in ``ζ_Z`` alone; Newton's
steps and exact line searches from a ``t_Z`` that minimizes keep it minimizing, so the
iterates in ζ are the same.

A vector of ζ enters ``H``'s layout as a state ``(ζ, t(ζ))`` with the minimizing
``t(ζ) = −C⁻¹ Bᵀ ζ`` (then ``H``'s residual is ``K``'s, with zero in ``t``) or as a right-hand
side ``(x, 0)``.
"""

from __future__ import annotations

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import numpy as np

from shellobstacle.models.hybrid_bending import CondensedStiffness
from shellobstacle.solvers.zone.graph import union

__all__ = ["HybridBlocks", "block_matrix", "penalty_entries"]


def block_matrix(hybrid: CondensedStiffness) -> tuple[PETSc.Mat, PETSc.IS, PETSc.IS]:
    """``H = [[A, B], [Bᵀ, C]]`` as one AIJ matrix (each rank's rows: its dofs, then its
    multipliers) and the (owned) rows of ζ and of ``t`` in it."""
    comm = hybrid.B.getComm()
    t0, t1 = hybrid.B.getOwnershipRangeColumn()
    C = PETSc.Mat().createAIJ(((t1 - t0, None), (t1 - t0, None)), nnz=(1, 0), comm=comm)
    C.setDiagonal(hybrid.c)
    C.assemble()
    Bt = hybrid.B.transpose(PETSc.Mat())
    nest = PETSc.Mat().createNest([[hybrid.A, hybrid.B], [Bt, C]], comm=comm)
    rows_zeta, rows_t = (rows.duplicate() for rows in nest.getNestISs()[0])
    H = nest.convert("aij", PETSc.Mat())
    for obj in (nest, Bt, C):
        obj.destroy()
    return H, rows_zeta, rows_t


def penalty_entries(J: PETSc.Mat, K: PETSc.Mat) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nonzeros of ``J − K``, the penalty's Hessian of a Jacobian ``J = K + P`` with
    ``K``'s pattern, in the owned rows: how many per row, their columns and values (exact
    zeros left out: outside the cells of active points ``J`` and ``K`` agree)."""
    P = J.copy()
    P.axpy(-1.0, K, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
    indptr, cols, values = P.getValuesCSR()
    P.destroy()
    keep = values != 0
    kept = np.concatenate([[0], np.cumsum(keep)])
    return kept[indptr[1:]] - kept[indptr[:-1]], cols[keep], values[keep]


class HybridBlocks:
    """``H`` of a hybrid stiffness, its numbering, the zone's multipliers and the vectors.

    Args:
        hybrid: the blocks ``A``, ``B``, ``C`` of the stiffness.
        V: the displacement space; T: the multiplier's space (one dof per facet). Their
            cells are those of a mesh ghosted by facets (each rank sees both cells of its
            facets).
    """

    def __init__(
        self,
        hybrid: CondensedStiffness,
        V: dolfinx.fem.FunctionSpace,
        T: dolfinx.fem.FunctionSpace,
    ) -> None:
        self.hybrid = hybrid
        self.H, self.rows_zeta, self.rows_t = block_matrix(hybrid)
        self.comm: MPI.Comm = hybrid.B.getComm().tompi4py()
        r0, r1 = hybrid.A.getOwnershipRange()
        t0, _ = hybrid.B.getOwnershipRangeColumn()
        starts = np.array(self.comm.allgather((r0, r1, t0)), dtype=np.int64).reshape(-1, 3)
        self._r0, self._r1, self._t0 = starts.T
        self.bs = hybrid.A.getBlockSize()
        # each local cell's dofs (global numbers in ζ) and multipliers (local numbers in t)
        mesh = V.mesh
        cells = mesh.topology.index_map(mesh.topology.dim)
        num_cells = cells.size_local + cells.num_ghosts
        bs = V.dofmap.index_map_bs
        nodes = V.dofmap.index_map.local_to_global(V.dofmap.list[:num_cells].ravel())
        self.cell_dofs = (nodes.reshape(num_cells, -1, 1) * bs + np.arange(bs)).reshape(
            num_cells, -1
        )
        self.cell_facets = T.dofmap.list[:num_cells]
        self.t_map = T.dofmap.index_map
        self.x, self.y = self.H.createVecRight(), self.H.createVecRight()  # work vectors

    def of_zeta(self, dofs: np.ndarray) -> np.ndarray:
        """``H``'s numbers of ζ's global dofs."""
        owner = np.searchsorted(self._r0, dofs, side="right") - 1
        return dofs + self._t0[owner]

    def of_t(self, facets: np.ndarray) -> np.ndarray:
        """``H``'s numbers of ``t``'s global dofs."""
        owner = np.searchsorted(self._t0, facets, side="right") - 1
        return self._r1[owner] + facets

    def variable_blocks(self, rows: np.ndarray) -> np.ndarray:
        """The sizes of the runs of ``rows`` (sorted numbers of ``H``) that are one node's
        displacements or one multiplier: the blocks MUMPS may order as one node each."""
        start = self._r0 + self._t0  # each rank's first row of H
        owner = np.searchsorted(start, rows, side="right") - 1
        local = rows - start[owner]
        zeta = local < (self._r1 - self._r0)[owner]
        node = np.where(zeta, (self._r0[owner] + local) // self.bs, -1 - rows)
        first = np.flatnonzero(np.concatenate([[True], node[1:] != node[:-1]]))
        return np.diff(np.concatenate([first, [rows.size]]))

    def zone(self, Z: np.ndarray) -> np.ndarray:
        """The zone in ``H`` (sorted, on every rank): the dofs ``Z`` (sorted global dofs of ζ)
        and the multipliers of the facets all of whose cells hold a dof of ``Z``.

        A facet with a cell outside would couple the zone to that cell's dofs and widen the
        interface by a cell; its multiplier stays outside.
        """
        hit = np.zeros(self.cell_dofs.shape, dtype=bool)
        if Z.size:
            at = np.minimum(np.searchsorted(Z, self.cell_dofs), Z.size - 1)
            hit = Z[at] == self.cell_dofs
        zone_cell = hit.any(axis=1)
        num_t = self.t_map.size_local + self.t_map.num_ghosts
        touched = np.zeros(num_t, dtype=bool)
        touched[self.cell_facets[zone_cell].ravel()] = True
        touched[self.cell_facets[~zone_cell].ravel()] = False
        owned = np.flatnonzero(touched[: self.t_map.size_local]).astype(np.int32)
        t_Z = union(self.comm, self.of_t(self.t_map.local_to_global(owned)))
        return np.sort(np.concatenate([self.of_zeta(Z), t_Z]))

    def with_penalty(self, J: PETSc.Mat, K: PETSc.Mat, out: PETSc.Mat | None) -> PETSc.Mat:
        """``H`` plus the penalty's Hessian ``J − K`` of a Jacobian ``J = K + P`` (``K``'s
        pattern), into ``out`` if given (``H``'s pattern): the block matrix whose Schur
        complement in ζ is ``J``. ``P`` lives on the cells of the active points, within
        ``A``'s pattern."""
        counts, cols, values = penalty_entries(J, K)
        per_row = np.zeros(self.H.getLocalSize()[0], dtype=np.int64)  # ζ's rows come first
        per_row[: counts.size] = counts
        spread = PETSc.Mat().createAIJ(
            self.H.getSizes(),
            csr=(
                np.concatenate([[0], np.cumsum(per_row)]).astype(PETSc.IntType),
                self.of_zeta(cols).astype(PETSc.IntType),
                values,
            ),
            comm=self.H.getComm(),
        )
        if out is None:
            out = self.H.duplicate(copy=True)
        else:
            self.H.copy(out, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        out.axpy(1.0, spread, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        spread.destroy()
        return out

    def state(self, zeta: PETSc.Vec, out: PETSc.Vec) -> None:
        """``out ← (ζ, t(ζ))`` with ``t(ζ) = −C⁻¹ Bᵀ ζ``."""
        part = out.getSubVector(self.rows_zeta)
        zeta.copy(part)
        out.restoreSubVector(self.rows_zeta, part)
        part = out.getSubVector(self.rows_t)
        self.hybrid.multiplier(zeta, part)
        out.restoreSubVector(self.rows_t, part)

    def pad(self, x: PETSc.Vec, out: PETSc.Vec) -> None:
        """``out ← (x, 0)``."""
        out.zeroEntries()
        part = out.getSubVector(self.rows_zeta)
        x.copy(part)
        out.restoreSubVector(self.rows_zeta, part)

    def restrict(self, w: PETSc.Vec, out: PETSc.Vec) -> None:
        """``out ← w_ζ`` (ζ's part of a vector of ``H``'s layout)."""
        part = w.getSubVector(self.rows_zeta)
        part.copy(out)
        w.restoreSubVector(self.rows_zeta, part)

    def destroy(self) -> None:
        for obj in (self.H, self.rows_zeta, self.rows_t, self.x, self.y):
            obj.destroy()
