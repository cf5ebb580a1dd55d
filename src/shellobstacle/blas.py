"""DGEMMT in blocks of DGEMM for MUMPS' LDLᵀ factorizations (``native/gemmt.c``).

MUMPS updates the contribution block of every front of an LDLᵀ (Cholesky) factorization with
DGEMMT, the product that computes one triangle of a symmetric result. The OpenBLAS of the
DOLFINx wheel (0.3.32) computes DGEMMT column by column with GEMV: for n = 300 … 3,000 it took
1.15–1.46× the time of a whole DGEMM that does twice its flops (``benchmarks/dgemm.py --gemmt``),
and in a serial solve at 1.93 M dofs its GEMV kernel was 19 % of all CPU samples
(docs/performance.md, eleventh session).

:func:`block_gemmt` runs when :mod:`shellobstacle.compat` is imported, before PETSc is loaded:
it compiles ``native/gemmt.c`` once per machine (with the C compiler that DOLFINx's form
compiler uses too; cached under ``$XDG_CACHE_HOME/shellobstacle`` or
``~/.cache/shellobstacle``) and loads it with ``RTLD_GLOBAL``, so that PETSc's MUMPS calls its
``dgemmt_``. That one computes each block of 128 columns by DGEMM (the diagonal block whole
into a buffer, its triangle added to C) and passes small calls (n ≤ 256, α = 0, k = 0) to
OpenBLAS' own DGEMMT. The result equals DGEMMT's up to the order of floating-point sums.

Nothing is changed (and :func:`gemmt_policy` says why) with ``SHELLOBSTACLE_GEMMT=openblas``,
when PETSc is already loaded, without the DOLFINx wheel's OpenBLAS (conda, Docker, source
builds), or when the library cannot be compiled or loaded.
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
from collections.abc import Mapping
from pathlib import Path

__all__ = ["OPT_OUT", "block_gemmt", "gemmt_calls", "gemmt_policy", "openblas_path"]

OPT_OUT = "SHELLOBSTACLE_GEMMT"  # "openblas": leave OpenBLAS' DGEMMT in place
SOURCE = Path(__file__).with_name("native") / "gemmt.c"

_policy = "openblas (not set up)"
_library: ctypes.CDLL | None = None


def openblas_path() -> Path | None:
    """The OpenBLAS that the DOLFINx wheel's PETSc links (``dolfinx_solver/lib``), or None."""
    spec = importlib.util.find_spec("dolfinx_solver")
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "lib" / "libopenblas.so.0"
    return path if path.exists() else None


def _cache_dir() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "shellobstacle"


def _compiler() -> str | None:
    cc = os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc"
    return shutil.which(cc.split()[0]) if cc.split() else None


def _build(cc: str) -> Path:
    """The compiled library, built once per source and compiler (atomic rename)."""
    source = SOURCE.read_bytes()
    tag = hashlib.sha256(source + cc.encode()).hexdigest()[:16]
    target = _cache_dir() / f"gemmt-{tag}.so"
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    command = [cc, "-O2", "-fPIC", "-shared", "-fvisibility=hidden", str(SOURCE), "-o", str(tmp)]
    try:
        subprocess.run([*command, "-ldl"], check=True, capture_output=True, timeout=120)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    for stale in target.parent.glob("gemmt-*.so"):  # builds of earlier sources or compilers
        if stale != target:
            stale.unlink(missing_ok=True)
    return target


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
    cc = _compiler()
    if cc is None:
        _policy = "openblas (no C compiler)"
        return False
    try:
        library = ctypes.CDLL(str(_build(cc)), mode=os.RTLD_GLOBAL | os.RTLD_NOW)
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
