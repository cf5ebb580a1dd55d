"""The PETSc functions the solvers call that petsc4py does not wrap, through ``ctypes``.

MUMPS' selected inverse entries (``MatMumpsGetInverse``), its variable blocks
(``MatMumpsSetBlk``), Chebyshev's eigenvalue bounds (``KSPChebyshevSetEigenvalues``,
``KSPChebyshevEstEigGetKSP``) and a matrix's absolute row sums (``MatGetRowSumAbs``) are
looked up in the libpetsc that petsc4py runs on, through
petsc4py's own compiled module: the dynamic linker's lookup on that module's handle searches it
and the libraries it was linked with, libpetsc among them, so no file is searched for and no
other PETSc can be picked. Where PETSc lacks a function (an older release, a build without MUMPS,
a static build that hides its symbols), :func:`function` is None and :func:`missing` says
why; each caller then takes its path without it.
"""

from __future__ import annotations

import ctypes
import os

from mpi4py import MPI  # noqa: F401  (loads MPI before petsc4py)
from petsc4py import PETSc

import numpy as np

__all__ = ["SIGNATURES", "function", "missing"]

_INT = ctypes.c_int64 if np.dtype(PETSc.IntType) == np.int64 else ctypes.c_int32
#: the functions used: name → (argument types, result type), as PETSc declares them
SIGNATURES: dict[str, tuple[list, type]] = {
    "MatMumpsGetInverse": ([ctypes.c_void_p, ctypes.c_void_p], ctypes.c_int),
    "MatMumpsSetBlk": ([ctypes.c_void_p, _INT, ctypes.c_void_p, ctypes.c_void_p], ctypes.c_int),
    "KSPChebyshevSetEigenvalues": (
        [ctypes.c_void_p, ctypes.c_double, ctypes.c_double],
        ctypes.c_int,
    ),
    "KSPChebyshevEstEigGetKSP": ([ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)], ctypes.c_int),
    "MatGetRowSumAbs": ([ctypes.c_void_p, ctypes.c_void_p], ctypes.c_int),
}


def _lookup(name: str) -> ctypes._CFuncPtr:
    """The C function ``name`` seen from petsc4py's module (OSError, AttributeError if not)."""
    library = ctypes.CDLL(PETSc.__file__, mode=getattr(os, "RTLD_NOLOAD", 0))
    return getattr(library, name)


def missing(name: str) -> str | None:
    """None when PETSc's function ``name`` (one of :data:`SIGNATURES`) can be called, else
    why not."""
    try:
        _lookup(name)
    except (OSError, AttributeError) as err:
        return f"PETSc has no {name} ({err})"
    return None


def function(name: str) -> ctypes._CFuncPtr | None:
    """PETSc's function ``name`` (one of :data:`SIGNATURES`) with its C signature, or None
    where PETSc lacks it."""
    if missing(name) is not None:
        return None
    f = _lookup(name)
    f.argtypes, f.restype = SIGNATURES[name]
    return f
