"""Exact solves with the Newton Jacobian by condensation onto a contact zone.

The Jacobian of ``J_κ`` (MODEL.md §5) is ``J = K + P_A`` with the membrane stiffness ``K``
(fixed per mesh) and the penalty part ``P_A = (1/κ) M_Aᵀ diag(1/D_A) M_A``, which couples only
the dofs of the cells holding active points ``A``. Split the dofs into a zone ``Z`` that holds
every active point and the rest ``I``:

    J = [[K_II, K_IZ], [K_ZI, K_ZZ + P_ZZ]],   S = K_ZZ + P_ZZ − T,   T = K_ZI K_II⁻¹ K_IZ.

``K_II`` depends neither on κ nor on the active set: it is factorized once per zone. ``T`` is
nonzero only on the dofs ``Γ ⊂ Z`` coupled to ``I`` and needs only the entries of ``K_II⁻¹`` on
the dofs ``I' ⊂ I`` coupled to ``Z``: ``T = K_ΓI' [K_II⁻¹]_{I'I'} K_I'Γ``, from MUMPS' selected
inverse entries (:func:`~shellobstacle.solvers.mumps.inverse_block`). A Newton step then
factorizes only ``S`` (the zone's sparse matrix plus a dense ``|Γ|×|Γ|`` block, a few
thousand dofs; on several ranks by all of them together) and solves

    S δ_Z = r_Z − K_ZI K_II⁻¹ r_I,   δ_I = K_II⁻¹ (r_I − K_IZ δ_Z).

For a Newton right-hand side ``r = −R(ζ)`` the penalty vanishes on ``I``, so
``K_ZI K_II⁻¹ r_I = K_ZI (K_II⁻¹ f_I − ζ_I) − T ζ_Z`` and one back-substitution per step is
enough (:meth:`Condensation.newton_step`; ``K_II⁻¹ f_I`` once per zone and load).
"""

from __future__ import annotations

import time

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.hybrid_bending import CondensedStiffness
from shellobstacle.solvers.mumps import ReplicatedFactor
from shellobstacle.solvers.zone.graph import union, unique
from shellobstacle.solvers.zone.interior import InteriorFactor

__all__ = ["Condensation"]


class Condensation:
    """``K_II`` factorized, ``T`` on ``Γ × Γ`` and the pattern of ``S`` for the zone ``Z``.

    Args:
        K: the membrane stiffness (parallel).
        Z: the zone's dofs (sorted global numbers, the same on every rank).
        factorization: MUMPS ``"lu"`` or ``"cholesky"``, of ``K_II`` and of ``S``.
        timings: seconds are added to its ``"factorize"`` entry.
    """

    def __init__(
        self,
        K: PETSc.Mat,
        Z: np.ndarray,
        factorization: str,
        timings: dict[str, float],
        hybrid: CondensedStiffness | None = None,
    ) -> None:
        self.K, self.Z, self.timings = K, Z, timings
        self.Jzz: PETSc.Mat | None = None  # J_ZZ on every rank (set_up)
        self.comm: MPI.Comm = K.getComm().tompi4py()
        petsc_comm = K.getComm()
        r0, r1 = K.getOwnershipRange()
        owned = np.arange(r0, r1, dtype=PETSc.IntType)
        in_z = np.isin(owned, Z, assume_unique=True)
        self.isI = PETSc.IS().createGeneral(owned[~in_z], comm=petsc_comm)
        self.isZ = PETSc.IS().createGeneral(owned[in_z], comm=petsc_comm)
        t0 = time.perf_counter()
        self.F_I = InteriorFactor(K, self.isI, factorization, hybrid)  # solves with K_II
        timings["factorize"] += time.perf_counter() - t0
        self.vI = PETSc.Vec().createMPI((self.isI.getLocalSize(), None), comm=petsc_comm)
        self.yI, self.tI = self.vI.duplicate(), self.vI.duplicate()
        m = Z.size
        self.sizes = {"zone_dofs": int(m)}
        self._objects = [self.isI, self.isZ, self.F_I, self.vI, self.yI, self.tI]
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
        # S: sparse plus a dense |Γ|² block; approximate minimum fill (ICNTL(7) = 2) orders it
        # for a 30 % faster factorization than MUMPS' default (METIS)
        self.S_factor = ReplicatedFactor(self.comm, self.S, factorization, {7: 2})
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
        if self.Jzz is not None:
            self.Jzz.destroy()
            self.Jzz = None

    # -- the load -----------------------------------------------------------------------------
    def solve_load(self, f: PETSc.Vec) -> None:
        """``u_f = K_II⁻¹ f_I`` and ``f̃ = f_Z − K_ZI u_f`` (once per zone and load)."""
        if self.uf_valid:
            return
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
        """Factorize ``S = J_ZZ − T`` for the Jacobian ``J``."""
        if self.Z.size == 0:
            return
        if self.Jzz is None:
            self.Jzz = J.createSubMatrices(self.isZ_all, self.isZ_all)[0]
        else:
            J.createSubMatrices(self.isZ_all, self.isZ_all, submats=[self.Jzz])
        self.S.zeroEntries()
        self.S.axpy(1.0, self.Jzz, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        self.S.axpy(1.0, self.minusT, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        self.S_factor.factorize(self.S)
        self.factored = True
        self.factor_state = None

    def newton_step(self, x: PETSc.Vec, zeta: PETSc.Vec, f: PETSc.Vec, y: PETSc.Vec) -> None:
        """``y ← J⁻¹ x`` for a Newton right-hand side ``x = −R(ζ)`` with the load ``f``: one
        solve with ``K_II``.

        The active points lie in the zone, so on ``I`` the penalty vanishes and
        ``x_I = f_I − K_II ζ_I − K_IZ ζ_Z``; hence ``K_ZI K_II⁻¹ x_I = K_ZI (u_f − ζ_I) − T ζ_Z``
        with ``u_f = K_II⁻¹ f_I`` solved once per zone and load, and only
        ``δ_I = K_II⁻¹ (x_I − K_IZ δ_Z)`` needs a back-substitution per step.
        """
        if self.Z.size == 0:
            self.apply(x, y)
            return
        self.solve_load(f)
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
        sub = x.getSubVector(self.isI)
        self.F_I.solve(sub, self.yI)
        x.restoreSubVector(self.isI, sub)
        if self.Z.size == 0:
            out = y.getSubVector(self.isI)
            self.yI.copy(out)
            y.restoreSubVector(self.isI, out)
            return
        xz = x.getSubVector(self.isZ)
        self.KZI.mult(self.yI, self.vZ)
        self.vZ.aypx(-1.0, xz)  # r_Z − K_ZI y
        x.restoreSubVector(self.isZ, xz)
        self.to_all.scatter(self.vZ, self.zseq, PETSc.InsertMode.INSERT)
        self._finish(x, y)

    def _finish(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """From the zone right-hand side ``zseq``: ``δ_Z``, ``δ_I = K_II⁻¹(x_I − K_IZ δ_Z)``."""
        self.S_factor.solve(self.zseq, self.dseq)
        self.dZ.array[:] = self.dseq.array_r[self.z_lo : self.z_hi]
        self.KIZ.mult(self.dZ, self.vI)
        sub = x.getSubVector(self.isI)
        self.vI.aypx(-1.0, sub)
        x.restoreSubVector(self.isI, sub)
        self.F_I.solve(self.vI, self.yI)
        self.write(y)

    def write(self, y: PETSc.Vec) -> None:
        """``y_I ← yI``, ``y_Z ← dZ`` (the work vectors of a solve)."""
        part = y.getSubVector(self.isI)
        self.yI.copy(part)
        y.restoreSubVector(self.isI, part)
        part = y.getSubVector(self.isZ)
        self.dZ.copy(part)
        y.restoreSubVector(self.isZ, part)

    def extend(self, z: PETSc.Vec, out: PETSc.Vec, f: PETSc.Vec | None) -> None:
        """``out ← (z, ζ_I)`` with ``ζ_I = K_II⁻¹ (f_I − K_IZ z)`` (with the load ``f``) or
        ``−K_II⁻¹ K_IZ z`` (without): the minimizer over ``ζ_I``, or the matching change of
        ``ζ_I`` for a change ``z`` of ``ζ_Z``; one back-substitution with ``K_II``."""
        self.dZ.array[:] = z.array_r[self.z_lo : self.z_hi]
        self.KIZ.mult(self.dZ, self.vI)
        self.F_I.solve(self.vI, self.yI)
        if f is not None:
            self.solve_load(f)
            self.yI.aypx(-1.0, self.uf)
        else:
            self.yI.scale(-1.0)
        self.write(out)
