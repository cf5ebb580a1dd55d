"""The tangent stiffness ``K(ζ) = J''(ζ)`` of a nonlinear energy, factorized with its inertia
(docs/model.md §11.1).

``K`` is symmetric (dead loads) but not definite away from a stable equilibrium: MUMPS'
symmetric indefinite LDLᵀ (``SYM = 2``, PETSc's Cholesky without the SPD flag) factorizes it
and counts its negative pivots, which by Sylvester's law of inertia are its negative
eigenvalues (INFOG(12); ICNTL(13) = 1 keeps the root node out of ScaLAPACK, whose pivots
MUMPS does not count). A shift ``K + τ D``, ``D`` the diagonal of ``|K|``, makes it definite for
``τ`` large enough.
"""

from __future__ import annotations

from mpi4py import MPI  # noqa: F401  (before PETSc: the MPI runtime PETSc links to)
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc

from shellobstacle.solvers.base import factorization_pc, factorize, unique_prefix

__all__ = ["Tangent"]


class Tangent:
    """``K(ζ)`` (Dirichlet rows and columns identity) and its LDLᵀ factorization.

    Attributes:
        K: the matrix; negative: the negative and null pivots of the last factorization.
    """

    def __init__(self, jacobian: dolfinx.fem.Form, bcs: list[dolfinx.fem.DirichletBC]) -> None:
        self.jacobian, self.bcs = jacobian, bcs
        self.K = dolfinx.fem.petsc.create_matrix(jacobian)
        self._diagonal = self.K.createVecLeft()
        self.ksp = PETSc.KSP().create(self.K.getComm())
        self.ksp.setOptionsPrefix(unique_prefix("nonlinear_tangent"))
        self.ksp.setOperators(self.K)
        self.ksp.setType("preonly")
        factorization_pc(self.ksp.getPC(), "cholesky", "mumps", icntl={13: 1, 24: 1})
        self.ksp.setFromOptions()
        self.negative = 0

    def assemble(self) -> None:
        """``K`` at the current ``ζ`` (the forms' coefficient)."""
        self.K.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(self.K, self.jacobian, bcs=self.bcs)
        self.K.assemble()
        self.K.getDiagonal(self._diagonal)

    def factor(self, shift: float = 0.0) -> int:
        """Factorize ``K + shift·D`` (``K`` as last assembled; it keeps the shift until the next
        :meth:`assemble`); returns its negative and null pivots (MUMPS' null-pivot detection,
        ICNTL(24) = 1, which PETSc's inertia needs)."""
        diagonal = self._diagonal.copy()
        if shift:
            scaled = self._diagonal.copy()
            scaled.abs()
            diagonal.axpy(shift, scaled)
        self.K.setDiagonal(diagonal, addv=PETSc.InsertMode.INSERT_VALUES)
        self.ksp.setOperators(self.K)
        factorize(self.ksp, "the nonlinear tangent stiffness")
        negative, null, _ = self.ksp.getPC().getFactorMatrix().getInertia()
        self.negative = negative + null
        return self.negative

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """``x ← (K + shift·D)⁻¹ b`` with the last factorization."""
        self.ksp.solve(b, x)
