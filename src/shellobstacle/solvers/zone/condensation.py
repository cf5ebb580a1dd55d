"""Exact solves with the Newton Jacobian by condensation onto a contact zone.

The Jacobian of ``J_κ`` (docs/model.md §5) is ``J = K + P_A`` with the membrane stiffness ``K``
(fixed per mesh) and the penalty part ``P_A = (1/κ) M_Aᵀ diag(1/D_A) M_A``, which couples only
the dofs of the cells holding active points ``A``. Split the dofs into a zone ``Z`` that holds
every active point and the rest ``I``:

    J = [[K_II, K_IZ], [K_ZI, K_ZZ + P_ZZ]],   S = K_ZZ + P_ZZ − T,   T = K_ZI K_II⁻¹ K_IZ.

``K_II`` depends neither on κ nor on the active set: it is factorized once per zone. ``T`` is
nonzero only on the dofs ``Γ ⊂ Z`` coupled to ``I`` and needs only the entries of ``K_II⁻¹`` on
the dofs ``I' ⊂ I`` coupled to ``Z``: ``T = K_ΓI' [K_II⁻¹]_{I'I'} K_I'Γ``, from MUMPS' selected
inverse entries (:func:`~shellobstacle.solvers.zone.mumps.inverse_block`). A Newton step then
factorizes only ``S`` (the zone's sparse matrix plus a dense ``|Γ|×|Γ|`` block, a few
thousand dofs; on several ranks by all of them together) and solves

    S δ_Z = r_Z − K_ZI K_II⁻¹ r_I,   δ_I = K_II⁻¹ (r_I − K_IZ δ_Z).

For a Newton right-hand side ``r = −R(ζ)`` the penalty vanishes on ``I``, so
``K_ZI K_II⁻¹ r_I = K_ZI (K_II⁻¹ f_I − ζ_I) − T ζ_Z`` and one back-substitution per step is
enough (:meth:`Condensation.newton_step`; ``K_II⁻¹ f_I`` once per zone and load).

For the hybrid bending form all of this is done in the block matrix ``H`` in ``(ζ, t)``
instead of ``K`` (:mod:`~shellobstacle.solvers.zone.multipliers`): the zone then holds
multipliers too, and the methods here take and return vectors of ζ all the same.
"""

from __future__ import annotations

import time

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers.zone.graph import union, unique
from shellobstacle.solvers.zone.interior import InteriorFactor
from shellobstacle.solvers.zone.multipliers import HybridBlocks, penalty_entries
from shellobstacle.solvers.zone.mumps import ReplicatedFactor

__all__ = ["Condensation"]


class Condensation:
    """``K_II`` factorized, ``T`` on ``Γ × Γ`` and the pattern of ``S`` for the zone ``Z``.

    Args:
        K: the stiffness (parallel).
        Z: the zone's dofs (sorted global numbers, the same on every rank).
        factorization: MUMPS ``"lu"`` or ``"cholesky"``, of ``K_II`` and of ``S``.
        timings: seconds are added to its ``"factorize"`` entry.
        blocks: for a hybrid stiffness, its block matrix: the zone is condensed in it.

    The zone's unknowns (``Z`` here, ``Ks``, ``S`` and the zone's vectors) are those of ``K``,
    or with ``blocks`` those of ``H``: ζ's at the positions :attr:`zeta_pos`, then the zone's
    multipliers.
    """

    def __init__(
        self,
        K: PETSc.Mat,
        Z: np.ndarray,
        factorization: str,
        timings: dict[str, float],
        blocks: HybridBlocks | None = None,
    ) -> None:
        self.blocks, self.timings = blocks, timings
        self.bs = K.getBlockSize()
        self.K_zeta, self.Z_zeta = K, Z  # ζ's stiffness and zone
        if blocks is not None:
            K, Z = blocks.H, blocks.zone(Z)
        self.K, self.Z = K, Z  # the matrix condensed and the zone's unknowns in it
        self.zeta_pos = np.searchsorted(Z, Z if blocks is None else blocks.of_zeta(self.Z_zeta))
        self.Jzz: PETSc.Mat | None = None  # J_ZZ on every rank (set_up)
        self.Kzz_zeta: PETSc.Mat | None = None  # ζ's K_ZZ on every rank (set_up with blocks)
        self.comm: MPI.Comm = K.getComm().tompi4py()
        petsc_comm = K.getComm()
        r0, r1 = K.getOwnershipRange()
        owned = np.arange(r0, r1, dtype=PETSc.IntType)
        in_z = np.isin(owned, Z, assume_unique=True)
        self.isI = PETSc.IS().createGeneral(owned[~in_z], comm=petsc_comm)
        self.isZ = PETSc.IS().createGeneral(owned[in_z], comm=petsc_comm)
        t0 = time.perf_counter()
        blocks_I = None  # with blocks: MUMPS orders each node's displacements as one node
        if blocks is not None:
            blocks_I = blocks.variable_blocks(np.setdiff1d(np.arange(K.getSize()[0]), Z))
        self.F_I = InteriorFactor(K, self.isI, factorization, blocks_I)  # solves with K_II
        timings["factorize"] += time.perf_counter() - t0
        self.vI = PETSc.Vec().createMPI((self.isI.getLocalSize(), None), comm=petsc_comm)
        self.yI, self.tI = self.vI.duplicate(), self.vI.duplicate()
        m = Z.size
        self.sizes = {"zone_dofs": int(self.Z_zeta.size)}
        self._objects = [self.isI, self.isZ, self.F_I, self.vI, self.yI, self.tI]
        # vectors of H's layout (with blocks): right-hand side, state, load, result
        self.xH = self.wH = self.fH = self.yH = None
        if blocks is not None:
            self.xH, self.wH, self.fH, self.yH = (K.createVecLeft() for _ in range(4))
            self._objects += [self.xH, self.wH, self.fH, self.yH]
            self.sizes["zone_multipliers"] = int(m - self.Z_zeta.size)
        if m == 0:
            return
        self.KZI = K.createSubMatrix(self.isZ, self.isI)
        self.KIZ = K.createSubMatrix(self.isI, self.isZ)
        self.vZ = self.KZI.createVecLeft()
        self.dZ = self.KZI.createVecLeft()
        # I': the dofs of I coupled to Z (nonempty rows of K_IZ), in K's numbering
        ip, _, _ = self.KIZ.getValuesCSR()
        Ip = union(self.comm, owned[~in_z][np.diff(ip) > 0])
        Ip_II = (Ip - np.searchsorted(Z, Ip)).astype(PETSc.IntType)  # numbering of K_II
        # Γ: the dofs of Z coupled to I (nonzero columns of K_I'Z), positions in Z
        root = self.comm.rank == 0
        seq = PETSc.COMM_SELF
        rows_ip = PETSc.IS().createGeneral(Ip if root else Ip[:0], comm=seq)
        cols_z = PETSc.IS().createGeneral(Z.astype(PETSc.IntType) if root else Ip[:0], comm=seq)
        KIpZ = K.createSubMatrices(rows_ip, cols_z)[0]
        KZIp = K.createSubMatrices(cols_z, rows_ip)[0]
        Ginv = self.F_I.inverse_block(Ip_II)  # [K_II⁻¹]_{I'I'} on rank 0
        if root:
            k = Ip_II.size
            ip, ix, v = KIpZ.getValuesCSR()  # K_I'Z: its nonzero columns are Γ
            rows, nz = np.repeat(np.arange(k), np.diff(ip)), v != 0
            gamma = unique(ix[nz])
            A_ = np.zeros((k, gamma.size))
            A_[rows[nz], np.searchsorted(gamma, ix[nz])] = v[nz]
            ip, ix, v = KZIp.getValuesCSR()  # K_ZI' on the rows Γ
            B_ = np.zeros((gamma.size, k))
            rows = np.repeat(np.arange(m), np.diff(ip))
            keep = np.isin(rows, gamma)
            B_[np.searchsorted(gamma, rows[keep]), ix[keep]] = v[keep]
            T = B_ @ Ginv @ A_
        else:
            gamma, T = None, None
        gamma, T = self.comm.bcast((gamma, T), root=0)
        for obj in (rows_ip, cols_z, KIpZ, KZIp):
            obj.destroy()
        self.sizes |= {"interface_dofs": int(gamma.size), "coupled_dofs": int(Ip.size)}
        self.gamma, self.T = gamma, T  # Γ (positions in Z) and T on Γ × Γ, on every rank
        # S = J_ZZ − T on every rank: pattern of K_ZZ plus the dense Γ × Γ block
        self.isZ_all = PETSc.IS().createGeneral(Z.astype(PETSc.IntType), comm=seq)
        Kzz = K.createSubMatrices(self.isZ_all, self.isZ_all)[0]
        ip, ix, _ = Kzz.getValuesCSR()
        r = np.repeat(np.arange(m, dtype=np.int64), np.diff(ip))
        g = gamma.astype(np.int64)  # (row·m + column overflows 32-bit integers from m ≈ 46k)
        keys = unique(np.concatenate([r * m + ix, (g[:, None] * m + g[None, :]).ravel()]))
        rows, cols = keys // m, keys % m
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=m))])
        pattern = (indptr.astype(PETSc.IntType), cols.astype(PETSc.IntType), np.zeros(keys.size))
        self.S = PETSc.Mat().createAIJ((m, m), csr=pattern, comm=seq)
        g_ptr = np.zeros(m + 1, dtype=PETSc.IntType)
        g_ptr[1:] = np.cumsum(np.isin(np.arange(m), gamma) * gamma.size)
        self.minusT = PETSc.Mat().createAIJ(
            (m, m),
            csr=(g_ptr, np.tile(gamma, gamma.size).astype(PETSc.IntType), -T.ravel()),
            comm=seq,
        )
        # K_S = K_ZZ − T: the stiffness of the zone's own problem (ζ_I eliminated)
        self.Ks = self.S.duplicate(copy=False)
        self.Ks.axpy(1.0, Kzz, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        self.Ks.axpy(1.0, self.minusT, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        Kzz.destroy()
        # S: sparse plus a dense |Γ|² block. K's zone: approximate minimum fill (ICNTL(7) = 2),
        # a 30 % faster factorization than MUMPS' default (METIS); H's zone, cells' blocks
        # that nested dissection separates: PORD (4), half AMF's flops
        ordering = 2 if blocks is None else 4
        self.S_factor = ReplicatedFactor(self.comm, self.S, factorization, {7: ordering})
        #: what S's factorization holds: None for a full Jacobian's Z block, or (κ, active
        #: points) of the zone problem's Jacobian (:mod:`~shellobstacle.solvers.zone.reduced`)
        self.factor_state: tuple[float, np.ndarray] | None = None
        self.wseq = self.S.createVecLeft()
        self.dseq = self.S.createVecLeft()
        self.to_all, self.zseq = PETSc.Scatter.toAll(self.vZ)
        self.zeta_seq = self.zseq.duplicate()
        self.uf = self.vI.duplicate()  # K_II⁻¹ f_I
        self.f_tilde = self.wseq.duplicate()  # f_Z − K_ZI K_II⁻¹ f_I on every rank
        self.uf_valid = False
        self.z_lo, self.z_hi = self.vZ.getOwnershipRange()
        self._objects += [
            self.KZI, self.KIZ, self.vZ, self.dZ, self.isZ_all, self.Ks, self.S, self.minusT,
            self.wseq, self.dseq, self.to_all, self.zseq, self.zeta_seq, self.uf, self.f_tilde,
            self.S_factor,
        ]  # fmt: skip

    def destroy(self) -> None:
        for obj in self._objects:
            obj.destroy()
        self._objects = []
        for obj in (self.Jzz, self.Kzz_zeta):
            if obj is not None:
                obj.destroy()
        self.Jzz = self.Kzz_zeta = None

    # -- vectors of ζ and of the matrix condensed ---------------------------------------------
    def _rhs(self, x: PETSc.Vec, work: PETSc.Vec | None) -> PETSc.Vec:
        """``x`` as a right-hand side of the matrix condensed (``(x, 0)`` in ``work`` with
        blocks)."""
        if self.blocks is None:
            return x
        self.blocks.pad(x, work)
        return work

    def _state(self, zeta: PETSc.Vec) -> PETSc.Vec:
        """``ζ`` as a state of the matrix condensed (``(ζ, t(ζ))`` with blocks)."""
        if self.blocks is None:
            return zeta
        self.blocks.state(zeta, self.wH)
        return self.wH

    def _out(self, y: PETSc.Vec) -> PETSc.Vec:
        return y if self.blocks is None else self.yH

    def _done(self, y: PETSc.Vec) -> None:
        if self.blocks is not None:
            self.blocks.restrict(self.yH, y)

    def gather_state(self, zeta: PETSc.Vec, out: PETSc.Vec) -> None:
        """``out ←`` the zone's entries of the state of ``ζ``, on every rank."""
        x = self._state(zeta)
        sub = x.getSubVector(self.isZ)
        self.to_all.scatter(sub, out, PETSc.InsertMode.INSERT)
        x.restoreSubVector(self.isZ, sub)

    # -- the load -----------------------------------------------------------------------------
    def solve_load(self, f: PETSc.Vec) -> None:
        """``u_f = K_II⁻¹ f_I`` and ``f̃ = f_Z − K_ZI u_f`` (once per zone and load)."""
        if self.uf_valid:
            return
        f = self._rhs(f, self.fH)
        sub = f.getSubVector(self.isI)
        self.F_I.solve(sub, self.uf)
        f.restoreSubVector(self.isI, sub)
        self.KZI.mult(self.uf, self.vZ)
        sub = f.getSubVector(self.isZ)
        self.vZ.aypx(-1.0, sub)
        f.restoreSubVector(self.isZ, sub)
        self.to_all.scatter(self.vZ, self.f_tilde, PETSc.InsertMode.INSERT)
        self.uf_valid = True

    # -- exact solves with a full Jacobian ----------------------------------------------------
    def set_up(self, J: PETSc.Mat) -> None:
        """Factorize ``S = J_ZZ − T`` for the Jacobian ``J`` (of ζ)."""
        if self.Z.size == 0:
            return
        self.S.zeroEntries()
        if self.blocks is None:
            self.Jzz = self._zone_block(J, self.Jzz)
            self.S.axpy(1.0, self.Jzz, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            self.S.axpy(1.0, self.minusT, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        else:  # S = K_S + (J − K)_ZZ
            self.S.axpy(1.0, self.Ks, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            P = self._penalty_part(J)
            self.S.axpy(1.0, P, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            P.destroy()
        self.S_factor.factorize(self.S)
        self.factor_state = None

    def _zone_block(self, A: PETSc.Mat, out: PETSc.Mat | None) -> PETSc.Mat:
        """ζ's zone block ``A_ZZ`` of a matrix of ζ, on every rank (into ``out`` if given)."""
        rows = self.isZ_all
        if self.blocks is not None:
            Z = self.Z_zeta.astype(PETSc.IntType)
            rows = PETSc.IS().createGeneral(Z, comm=PETSc.COMM_SELF)
        if out is None:
            out = A.createSubMatrices(rows, rows)[0]
        else:
            A.createSubMatrices(rows, rows, submats=[out])
        if rows is not self.isZ_all:
            rows.destroy()
        return out

    def _penalty_part(self, J: PETSc.Mat) -> PETSc.Mat:
        """``(J − K)_ZZ`` (the penalty's Hessian on the zone) in the zone's unknowns of ``H``.

        ``J`` is ``K`` plus the penalty's Hessian, nonzero on the cells of active points only,
        whose dofs ``H`` couples: the difference's nonzeros lie in ``S``'s pattern.
        """
        if self.Kzz_zeta is None:
            self.Kzz_zeta = self._zone_block(self.K_zeta, None)
        self.Jzz = self._zone_block(J, self.Jzz)
        counts, cols, values = penalty_entries(self.Jzz, self.Kzz_zeta)
        per_row = np.zeros(self.Z.size, dtype=np.int64)
        per_row[self.zeta_pos] = counts
        m = self.Z.size
        return PETSc.Mat().createAIJ(
            (m, m),
            csr=(
                np.concatenate([[0], np.cumsum(per_row)]).astype(PETSc.IntType),
                self.zeta_pos[cols].astype(PETSc.IntType),
                values,
            ),
            comm=PETSc.COMM_SELF,
        )

    def newton_step(self, x: PETSc.Vec, zeta: PETSc.Vec, f: PETSc.Vec, y: PETSc.Vec) -> None:
        """``y ← J⁻¹ x`` for a Newton right-hand side ``x = −R(ζ)`` with the load ``f``: one
        solve with ``K_II``.

        The active points lie in the zone, so on ``I`` the penalty vanishes and
        ``x_I = f_I − K_II ζ_I − K_IZ ζ_Z``; hence ``K_ZI K_II⁻¹ x_I = K_ZI (u_f − ζ_I) − T ζ_Z``
        with ``u_f = K_II⁻¹ f_I`` solved once per zone and load, and only
        ``δ_I = K_II⁻¹ (x_I − K_IZ δ_Z)`` needs a back-substitution per step. (With blocks:
        ``(x, 0)`` is ``H``'s right-hand side at the state ``(ζ, t(ζ))``.)
        """
        if self.Z.size == 0:
            self.apply(x, y)
            return
        self.solve_load(f)
        x, zeta = self._rhs(x, self.xH), self._state(zeta)
        sub = zeta.getSubVector(self.isI)
        self.uf.copy(self.tI)
        self.tI.axpy(-1.0, sub)  # u_f − ζ_I
        zeta.restoreSubVector(self.isI, sub)
        self.KZI.mult(self.tI, self.vZ)
        sub = x.getSubVector(self.isZ)
        self.vZ.aypx(-1.0, sub)  # x_Z − K_ZI (u_f − ζ_I)
        x.restoreSubVector(self.isZ, sub)
        self.to_all.scatter(self.vZ, self.zseq, PETSc.InsertMode.INSERT)
        sub = zeta.getSubVector(self.isZ)
        self.to_all.scatter(sub, self.zeta_seq, PETSc.InsertMode.INSERT)
        zeta.restoreSubVector(self.isZ, sub)
        g = self.gamma
        self.zseq.array[g] += self.T @ self.zeta_seq.array_r[g]  # + T ζ_Z
        self._finish(x, y)

    def apply(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """``y ← J⁻¹ x`` for any ``x`` (two solves with ``K_II``)."""
        x = self._rhs(x, self.xH)
        sub = x.getSubVector(self.isI)
        self.F_I.solve(sub, self.yI)
        x.restoreSubVector(self.isI, sub)
        if self.Z.size == 0:
            out = self._out(y)
            part = out.getSubVector(self.isI)
            self.yI.copy(part)
            out.restoreSubVector(self.isI, part)
            self._done(y)
            return
        xz = x.getSubVector(self.isZ)
        self.KZI.mult(self.yI, self.vZ)
        self.vZ.aypx(-1.0, xz)  # r_Z − K_ZI y
        x.restoreSubVector(self.isZ, xz)
        self.to_all.scatter(self.vZ, self.zseq, PETSc.InsertMode.INSERT)
        self._finish(x, y)

    def _finish(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """From the zone right-hand side ``zseq``: ``δ_Z``, ``δ_I = K_II⁻¹(x_I − K_IZ δ_Z)``
        (``x`` of the matrix condensed, ``y`` of ζ)."""
        self.S_factor.solve(self.zseq, self.dseq)
        self.dZ.array[:] = self.dseq.array_r[self.z_lo : self.z_hi]
        self.KIZ.mult(self.dZ, self.vI)
        sub = x.getSubVector(self.isI)
        self.vI.aypx(-1.0, sub)
        x.restoreSubVector(self.isI, sub)
        self.F_I.solve(self.vI, self.yI)
        self.write(y)

    def write(self, y: PETSc.Vec) -> None:
        """``y_I ← yI``, ``y_Z ← dZ`` (the work vectors of a solve; ``y`` of ζ)."""
        out = self._out(y)
        part = out.getSubVector(self.isI)
        self.yI.copy(part)
        out.restoreSubVector(self.isI, part)
        part = out.getSubVector(self.isZ)
        self.dZ.copy(part)
        out.restoreSubVector(self.isZ, part)
        self._done(y)

    def extend(self, z: PETSc.Vec, out: PETSc.Vec, f: PETSc.Vec | None) -> None:
        """``out ← (z, ζ_I)`` with ``ζ_I = K_II⁻¹ (f_I − K_IZ z)`` (with the load ``f``) or
        ``−K_II⁻¹ K_IZ z`` (without): the minimizer over ``ζ_I``, or the matching change of
        ``ζ_I`` for a change ``z`` of ``ζ_Z``; one back-substitution with ``K_II``. (``z``:
        the zone's unknowns, ``out`` of ζ.)"""
        self.dZ.array[:] = z.array_r[self.z_lo : self.z_hi]
        self.KIZ.mult(self.dZ, self.vI)
        self.F_I.solve(self.vI, self.yI)
        if f is not None:
            self.solve_load(f)
            self.yI.aypx(-1.0, self.uf)
        else:
            self.yI.scale(-1.0)
        self.write(out)
