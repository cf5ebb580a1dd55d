"""DGEMMT in blocks of DGEMM for MUMPS' LDLᵀ factorizations (``native/gemmt.c``).

MUMPS updates the contribution block of every front of an LDLᵀ (Cholesky) factorization with
DGEMMT, the product that computes one triangle of a symmetric result. The OpenBLAS of the
DOLFINx wheel computes DGEMMT column by column with GEMV, slower than a whole DGEMM that does
twice its flops (``benchmarks/dgemm.py --gemmt``). :func:`block_gemmt` compiles
``native/gemmt.c`` once per machine (:mod:`.build`) and loads it with ``RTLD_GLOBAL`` before
PETSc is loaded, so that MUMPS calls its ``dgemmt_``: each block of 128 columns by DGEMM (the
diagonal block whole into a buffer, its triangle added to C), small calls passed to
OpenBLAS' own DGEMMT. The result equals DGEMMT's up to the order of floating-point sums.

Nothing is changed (and the policy says why) when PETSc is already loaded, without the
DOLFINx wheel's OpenBLAS (conda, Docker, source builds), or when the library cannot be
compiled or loaded.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

from shellobstacle.tuning.build import build, compiler

__all__ = ["block_gemmt", "gemmt_calls", "openblas_path"]

_library: ctypes.CDLL | None = None


def openblas_path() -> Path | None:
    """The OpenBLAS that the DOLFINx wheel's PETSc links (``dolfinx_solver/lib``), or None."""
    spec = importlib.util.find_spec("dolfinx_solver")
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "lib" / "libopenblas.so.0"
    return path if path.exists() else None


def block_gemmt(environ: Mapping[str, str] = os.environ) -> str:
    """Give PETSc's MUMPS the blocked DGEMMT; returns ``"blocked"``, or ``"openblas (why)"``."""
    global _library
    if _library is not None:
        return "blocked"
    if "petsc4py.PETSc" in sys.modules:
        return "openblas (PETSc was loaded before the tuning)"
    openblas = openblas_path()
    if openblas is None:
        return "openblas (no DOLFINx wheel OpenBLAS)"
    cc = compiler()
    if cc is None:
        return "openblas (no C compiler)"
    try:
        library = ctypes.CDLL(str(build("gemmt", cc, ["-ldl"])), mode=os.RTLD_GLOBAL | os.RTLD_NOW)
    except (OSError, RuntimeError, subprocess.SubprocessError) as err:
        return f"openblas (the blocked DGEMMT did not build or load: {err})"
    library.shellobstacle_gemmt_init.argtypes = [ctypes.c_char_p]
    if library.shellobstacle_gemmt_init(str(openblas).encode()) != 0:
        return "openblas (no dgemm_/dgemmt_ in the wheel's OpenBLAS)"
    library.shellobstacle_gemmt_calls.argtypes = [ctypes.c_int]
    library.shellobstacle_gemmt_calls.restype = ctypes.c_long
    _library = library
    return "blocked"


def gemmt_calls() -> dict[str, int]:
    """DGEMMT calls so far in this process: taken in blocks, passed to OpenBLAS."""
    if _library is None:
        return {"blocked": 0, "forwarded": 0}
    return {
        "blocked": int(_library.shellobstacle_gemmt_calls(1)),
        "forwarded": int(_library.shellobstacle_gemmt_calls(0)),
    }
