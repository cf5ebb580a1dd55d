"""DGEMMT in blocks of DGEMM for MUMPS' LDLᵀ factorizations (``native/gemmt.c``).

MUMPS updates the contribution block of every front of an LDLᵀ (Cholesky) factorization with
DGEMMT, the product that computes one triangle of a symmetric result. The OpenBLAS of the
DOLFINx wheel (0.3.32) computes DGEMMT column by column with GEMV: for n = 300 … 3,000 it took
1.15–1.46× the time of a whole DGEMM that does twice its flops (``benchmarks/dgemm.py --gemmt``),
and in a serial solve at 1.93 M dofs its GEMV kernel was 19 % of all CPU samples
(docs/performance.md, eleventh session).

:func:`block_gemmt` runs when :mod:`shellobstacle.compat` is imported, before PETSc is loaded:
it compiles ``native/gemmt.c`` once per machine (:mod:`shellobstacle.cbuild`) and loads it
with ``RTLD_GLOBAL``, so that PETSc's MUMPS calls its ``dgemmt_``. That one computes each
block of 128 columns by DGEMM (the diagonal block whole into a buffer, its triangle added to
C) and passes small calls (n ≤ 256, α = 0, k = 0) to OpenBLAS' own DGEMMT. The result
equals DGEMMT's up to the order of floating-point sums.

Nothing is changed (and :func:`gemmt_policy` says why) with ``SHELLOBSTACLE_GEMMT=openblas``,
when PETSc is already loaded, without the DOLFINx wheel's OpenBLAS (conda, Docker, source
builds), or when the library cannot be compiled or loaded.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

from shellobstacle.cbuild import build, compiler

__all__ = ["OPT_OUT", "block_gemmt", "gemmt_calls", "gemmt_policy", "openblas_path"]

OPT_OUT = "SHELLOBSTACLE_GEMMT"  # "openblas": leave OpenBLAS' DGEMMT in place

_policy = "openblas (not set up)"
_library: ctypes.CDLL | None = None


def openblas_path() -> Path | None:
    """The OpenBLAS that the DOLFINx wheel's PETSc links (``dolfinx_solver/lib``), or None."""
    spec = importlib.util.find_spec("dolfinx_solver")
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "lib" / "libopenblas.so.0"
    return path if path.exists() else None


def block_gemmt(environ: Mapping[str, str] = os.environ) -> bool:
    """Give PETSc's MUMPS the blocked DGEMMT, unless the user or the setting rules it out.

    Returns whether it was installed; :func:`gemmt_policy` records the outcome.
    """
    global _policy, _library
    if _library is not None:
        return True
    if environ.get(OPT_OUT, "").strip().lower() == "openblas":
        _policy = f"openblas ({OPT_OUT}=openblas)"
        return False
    if "petsc4py.PETSc" in sys.modules:
        _policy = "openblas (PETSc was loaded before shellobstacle)"
        return False
    openblas = openblas_path()
    if openblas is None:
        _policy = "openblas (no DOLFINx wheel OpenBLAS)"
        return False
    cc = compiler()
    if cc is None:
        _policy = "openblas (no C compiler)"
        return False
    try:
        library = ctypes.CDLL(str(build("gemmt", cc, ["-ldl"])), mode=os.RTLD_GLOBAL | os.RTLD_NOW)
    except (OSError, RuntimeError, subprocess.SubprocessError) as err:
        _policy = f"openblas (the blocked DGEMMT did not build or load: {err})"
        return False
    library.shellobstacle_gemmt_init.argtypes = [ctypes.c_char_p]
    if library.shellobstacle_gemmt_init(str(openblas).encode()) != 0:
        _policy = "openblas (no dgemm_/dgemmt_ in the wheel's OpenBLAS)"
        return False
    library.shellobstacle_gemmt_calls.argtypes = [ctypes.c_int]
    library.shellobstacle_gemmt_calls.restype = ctypes.c_long
    _library = library
    _policy = "blocked"
    return True


def gemmt_policy() -> str:
    """``"blocked"`` when MUMPS runs on the blocked DGEMMT, else ``"openblas (why)"``."""
    return _policy


def gemmt_calls() -> dict[str, int]:
    """DGEMMT calls so far in this process: taken in blocks, passed to OpenBLAS."""
    if _library is None:
        return {"blocked": 0, "forwarded": 0}
    return {
        "blocked": int(_library.shellobstacle_gemmt_calls(1)),
        "forwarded": int(_library.shellobstacle_gemmt_calls(0)),
    }
