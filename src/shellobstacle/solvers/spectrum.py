"""Extreme eigenvalues of symmetric positive definite pencils ``A v = λ B v`` (SLEPc).

The Brezis–Sibony step and its contraction bound need the smallest eigenvalue of the
stiffness and the largest of the all-active Jacobian, both against the mass matrix
(:mod:`~shellobstacle.solvers.brezis_sibony.iteration`).
"""

from __future__ import annotations

from mpi4py import MPI  # noqa: F401  (before PETSc and SLEPc: the MPI runtime they link to)
from petsc4py import PETSc
from slepc4py import SLEPc

from shellobstacle.solvers.base import ConvergenceError, unique_prefix

__all__ = ["extreme_eigenvalue"]


def extreme_eigenvalue(
    A: PETSc.Mat, B: PETSc.Mat, largest: bool, tol: float = 1e-8, max_iterations: int = 1000
) -> float:
    """The largest (``largest``) or smallest eigenvalue of the SPD pencil ``A v = λ B v``.

    Krylov–Schur on the generalized Hermitian problem: for the largest, the spectral
    transformation ``B⁻¹A``; for the smallest, shift-and-invert at 0, ``A⁻¹B`` (both with
    MUMPS' LU).

    Raises:
        ConvergenceError: SLEPc did not converge.
    """
    eps = SLEPc.EPS().create(A.getComm())
    eps.setOperators(A, B)
    eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
    eps.setDimensions(nev=1)
    eps.setTolerances(tol, max_iterations)
    st = eps.getST()
    if largest:
        eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
        st.setType(SLEPc.ST.Type.SHIFT)  # applies B⁻¹ A
    else:
        st.setType(SLEPc.ST.Type.SINVERT)  # applies (A − 0·B)⁻¹ B
        eps.setTarget(0.0)
        eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    ksp = st.getKSP()
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    eps.setOptionsPrefix(unique_prefix("eig_max" if largest else "eig_min"))
    eps.setFromOptions()
    eps.solve()
    nconv = eps.getConverged()
    if nconv < 1:
        its = eps.getIterationNumber()
        eps.destroy()
        which = "largest" if largest else "smallest"
        raise ConvergenceError(
            f"SLEPc did not converge to the {which} eigenvalue in {its} iterations; raise "
            "eigen_max_iterations or give xi explicitly"
        )
    values = [eps.getEigenvalue(i).real for i in range(nconv)]
    eps.destroy()
    return float(max(values) if largest else min(values))
