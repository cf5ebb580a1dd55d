"""Exact Newton solves by condensation onto the contact zone.

The Jacobian of ``J_κ`` (MODEL.md §5) is ``J = K + P_A`` with the membrane stiffness ``K``
(fixed per mesh) and the penalty part ``P_A = (1/κ) M_Aᵀ diag(1/D_A) M_A``, which couples only
the dofs of the cells holding active points ``A``. Split the dofs into a zone ``Z`` that holds
every active point and the rest ``I``:

    J = [[K_II, K_IZ], [K_ZI, K_ZZ + P_ZZ]],   S = K_ZZ + P_ZZ − T,   T = K_ZI K_II⁻¹ K_IZ.

``K_II`` depends neither on κ nor on the active set: it is factorized once per zone. ``T`` is
nonzero only on the dofs ``Γ ⊂ Z`` coupled to ``I`` and needs only the entries of ``K_II⁻¹`` on
the dofs ``I' ⊂ I`` coupled to ``Z``: ``T = K_ΓI' [K_II⁻¹]_{I'I'} K_I'Γ``, computed by MUMPS'
selected entries of the inverse (ICNTL(30)). A Newton step then factorizes only ``S`` (the
zone's sparse matrix plus a dense ``|Γ|×|Γ|`` block, a few thousand dofs) and solves

    S δ_Z = r_Z − K_ZI K_II⁻¹ r_I,   δ_I = K_II⁻¹ (r_I − K_IZ δ_Z).

For a Newton right-hand side ``r = −R(ζ)`` the penalty vanishes on ``I``, so
``K_ZI K_II⁻¹ r_I = K_ZI (K_II⁻¹ f_I − ζ_I) − T ζ_Z`` and one back-substitution per step is
enough (:meth:`ContactZone.newton_step`; ``K_II⁻¹ f_I`` once per zone and load).

Better still, while no point outside the zone is active, ``ζ_I = K_II⁻¹ (f_I − K_IZ ζ_Z)``
minimizes ``J_κ`` over ``ζ_I``, which leaves a penalized problem on the zone alone with the
energy ``½ ζ_Zᵀ (K_ZZ − T) ζ_Z − f̃·ζ_Z`` (``f̃ = f_Z − K_ZI K_II⁻¹ f_I``) plus the penalty at the
zone's points. Its Newton steps (``NewtonSolver._zone_newton``) are Newton steps of ``J_κ``
that touch only the zone's small matrices; ``ζ_I`` costs one back-substitution per solve.

When an active point leaves the zone, the zone is rebuilt around the active points and the
penetration of the last full Newton step, then dilated by rings of the stiffness graph until its
dofs have doubled (room for the contact region to move). A zone above ``max_fraction`` of the
dofs is not worth condensing: the Jacobian is then factorized as a whole.
"""

from __future__ import annotations

import ctypes
import time
import warnings

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shellobstacle import compat  # noqa: F401
from shellobstacle.penalty import QuadraturePenalty, gap_scale, penalty_hessian
from shellobstacle.solvers.options import unique_prefix

__all__ = ["ContactZone", "zone_available"]

_LIB: ctypes.CDLL | None = None

# Right-hand sides per block when MUMPS computes the selected entries of K_II⁻¹ (ICNTL(27)).
# Its automatic default (32) took 0.40 s serially and 0.34–0.36 s on 2 ranks at 329k dofs (636
# requested columns), 3.3 s on 2 ranks at 1.93 M (1,494 columns); 256 takes 0.30, 0.25 and
# 2.4 s with the same peak memory (2,048: 2.6–3.1 s and 0.25 GB more). Measured,
# docs/performance.md (tenth session).
INVERSE_BLOCK = 256


def _libpetsc() -> ctypes.CDLL:
    """The PETSc library petsc4py runs on (for ``MatMumpsGetInverse``, which it does not wrap)."""
    global _LIB
    if _LIB is None:
        with open("/proc/self/maps") as maps:  # (OSError off Linux)
            paths = {line.split()[-1] for line in maps if "libpetsc.so" in line}
        if len(paths) != 1:
            raise RuntimeError(f"cannot locate the loaded libpetsc (found {sorted(paths)})")
        _LIB = ctypes.CDLL(paths.pop())
        _LIB.MatMumpsGetInverse.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        _LIB.MatMumpsGetInverse.restype = ctypes.c_int
    return _LIB


def zone_available(comm: MPI.Comm) -> bool:
    """Whether MUMPS' selected inverse entries can be reached (else: warn, and False).

    The condensation needs ``MatMumpsGetInverse`` from the PETSc library petsc4py runs on,
    found through ``/proc/self/maps`` (Linux).
    """
    try:
        _libpetsc()
        ok = True
    except (OSError, RuntimeError, AttributeError) as err:
        ok, reason = False, str(err)
    if not comm.allreduce(ok, op=MPI.LAND):
        warnings.warn(
            "solver.contact_zone: MUMPS' selected inverse entries are not reachable "
            f"({reason if not ok else 'on another rank'}); using one factorization per κ "
            "reused by CG instead",
            RuntimeWarning,
            stacklevel=3,
        )
        return False
    return True


def _lu(
    comm: PETSc.Comm, A: PETSc.Mat, factorization: str = "lu", icntl: dict[int, int] | None = None
) -> PETSc.KSP:
    """A MUMPS ``factorization`` (lu or cholesky) solver for ``A``, made at its first set-up.

    ``icntl``: MUMPS controls, e.g. ``{7: 2}`` for its ordering (default: its own choices).
    """
    ksp = PETSc.KSP().create(comm)
    ksp.setOptionsPrefix(unique_prefix("zone"))
    ksp.setOperators(A)
    ksp.setType("preonly")
    pc = ksp.getPC()
    if factorization == "cholesky":
        A.setOption(PETSc.Mat.Option.SPD, True)
    pc.setType(factorization)
    pc.setFactorSolverType("mumps")
    _controls(pc, icntl)
    ksp.setFromOptions()
    return ksp


def _controls(pc: PETSc.PC, icntl: dict[int, int] | None) -> None:
    """Set MUMPS controls on the factor matrix ``pc`` is about to make."""
    if icntl:
        pc.setFactorSetUpSolverType()
        F = pc.getFactorMatrix()
        for key, value in icntl.items():
            F.setMumpsIcntl(key, value)


def _set_up(ksp: PETSc.KSP, what: str, attempts: int = 3) -> None:
    """``ksp.setUp()`` for a MUMPS factorization of ``what``, made to succeed or raise.

    MUMPS sizes its working space by the analysis' estimate plus ICNTL(14) percent, and the
    estimate can be short for a distributed dense front (the zone's ``S`` at 1.92 M dofs on 2
    ranks: INFOG(1) = −9 with MUMPS' 20 %, measured). On INFOG(1) = −8 or −9 the analysis and
    factorization are made again with ICNTL(14) doubled, up to ``attempts`` times (setting it
    on the existing factor does not take: measured); any other failure raises.
    """
    pc = ksp.getPC()
    for attempt in range(attempts + 1):
        ksp.setUp()
        if pc.getFailedReason() == 0:
            return
        F = pc.getFactorMatrix()
        info, icntl = F.getMumpsInfog(1), {key: F.getMumpsIcntl(key) for key in (7, 14)}
        if info not in (-8, -9) or attempt == attempts:
            raise RuntimeError(
                f"MUMPS could not factorize {what}: INFOG(1) = {info}, INFOG(2) = "
                f"{F.getMumpsInfog(2)} with ICNTL(14) = {icntl[14]} (MUMPS manual, section 8)"
            )
        icntl[14] = max(2 * icntl[14], 20)
        A, P = pc.getOperators()
        pc.reset()
        ksp.setOperators(A, P)
        _controls(pc, icntl)


def _unique(a: np.ndarray) -> np.ndarray:
    """Sorted distinct values of an integer array.

    By sorting: NumPy 2.5's hash-based ``np.unique`` took 2.4 s for 4 M integers here, a
    sort 0.08 s (measured), and far longer still for the structured keys of ``S``'s pattern.
    """
    a = np.sort(a.ravel(), kind="stable")  # a merge of the sorted runs it may be made of
    return a[np.concatenate([[True], a[1:] != a[:-1]])] if a.size else a


def _csr(A: PETSc.Mat) -> tuple[np.ndarray, np.ndarray]:
    """Row pointers and (global) columns of ``A``'s owned rows.

    Fetched when a zone is built (rarely) rather than kept: at 1.9 M dofs the patterns of the
    stiffness and point matrices would take ≈ 1.5 GB.
    """
    ip, ix, _ = A.getValuesCSR()
    return ip, ix


def _columns(csr: tuple[np.ndarray, np.ndarray], rows: np.ndarray) -> np.ndarray:
    """The columns of the given local rows of ``csr``, concatenated."""
    ip, ix = csr
    if rows.size == 0:
        return ix[:0]
    start, count = ip[rows], ip[rows + 1] - ip[rows]
    offsets = np.repeat(start - np.concatenate([[0], np.cumsum(count)[:-1]]), count)
    return ix[np.arange(offsets.size) + offsets]


class _Preconditioner:
    """A PETSc ``python`` preconditioner that solves with a kept factorization."""

    def __init__(self, factor: _ReplicatedFactor) -> None:
        self.factor = factor

    def apply(self, pc: PETSc.PC, x: PETSc.Vec, y: PETSc.Vec) -> None:
        self.factor.solve(x, y)


class _ReplicatedFactor:
    """A MUMPS factorization of a sequential matrix that every rank holds whole (``S``).

    Serially the matrix is factorized as it is. On several ranks a distributed copy (rows in
    contiguous blocks, the same pattern) is factorized by MUMPS on all ranks together instead
    of the whole matrix on each of them; :meth:`solve` takes and returns sequential vectors
    that are the same on every rank. ``icntl``: MUMPS controls (:func:`_lu`).
    """

    def __init__(
        self, comm: MPI.Comm, A: PETSc.Mat, factorization: str, icntl: dict[int, int]
    ) -> None:
        self.parallel = comm.size > 1
        if not self.parallel:
            self.ksp = _lu(PETSc.COMM_SELF, A, factorization, icntl)
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
        # MUMPS' working space estimate falls short for S's dense front split over the ranks
        # (1.92 M dofs, 2 ranks: INFOG(1) = −9 with its 20 %, fine with 40 %; _set_up would
        # retry): 50 % more from the start, no measurable change of the peak memory
        self.ksp = _lu(self.D.getComm(), self.D, factorization, {**icntl, 14: 50})
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
        _set_up(self.ksp, "the contact zone's Schur complement S")

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """``x ← A⁻¹ b`` (sequential vectors, the same on every rank)."""
        if not self.parallel:
            self.ksp.solve(b, x)
            return
        self.b.array[:] = b.array_r[self.lo : self.hi]
        self.ksp.solve(self.b, self.x)
        self.to_all.scatter(self.x, x, PETSc.InsertMode.INSERT)

    def destroy(self) -> None:
        self.ksp.destroy()
        if self.parallel:
            for obj in (self.D, self.b, self.x, self.to_all):
                obj.destroy()


class ContactZone:
    """Solves with the Newton Jacobian through a factorization of ``K_II`` kept per zone.

    Used as a PETSc ``python`` preconditioner: :meth:`setUp` builds ``S`` for the operator
    (the Jacobian), :meth:`apply` solves with it exactly. :meth:`prepare` must be called
    with the active points before every set-up. ``factorization`` (MUMPS ``"lu"`` or
    ``"cholesky"``) is that of ``K_II`` and of ``S``, both symmetric positive definite.
    """

    def __init__(
        self,
        K: PETSc.Mat,
        penalty: QuadraturePenalty,
        max_fraction: float = 0.3,
        factorization: str = "lu",
    ) -> None:
        self.K, self.penalty, self.max_fraction = K, penalty, max_fraction
        self.factorization = factorization
        self.comm = K.getComm().tompi4py()
        self.n = K.getSize()[0]
        self.r0, self.r1 = K.getOwnershipRange()
        self.num_points = penalty.D.size  # owned points
        self.points: np.ndarray | None = None  # owned points inside the zone (None: no zone)
        self.Z: np.ndarray | None = None  # the zone's dofs (global, sorted, on all ranks)
        self.whole = False  # the zone is too large: factorize the whole Jacobian
        self.builds = 0  # zones built (each a factorization of K_II)
        self.timings = {"factorize": 0.0, "zone": 0.0, "condense": 0.0}
        self.sizes: dict[str, int] = {}
        self._objects: list = []
        self._J: PETSc.Mat | None = None  # the operator of the last set-up
        self._f: PETSc.Vec | None = None  # the load vector (newton_step)
        self._stale = False  # the zone changed after that set-up
        self.factored = False  # S is factorized for the current zone
        self._S_state: tuple[float, np.ndarray] | None = None  # κ and active points of S
        self.ksp_cg: PETSc.KSP | None = None  # CG on the zone, preconditioned by S's factors
        self.Jzz: PETSc.Mat | None = None
        self.whole_ksp: PETSc.KSP | None = None

    # -- the zone ------------------------------------------------------------------------------
    def _union(self, local: np.ndarray) -> np.ndarray:
        """Sorted union over the ranks of global dof numbers."""
        return _unique(np.concatenate(self.comm.allgather(_unique(local))))

    def _dofs_of(self, points: np.ndarray, csr: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """The dofs coupled to the given owned points (all ranks' points, on all ranks).

        ``csr``: :func:`_csr` of the point matrix.
        """
        return self._union(_columns(csr, np.flatnonzero(points)))

    def _dilate(self, Z: np.ndarray, target: int) -> np.ndarray:
        """``Z`` grown by rings of neighbours in the graph of ``K`` until it has ``target`` dofs
        (or stops growing)."""
        csr = _csr(self.K)
        zone = np.zeros(self.n, dtype=np.uint8)
        zone[Z] = 1
        lo, hi = np.searchsorted(Z, [self.r0, self.r1])
        front = Z[lo:hi] - self.r0  # the owned rows added last
        size = Z.size
        for _ in range(50):
            if size >= target:
                break
            ring = np.zeros(self.n, dtype=np.uint8)
            ring[_columns(csr, front)] = 1
            self.comm.Allreduce(MPI.IN_PLACE, ring, op=MPI.BOR)
            ring &= 1 - zone
            grown = int(np.count_nonzero(ring))
            if grown == 0:
                break
            zone |= ring
            size += grown
            front = np.flatnonzero(ring[self.r0 : self.r1])
        return np.flatnonzero(zone)

    def _inside(self, Z: np.ndarray, csr: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Owned points all of whose dofs are in ``Z`` (``csr``: of the point matrix)."""
        ip, ix = csr
        in_zone = np.zeros(self.n, dtype=bool)
        in_zone[Z] = True
        outside = np.concatenate([[0], np.cumsum(~in_zone[ix])])
        return outside[ip[1:]] == outside[ip[:-1]]

    def covers(self, active: np.ndarray) -> bool:
        """Whether the current zone holds all active points (collective)."""
        ok = self.whole or (self.points is not None and not np.any(active & ~self.points))
        return bool(self.comm.allreduce(ok, op=MPI.LAND))

    def prepare(self, active: np.ndarray, hint: np.ndarray | None) -> bool:
        """Make the zone hold the active points; returns True if a zone was built.

        ``hint``: more points the zone should hold (the penetration of the last full step).
        """
        if self.covers(active):
            return False
        t0, factorize0 = time.perf_counter(), self.timings["factorize"]
        base = active.copy()
        if hint is not None:
            base |= hint
        if self.points is not None:
            base |= self.points
        csr = _csr(self.penalty.M)
        Z = self._dofs_of(base, csr)
        if Z.size:
            Z = self._dilate(Z, 2 * Z.size)
        self.set_zone(Z, csr)
        self.timings["zone"] += time.perf_counter() - t0 - (self.timings["factorize"] - factorize0)
        return True

    @property
    def usable(self) -> bool:
        """A nonempty zone that is condensed (not "factorize the whole Jacobian")."""
        return not self.whole and self.Z is not None and self.Z.size > 0

    def owned_zone(self) -> np.ndarray:
        """Local positions of the zone's owned dofs (empty without a zone)."""
        if self.Z is None:
            return np.zeros(0, dtype=np.int64)
        lo, hi = np.searchsorted(self.Z, [self.r0, self.r1])
        return self.Z[lo:hi] - self.r0

    def set_owned_zone(self, owned: np.ndarray) -> None:
        """Make the union over the ranks of these owned dofs (local positions) the zone."""
        self.set_zone(self._union(owned + self.r0))

    def set_zone(self, Z: np.ndarray, csr: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Make ``Z`` (sorted global dofs, the same on all ranks) the zone (collective).

        Factorizes ``K_II`` and computes ``T``; a zone above ``max_fraction`` of the dofs
        means "factorize the whole Jacobian" instead. ``csr``: the point matrix's pattern,
        if the caller has it.
        """
        self._destroy()
        self._stale = self._J is not None
        self.factored = False
        self._S_state = None
        self.whole = Z.size > self.max_fraction * self.n
        self.Z = Z
        if self.whole:
            self.points = None
            self.sizes = {"zone_dofs": int(Z.size)}
        else:
            self.points = self._inside(Z, csr or _csr(self.penalty.M))
            self._build(Z)
            self.builds += 1

    def _build(self, Z: np.ndarray) -> None:
        """``K_II`` factorized, ``T`` on ``Γ × Γ`` and the pattern of ``S`` for the zone ``Z``."""
        comm, K, petsc_comm = self.comm, self.K, self.K.getComm()
        owned = np.arange(self.r0, self.r1, dtype=PETSc.IntType)
        in_z = np.isin(owned, Z, assume_unique=True)
        self.isI = PETSc.IS().createGeneral(owned[~in_z], comm=petsc_comm)
        self.isZ = PETSc.IS().createGeneral(owned[in_z], comm=petsc_comm)
        KII = K.createSubMatrix(self.isI, self.isI)
        t0 = time.perf_counter()
        ksp = _lu(petsc_comm, KII, self.factorization)
        _set_up(ksp, "K_II")
        self.timings["factorize"] += time.perf_counter() - t0
        self.F_I = ksp.getPC().getFactorMatrix()  # solves with K_II: MatSolve on it
        nI = KII.getSize()[0]
        self.vI, self.yI, self.tI = KII.createVecRight(), KII.createVecRight(), KII.createVecRight()
        # Only a serial LU leaves the matrix entries in K_II's own arrays (PETSc's MUMPS
        # interface copies them for Cholesky and for distributed matrices): otherwise K_II is
        # not needed once factorized (1.92 M dofs: 0.24 GB per rank on 2 ranks).
        if self.factorization == "lu" and comm.size == 1:
            self._kept = [KII, ksp]
        else:
            self._kept = []
            ksp.destroy()
            KII.destroy()
        m = Z.size
        self.sizes = {"zone_dofs": int(m)}
        if m == 0:
            self._objects = [self.isI, self.isZ, self.F_I, self.vI, self.yI, self.tI, *self._kept]
            return
        self.KZI = K.createSubMatrix(self.isZ, self.isI)
        self.KIZ = K.createSubMatrix(self.isI, self.isZ)
        self.vZ = self.KZI.createVecLeft()
        self.dZ = self.KZI.createVecLeft()
        # I': the dofs of I coupled to Z (nonempty rows of K_IZ), in K's numbering
        ip, _, _ = self.KIZ.getValuesCSR()
        I_owned = owned[~in_z]
        Ip = self._union(I_owned[np.diff(ip) > 0])
        Ip_II = (Ip - np.searchsorted(Z, Ip)).astype(PETSc.IntType)  # numbering of K_II
        # Γ: the dofs of Z coupled to I (nonzero columns of K_I'Z), positions in Z
        root = comm.rank == 0
        seq = PETSc.COMM_SELF
        rows_ip = PETSc.IS().createGeneral(Ip if root else Ip[:0], comm=seq)
        cols_z = PETSc.IS().createGeneral(Z.astype(PETSc.IntType) if root else Ip[:0], comm=seq)
        KIpZ = K.createSubMatrices(rows_ip, cols_z)[0]
        KZIp = K.createSubMatrices(cols_z, rows_ip)[0]
        # [K_II⁻¹]_{I'I'} by MUMPS on the factorization just made (the request lives on rank 0)
        F = self.F_I
        # the request: a parallel matrix whose rows and columns all live on rank 0 (MUMPS
        # takes the sparse right-hand sides from the diagonal block of rank 0)
        k = Ip_II.size
        counts = np.zeros(nI if root else 0, dtype=PETSc.IntType)
        if root:
            counts[Ip_II] = k
        indptr = np.concatenate([[0], np.cumsum(counts)]).astype(PETSc.IntType)
        indices = np.tile(Ip_II, k if root else 0).astype(PETSc.IntType)
        local = nI if root else 0
        transposed = PETSc.Mat().createAIJ(
            ((local, nI), (local, nI)),
            csr=(indptr, indices, np.zeros(indices.size)),
            comm=petsc_comm,
        )
        request = PETSc.Mat().createTranspose(transposed)
        saved = {i: F.getMumpsIcntl(i) for i in (20, 21, 27, 30)}
        F.setMumpsIcntl(27, INVERSE_BLOCK)
        err = _libpetsc().MatMumpsGetInverse(F.handle, request.handle)
        for i, value in saved.items():  # back to ordinary solves
            F.setMumpsIcntl(i, value)
        if comm.allreduce(err, op=MPI.MAX) != 0:
            raise RuntimeError(f"MatMumpsGetInverse failed (PETSc error {err})")
        if root:
            ipT, _, vT = transposed.getValuesCSR()
            k = Ip_II.size
            # row Ip_II[a] of the transposed request holds (K_II⁻¹)[Ip_II[b], Ip_II[a]]
            Ginv = np.stack([vT[ipT[r] : ipT[r + 1]] for r in Ip_II]).T
            assert Ginv.shape == (k, k)
            ip, ix, v = KIpZ.getValuesCSR()  # K_I'Z: its nonzero columns are Γ
            rows, nz = np.repeat(np.arange(k), np.diff(ip)), v != 0
            gamma = _unique(ix[nz])
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
        gamma, T = comm.bcast((gamma, T), root=0)
        for obj in (rows_ip, cols_z, KIpZ, KZIp, transposed, request):
            obj.destroy()
        self.sizes |= {"interface_dofs": int(gamma.size), "coupled_dofs": int(Ip.size)}
        self.gamma, self.T = gamma, T  # Γ (positions in Z) and T on Γ × Γ, on every rank
        # S = J_ZZ − T on every rank: pattern of K_ZZ plus the dense Γ × Γ block
        self.isZ_all = PETSc.IS().createGeneral(Z.astype(PETSc.IntType), comm=seq)
        Kzz = K.createSubMatrices(self.isZ_all, self.isZ_all)[0]
        ip, ix, _ = Kzz.getValuesCSR()
        r = np.repeat(np.arange(m, dtype=np.int64), np.diff(ip))
        g = gamma.astype(np.int64)  # (row·m + column overflows 32-bit integers from m ≈ 46k)
        keys = _unique(np.concatenate([r * m + ix, (g[:, None] * m + g[None, :]).ravel()]))
        rows, cols = keys // m, keys % m
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=m))])
        csr = (indptr.astype(PETSc.IntType), cols.astype(PETSc.IntType), np.zeros(keys.size))
        self.S = PETSc.Mat().createAIJ((m, m), csr=csr, comm=seq)
        g_ptr = np.zeros(m + 1, dtype=PETSc.IntType)
        g_ptr[1:] = np.cumsum(np.isin(np.arange(m), gamma) * gamma.size)
        self.minusT = PETSc.Mat().createAIJ(
            (m, m),
            csr=(g_ptr, np.tile(gamma, gamma.size).astype(PETSc.IntType), -T.ravel()),
            comm=seq,
        )
        # the zone's own problem (ζ_I eliminated): K_ZZ − T and the penalty at the zone's points
        self.Ks = self.S.duplicate(copy=False)
        self.Ks.axpy(1.0, Kzz, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        self.Ks.axpy(1.0, self.minusT, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        Kzz.destroy()
        M = self.penalty.M
        own = np.flatnonzero(self.points)
        P = np.concatenate(comm.allgather(own + M.getOwnershipRange()[0])).astype(PETSc.IntType)
        self.DP = np.concatenate(comm.allgather(self.penalty.D[own]))
        self.g0P = np.concatenate(comm.allgather(self.penalty.g0[own]))
        isP = PETSc.IS().createGeneral(P, comm=seq)
        self.MP = M.createSubMatrices(isP, self.isZ_all)[0]  # rows: all the zone's points
        isP.destroy()
        self.wP = self.MP.createVecLeft()
        self.component = Z % K.getBlockSize()  # ζ_j of each zone dof (blocked numbering)
        # S: sparse plus a dense |Γ|² block; approximate minimum fill (ICNTL(7) = 2) orders it
        # for a 30 % faster factorization than MUMPS' default (METIS) at 326k dofs (measured);
        # on several ranks factorized by all of them together
        self.S_factor = _ReplicatedFactor(comm, self.S, self.factorization, {7: 2})
        self.S_now = self.S.duplicate(copy=False)  # the current Jacobian when S's are reused
        self.wseq = self.S.createVecLeft()
        self.dseq = self.S.createVecLeft()
        self.to_all, self.zseq = PETSc.Scatter.toAll(self.vZ)
        self.zeta_seq = self.zseq.duplicate()
        self.uf = self.vI.duplicate()  # K_II⁻¹ f_I (for newton_step)
        self.f_tilde = self.wseq.duplicate()  # f_Z − K_ZI K_II⁻¹ f_I on every rank
        self._uf_valid = False
        self.z_lo, self.z_hi = self.vZ.getOwnershipRange()
        self._objects = [
            self.isI, self.isZ, self.F_I, self.vI, self.yI, self.tI, self.KZI,
            self.KIZ, self.vZ, self.dZ, self.isZ_all, self.S, self.minusT,
            self.wseq, self.dseq, self.to_all, self.zseq, self.zeta_seq, self.uf, self.Ks,
            self.MP, self.wP, self.f_tilde, self.S_now, self.S_factor, *self._kept,
        ]  # fmt: skip

    def _destroy(self) -> None:
        for obj in self._objects:
            obj.destroy()
        self._objects = []
        if self.Jzz is not None:
            self.Jzz.destroy()
            self.Jzz = None
        if self.whole_ksp is not None:
            self.whole_ksp.destroy()
            self.whole_ksp = None
        if self.ksp_cg is not None:
            self.ksp_cg.destroy()
            self.ksp_cg = None

    # -- the PETSc python-preconditioner protocol ---------------------------------------------
    def setUp(self, pc: PETSc.PC) -> None:
        """Factorize ``S`` for the current Jacobian (or the whole Jacobian)."""
        self._J = pc.getOperators()[0]
        self._refresh()

    def _refresh(self) -> None:
        """``S`` (or the whole factorization) for the operator of the last set-up."""
        t0 = time.perf_counter()
        J = self._J
        self._stale = False
        if self.whole:
            if self.whole_ksp is None:
                self.whole_ksp = _lu(J.getComm(), J)
            self.whole_ksp.setOperators(J)
            _set_up(self.whole_ksp, "the Jacobian")
            self.timings["factorize"] += time.perf_counter() - t0
            return
        if self.points is None:
            raise RuntimeError("ContactZone.prepare() must be called before the set-up")
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
        self._S_state = None  # (a full step's Jacobian: not compared by active points)
        self.timings["condense"] += time.perf_counter() - t0

    def set_load(self, f: PETSc.Vec) -> None:
        """The load vector of the coming Newton steps (``K_II⁻¹ f_I`` is kept if unchanged)."""
        if self._f is not None:
            same = np.array_equal(self._f.array_r, f.array_r)
            if self.comm.allreduce(same, op=MPI.LAND):
                return
            self._f.destroy()
        self._f = f.copy()
        self._uf_valid = False

    def _solve_load(self) -> None:
        """``u_f = K_II⁻¹ f_I`` and ``f̃ = f_Z − K_ZI u_f`` (once per zone and load)."""
        if self._uf_valid:
            return
        sub = self._f.getSubVector(self.isI)
        self.F_I.solve(sub, self.uf)
        self._f.restoreSubVector(self.isI, sub)
        self.KZI.mult(self.uf, self.vZ)
        sub = self._f.getSubVector(self.isZ)
        self.vZ.aypx(-1.0, sub)
        self._f.restoreSubVector(self.isZ, sub)
        self.to_all.scatter(self.vZ, self.f_tilde, PETSc.InsertMode.INSERT)
        self._uf_valid = True

    def newton_step(self, x: PETSc.Vec, zeta: PETSc.Vec, y: PETSc.Vec) -> None:
        """``y ← J⁻¹ x`` for a Newton right-hand side ``x = −R(ζ)``, one solve with ``K_II``.

        The active points lie in the zone, so on ``I`` the penalty vanishes and
        ``x_I = f_I − K_II ζ_I − K_IZ ζ_Z``; hence ``K_ZI K_II⁻¹ x_I = K_ZI (u_f − ζ_I) − T ζ_Z``
        with ``u_f = K_II⁻¹ f_I`` solved once per zone and load, and only
        ``δ_I = K_II⁻¹ (x_I − K_IZ δ_Z)`` needs a back-substitution per step.
        """
        if self.whole or self.Z is None or self.Z.size == 0 or self._f is None:
            self.apply(None, x, y)
            return
        if self._stale:
            self._refresh()
        self._solve_load()
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

    def _finish(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """From the zone right-hand side ``zseq``: ``δ_Z``, ``δ_I = K_II⁻¹(x_I − K_IZ δ_Z)``."""
        self.S_factor.solve(self.zseq, self.dseq)
        self.dZ.array[:] = self.dseq.array_r[self.z_lo : self.z_hi]
        self.KIZ.mult(self.dZ, self.vI)
        sub = x.getSubVector(self.isI)
        self.vI.aypx(-1.0, sub)
        x.restoreSubVector(self.isI, sub)
        self.F_I.solve(self.vI, self.yI)
        self._write(y)

    def _write(self, y: PETSc.Vec) -> None:
        """``y_I ← yI``, ``y_Z ← dZ`` (the work vectors of a solve)."""
        part = y.getSubVector(self.isI)
        self.yI.copy(part)
        y.restoreSubVector(self.isI, part)
        part = y.getSubVector(self.isZ)
        self.dZ.copy(part)
        y.restoreSubVector(self.isZ, part)

    def apply(self, pc: PETSc.PC, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """``y ← J⁻¹ x``."""
        if self._stale:  # the zone changed since the set-up, the operator did not
            self._refresh()
        if self.whole:
            self.whole_ksp.solve(x, y)
            return
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

    # -- the zone's own problem: ζ_I eliminated ------------------------------------------------
    # While no point outside the zone is active, minimizing J_κ over ζ_I gives
    # ζ_I = K_II⁻¹ (f_I − K_IZ ζ_Z) and leaves j(ζ_Z) = ½ ζ_Zᵀ K_S ζ_Z − f̃·ζ_Z + the penalty at
    # the zone's points, with K_S = K_ZZ − T and f̃ = f_Z − K_ZI K_II⁻¹ f_I. Its vectors are
    # sequential and the same on every rank (``wseq`` layout).
    def zone_vector(self) -> PETSc.Vec:
        """A new sequential vector on the zone's dofs."""
        return self.wseq.duplicate()

    def gather(self, x: PETSc.Vec, out: PETSc.Vec) -> None:
        """``out ← x_Z`` on every rank."""
        sub = x.getSubVector(self.isZ)
        self.to_all.scatter(sub, out, PETSc.InsertMode.INSERT)
        x.restoreSubVector(self.isZ, sub)

    def zone_gap(self, z: PETSc.Vec) -> np.ndarray:
        """``g`` at the zone's points for ``ζ_Z = z``."""
        self.MP.mult(z, self.wP)
        return self.g0P + self.wP.array_r / self.DP

    def zone_residual(self, z: PETSc.Vec, kappa: float, r: PETSc.Vec) -> np.ndarray:
        """``r ← ∇j(z) = K_S z − f̃ + (1/κ) M_Pᵀ min(g, 0)``; returns ``g`` at the zone's points."""
        self._solve_load()
        g = self.zone_gap(z)
        self.Ks.mult(z, r)
        r.axpy(-1.0, self.f_tilde)
        self.add_zone_penalty(np.minimum(g, 0.0), kappa, r)
        return g

    def add_zone_penalty(self, values: np.ndarray, kappa: float, r: PETSc.Vec) -> None:
        """``r ← r + (1/κ) M_Pᵀ values`` (``values`` at the zone's points)."""
        self.wP.array[:] = values / kappa
        self.MP.multTransposeAdd(self.wP, r, r)

    def zone_gap_scale(self, z: PETSc.Vec) -> np.ndarray:
        """``|θ·q| + Σ_j |ζ_j c_j|`` at the zone's points (the shared ``penalty.gap_scale``)."""
        x = z.duplicate()
        total = gap_scale(self.MP, self.DP, self.g0P, z.array_r.copy(), self.component, x, self.wP)
        x.destroy()
        return total

    def _zone_jacobian(self, S: PETSc.Mat, g: np.ndarray, kappa: float) -> None:
        """``S ← K_S + (1/κ) M_Aᵀ diag(1/D_A) M_A`` (``A``: zone points with g < 0)."""
        S.zeroEntries()
        S.axpy(1.0, self.Ks, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        active = np.flatnonzero(g < 0)
        if active.size:
            P = penalty_hessian(self.MP, self.DP, active, kappa)
            S.axpy(1.0, P, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
            P.destroy()

    def _factorize_S(self, g: np.ndarray, kappa: float) -> None:
        self.S_factor.factorize(self.S)
        self._stale = False  # S is the Jacobian of the zone's problem at this iterate
        self.factored = True
        self._S_state = (kappa, g < 0)

    def forget_factorization(self) -> None:
        """Do not reuse the kept factorization of ``S`` for later Jacobians (a new solve)."""
        self._S_state = None

    def zone_newton_solve(
        self, g: np.ndarray, kappa: float, b: PETSc.Vec, d: PETSc.Vec, budget: int, rtol: float
    ) -> int:
        """``d ← S⁻¹ b`` for the zone's Jacobian ``S`` at the gap ``g`` (rank 0's on all ranks).

        With a kept factorization at this κ of a Jacobian whose active points differ from
        ``g``'s in at most ``budget`` points (each a rank-one change), conjugate gradients
        preconditioned by it, to ``rtol``; a new factorization when more points changed or
        CG needs more than ``budget`` iterations (a fixed number, so the iterates do not
        depend on timings). Returns the CG iterations (0: factorized).
        """
        t0 = time.perf_counter()
        kept = self._S_state
        changed = budget + 1
        if budget > 0 and kept is not None and kept[0] == kappa:
            changed = int(np.count_nonzero(kept[1] != (g < 0)))
        iterations = 0
        if changed <= budget:
            self._zone_jacobian(self.S_now, g, kappa)
            if self.ksp_cg is None:
                self.ksp_cg = PETSc.KSP().create(PETSc.COMM_SELF)
                self.ksp_cg.setOptionsPrefix(unique_prefix("zone_cg"))
                self.ksp_cg.setType("cg")
                self.ksp_cg.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
                self.ksp_cg.getPC().setType("python")
                self.ksp_cg.getPC().setPythonContext(_Preconditioner(self.S_factor))
                self.ksp_cg.setFromOptions()
            self.ksp_cg.setTolerances(rtol=rtol, atol=0.0, max_it=budget)
            self.ksp_cg.setOperators(self.S_now)
            self.ksp_cg.solve(b, d)
            iterations = self.ksp_cg.getIterationNumber()
            if self.ksp_cg.getConvergedReason() <= 0:
                self.S_now.copy(self.S, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
                self._factorize_S(g, kappa)
                self.S_factor.solve(b, d)
                iterations = 0
        else:
            self._zone_jacobian(self.S, g, kappa)
            self._factorize_S(g, kappa)
            self.S_factor.solve(b, d)
        self.comm.Bcast(d.array, root=0)
        self.timings["condense"] += time.perf_counter() - t0
        return iterations

    def extend(self, z: PETSc.Vec, out: PETSc.Vec, load: bool) -> None:
        """``out ← (z, ζ_I)`` with ``ζ_I = K_II⁻¹ (f_I − K_IZ z)`` (``load``) or ``−K_II⁻¹ K_IZ z``.

        One back-substitution with ``K_II``: the minimizer over ``ζ_I`` (with ``load``), or the
        matching change of ``ζ_I`` for a change ``z`` of ``ζ_Z`` (without).
        """
        self.dZ.array[:] = z.array_r[self.z_lo : self.z_hi]
        self.KIZ.mult(self.dZ, self.vI)
        self.F_I.solve(self.vI, self.yI)
        if load:
            self._solve_load()
            self.yI.aypx(-1.0, self.uf)
        else:
            self.yI.scale(-1.0)
        self._write(out)
