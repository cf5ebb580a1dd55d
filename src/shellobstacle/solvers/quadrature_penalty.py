"""The penalty term of ``J_κ`` evaluated at its quadrature points (docs/model.md §4–5;
:eq:`penalty-sum`).

The penalty ``(ε/(2κ)) ∫ ({g(ζ)}^-)² / |c| dy`` is a sum over the points ``x_k`` of its
quadrature rule (Gauss or vertex) with weights ``w_k`` (including ``|det J|``). The
obstacle's gap (:mod:`shellobstacle.obstacle`) is affine in ``ζ``:
``g(x_k) = g(θ)(x_k) + ζ_j c_j(x_k) = g⁰_k + (B ζ)_k``. With
``D_k = w_k ε / |c|(x_k)`` and ``M = diag(D) B`` (assembled once per mesh, as the matrix of
``∫ (c·u) r ε/|c| dy`` for ``u`` in the displacement space and ``r`` in the quadrature space)
the penalty and its first two derivatives are

    energy    (1/(2κ)) Σ_k D_k (min(g_k, 0))²
    residual  (1/κ) Mᵀ min(g, 0)           (its derivative in κ: −(1/κ²) Mᵀ min(g, 0))
    Jacobian  (1/κ) M_Aᵀ diag(1/D_A) M_A         (A: the points with g_k < 0)

exactly the values the UFL forms of :class:`~shellobstacle.models.problem.PenalizedProblem`
assemble with the same rule. The membrane part of ``J_κ`` is quadratic, so Newton needs
the membrane stiffness ``K`` once per mesh, and an exact line search needs only vector
operations at the quadrature points (:mod:`shellobstacle.solvers.newton.solver`).
"""

from __future__ import annotations

from mpi4py import MPI  # noqa: F401  (MPI before PETSc and DOLFINx)
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np
import ufl

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.rule import quadrature_space

__all__ = [
    "SPARSE_ROWS",
    "QuadraturePenalty",
    "add_penalty_hessian",
    "gap_scale",
    "penalty_factor",
    "penalty_hessian",
]

#: a transpose product with values nonzero at most at this fraction of the points multiplies
#: those rows of ``M`` only (:meth:`QuadraturePenalty.add_residual`)
SPARSE_ROWS = 0.1


class QuadraturePenalty:
    """The penalty of one :class:`PenalizedProblem` as operators on quadrature-point values.

    Attributes:
        M: ``diag(D) B`` (rows: owned quadrature points; Dirichlet columns zeroed).
        D: ``w_k ε / |c|(x_k)`` at the owned points.
        g0: ``g(θ)`` (the obstacle's reference gap) at the owned points.

    For a curved obstacle ``B`` and ``g0`` are those of the gap's linearization at
    ``problem.zeta_lin`` (:meth:`refresh` follows it when it moves).
    """

    def __init__(self, problem: PenalizedProblem) -> None:
        self.problem = problem
        self.Q = Q = quadrature_space(problem)
        r = ufl.TestFunction(Q)
        u = ufl.TrialFunction(problem.V)
        eps = problem.shell.material.epsilon
        weight = eps / problem.c_norm
        if problem.kappa_scale is not None:  # κ(x) = κ ρ(x): D_k = w_k ε / (|c| ρ)(x_k)
            weight = weight / problem.kappa_scale
        dxq = problem.dx_penalty
        c = problem.c
        g0 = problem.g0  # g(θ), or a curved obstacle's linearization at ζ = 0
        # M and g0 read the gap's linearization (a curved obstacle's): kept for refresh()
        self._M_form = dolfinx.fem.form(sum(c[j] * u[j] for j in range(3)) * r * weight * dxq)
        self._gD_form = dolfinx.fem.form(g0 * weight * r * dxq)
        self.M = dolfinx.fem.petsc.assemble_matrix(self._M_form, bcs=problem.bcs)
        self.M.assemble()
        self._n = n = Q.dofmap.index_map.size_local
        D = dolfinx.fem.assemble_vector(dolfinx.fem.form(weight * r * dxq))
        self.D = np.array(D.array[:n])
        self.g0 = self._reference_gap()
        self._work_q = self.M.createVecLeft()
        self._work_v = self.M.createVecRight()
        self._scaled = np.empty(n)  # (1/κ) times the values of add_residual
        self._MT: PETSc.Mat | None = None  # Mᵀ, if stored (:meth:`store_transpose`)

    def _reference_gap(self) -> np.ndarray:
        """``g0`` at the owned points: ``∫ g0 w r dy / D`` (the rule's value there)."""
        gD = dolfinx.fem.assemble_vector(self._gD_form)
        return np.array(gD.array[: self._n]) / self.D

    def refresh(self) -> None:
        """``M`` and ``g0`` assembled again, in place, after the problem's gap was linearized
        anew (:meth:`~shellobstacle.models.problem.PenalizedProblem.linearize`): ``M`` keeps
        its sparsity (the solvers that hold it keep their symbolic analyses), ``D`` does not
        move (``|c|`` is taken at ``ζ = 0``), and a stored ``Mᵀ`` is made again."""
        self.M.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(self.M, self._M_form, bcs=self.problem.bcs)
        self.M.assemble()
        self.g0 = self._reference_gap()
        if self._MT is not None:
            self._MT.destroy()
            self._MT = self.M.transpose(PETSc.Mat())

    @property
    def num_points(self) -> int:
        """Global number of quadrature points of the penalty."""
        return self.Q.dofmap.index_map.size_global

    # -- values at the points ----------------------------------------------------------------
    def by_cell(self, values: np.ndarray) -> np.ndarray:
        """Point values (owned points, local order) as rows of the owned cells: shape
        ``(cells, points per cell)``, row ``c`` holding the values at cell ``c``'s points."""
        Q = self.Q
        cells = Q.mesh.topology.index_map(Q.mesh.topology.dim).size_local
        return values[Q.dofmap.list[:cells]]

    def apply_B(self, x: PETSc.Vec, out: np.ndarray | None = None) -> np.ndarray:
        """``B x`` at the owned points (``x`` a displacement vector), into ``out`` if given."""
        self.M.mult(x, self._work_q)
        return np.divide(self._work_q.array_r, self.D, out=out)

    def gap(self, zeta: PETSc.Vec, out: np.ndarray | None = None) -> np.ndarray:
        """``g(ζ)`` at the owned points, into ``out`` if given."""
        Bz = self.apply_B(zeta, out)
        return np.add(self.g0, Bz, out=Bz)

    def gap_scale(self, zeta: PETSc.Vec, points: np.ndarray) -> np.ndarray:
        """``|g(θ)| + Σ_j |ζ_j c_j|`` at the owned ``points`` (local positions; collective).

        Only the rows of ``points`` are multiplied (:func:`gap_scale` on ``M``'s submatrix;
        each row's sum is the one ``M`` computes): the floor needs the active points only,
        about 1 % of the 7.7 M points at 1.92 M dofs.
        """
        x = self._work_v
        n = x.getLocalSize()
        with zeta.localForm() as z:
            owned = z.array_r[:n].copy()
        MP = rows_of(self.M, points)
        w = MP.createVecLeft()
        total = gap_scale(MP, self.D[points], self.g0[points], owned, np.arange(n) % 3, x, w)
        MP.destroy()
        w.destroy()
        return total

    # -- derivatives -------------------------------------------------------------------------
    def energy(self, g: np.ndarray, kappa: float) -> float:
        """``(1/(2κ)) Σ D_k min(g_k, 0)²`` (global)."""
        local = float(np.dot(self.D, np.minimum(g, 0.0) ** 2)) / (2.0 * kappa)
        return self.problem.mesh.comm.allreduce(local)

    def store_transpose(self) -> None:
        """Keep ``Mᵀ`` as a matrix of its own: :meth:`add_residual` then multiplies by it,
        faster than ``M``'s transpose product, for a second copy of ``M``
        (worth it for the Brezis–Sibony iteration's 10⁵ residuals on small meshes)."""
        if self._MT is None:
            self._MT = self.M.transpose(PETSc.Mat())

    def add_residual(self, values: np.ndarray, kappa: float, b: PETSc.Vec) -> None:
        """``b ← b + (1/κ) Mᵀ values`` (``values`` at the owned points, e.g. ``min(g, 0)``)."""
        self._add_transpose(np.divide(values, kappa, out=self._scaled), b)

    def add_kappa_derivative(self, g: np.ndarray, kappa: float, b: PETSc.Vec) -> None:
        """``b ← b − ∂R/∂κ = b + (1/κ²) Mᵀ min(g, 0)`` at the gap ``g`` (owned points): the
        right-hand side of the tangent ``J dζ/dκ = −∂R/∂κ`` of the solution path."""
        self._add_transpose(np.minimum(g, 0.0) / (kappa * kappa), b)

    def _add_transpose(self, values: np.ndarray, b: PETSc.Vec) -> None:
        """``b ← b + Mᵀ values``; with ``values`` nonzero at a few points (the active ones,
        about 1 %: :data:`SPARSE_ROWS`) only their rows of ``M`` are multiplied, which adds
        the same terms in the same order (the other rows add zeros)."""
        if self._MT is not None:
            self._work_q.array[:] = values
            self._MT.multAdd(self._work_q, b, b)
            return
        rows = np.flatnonzero(values)
        count = self.problem.mesh.comm.allreduce(rows.size)
        if count > SPARSE_ROWS * self.num_points:
            self._work_q.array[:] = values
            self.M.multTransposeAdd(self._work_q, b, b)
        elif count:
            MA = rows_of(self.M, rows)
            w = MA.createVecLeft()
            w.array[:] = values[rows]
            MA.multTransposeAdd(w, b, b)
            for obj in (MA, w):
                obj.destroy()

    def jacobian(self, g: np.ndarray, kappa: float) -> PETSc.Mat | None:
        """``(1/κ) M_Aᵀ diag(1/D_A) M_A`` for the active points ``g < 0`` (None if A = ∅)."""
        active = np.flatnonzero(g < 0)
        if self.problem.mesh.comm.allreduce(active.size) == 0:
            return None
        return penalty_hessian(self.M, self.D, active, kappa)


def gap_scale(
    M: PETSc.Mat,
    D: np.ndarray,
    g0: np.ndarray,
    zeta: np.ndarray,
    component: np.ndarray,
    x: PETSc.Vec,
    w: PETSc.Vec,
) -> np.ndarray:
    """``|g(θ)| + Σ_j |ζ_j c_j|`` at the rows of a point matrix ``M = diag(D) B``: the size of
    the terms of ``g = g(θ) + ζ_j c_j``, the scale of its round-off.

    ``c_j ζ_j`` is ``B`` applied to ``ζ`` with every component but ``j`` set to 0; ``zeta``
    holds the local entries of ``ζ`` and ``component`` the ``j`` of each; ``x`` (a vector of
    ``M``'s columns) and ``w`` (of its rows) are work vectors.
    """
    total = np.abs(g0)
    for j in range(3):
        x.array[:] = np.where(component == j, zeta, 0.0)
        M.mult(x, w)
        total += np.abs(w.array_r / D)
    return total


def rows_of(M: PETSc.Mat, points: np.ndarray) -> PETSc.Mat:
    """The owned rows ``points`` (local positions) of ``M``, with ``M``'s column layout."""
    comm = M.getComm()
    start = M.getOwnershipRange()[0]
    rows = PETSc.IS().createGeneral((start + points).astype(PETSc.IntType), comm=comm)
    c0, c1 = M.getOwnershipRangeColumn()
    cols = PETSc.IS().createStride(c1 - c0, c0, 1, comm=comm)
    sub = M.createSubMatrix(rows, cols)
    rows.destroy()
    cols.destroy()
    return sub


def penalty_hessian(M: PETSc.Mat, D: np.ndarray, active: np.ndarray, kappa: float) -> PETSc.Mat:
    """``(1/κ) M_Aᵀ diag(1/D_A) M_A`` for the owned rows ``active`` (local positions) of ``M``.

    ``M`` is a point matrix ``diag(D) B`` (parallel, or the sequential one of a contact zone).
    """
    S = penalty_factor(M, D, active, kappa)
    H = S.transposeMatMult(S)
    S.destroy()
    return H


def penalty_factor(M: PETSc.Mat, D: np.ndarray, active: np.ndarray, kappa: float) -> PETSc.Mat:
    """``S = diag(1/√(κ D_A)) M_A``, the factor of the penalty Hessian ``Sᵀ S``
    (:func:`penalty_hessian`), for the owned rows ``active`` of ``M``; ``S P`` gives the
    Hessian's Galerkin product ``(S P)ᵀ (S P) = Pᵀ (Sᵀ S) P`` without the ``n × n`` matrix."""
    S = rows_of(M, active)
    scale = S.createVecLeft()
    scale.array[:] = 1.0 / np.sqrt(kappa * D[active])
    S.diagonalScale(L=scale)
    scale.destroy()
    return S


def add_penalty_hessian(
    A: PETSc.Mat, M: PETSc.Mat, D: np.ndarray, active: np.ndarray, kappa: float, sign: float
) -> None:
    """``A ← A + sign (1/κ) M_Aᵀ diag(1/D_A) M_A`` for the owned rows ``active`` of ``M``,
    the product taken on the columns those rows touch (collective).

    :func:`penalty_hessian` makes an ``n × n`` matrix, whose set-up costs ``O(n)`` however
    few the points; here each rank multiplies its rows on their own columns, renumbered in
    order, and adds the result into ``A`` (whose pattern holds it): serially the same sums
    in the same order, so the same values as :func:`penalty_hessian` and ``MatAXPY``; with
    several ranks a product shared by two ranks is summed in ``A``'s assembly instead.
    """
    MA = rows_of(M, active)
    indptr, indices, values = MA.getValuesCSR()
    MA.destroy()
    values = values * np.repeat(1.0 / np.sqrt(kappa * D[active]), np.diff(indptr))
    columns, compact = np.unique(indices, return_inverse=True)
    if columns.size:
        local = PETSc.Mat().createAIJ(
            (indptr.size - 1, columns.size),
            csr=(indptr, compact.astype(PETSc.IntType), values),
            comm=PETSc.COMM_SELF,
        )
        H = local.transposeMatMult(local)
        rows, cols, entries = H.getValuesCSR()
        for obj in (local, H):
            obj.destroy()
        A.setValuesIJV(
            rows, columns[cols].astype(PETSc.IntType), sign * entries,
            addv=PETSc.InsertMode.ADD_VALUES, rowmap=columns.astype(PETSc.IntType),
        )  # fmt: skip
    A.assemble()
