"""A DGEMMT made of DGEMM blocks for MUMPS' LDLᵀ factorizations, loaded ahead of PETSc.

MUMPS updates the contribution block of every front of an LDLᵀ factorization with DGEMMT (one
triangle of a symmetric product). The DOLFINx wheel's OpenBLAS computes DGEMMT column by column
with GEMV (OpenBLAS issue 4921), slower than one DGEMM of twice the flops
(``dgemm.py --gemmt``). :func:`load` compiles ``native/gemmt.c`` (cached in
``$XDG_CACHE_HOME/shellobstacle``, by a hash of the source and the compiler) and loads it with
``RTLD_GLOBAL`` before PETSc is loaded, so that MUMPS calls its ``dgemmt_``: each block of 128
columns by DGEMM, small calls passed to OpenBLAS' own DGEMMT. The result equals DGEMMT's up to
the order of floating-point sums. Only with the DOLFINx wheel's OpenBLAS, a C compiler, and
before PETSc is loaded.

Run a command or a benchmark script with it (docs/perf/tuning.md measures what it saves)::

    .venv/bin/python benchmarks/blocked_gemmt.py solve examples/paper.toml \\
        --set domain.h=0.0012 --set 'solver.linear_solver="direct"'
    .venv/bin/python benchmarks/blocked_gemmt.py benchmarks/batch1.py --target 0.0029
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib.util
import os
import runpy
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

SOURCE = Path(__file__).with_name("native") / "gemmt.c"


def openblas() -> Path:
    """The OpenBLAS that the DOLFINx wheel's PETSc links (``dolfinx_solver/lib``)."""
    spec = importlib.util.find_spec("dolfinx_solver")
    path = Path(spec.origin).parent / "lib" / "libopenblas.so.0" if spec and spec.origin else None
    if path is None or not path.exists():
        raise SystemExit("blocked_gemmt: no DOLFINx wheel OpenBLAS (dolfinx_solver/lib)")
    return path


def build() -> Path:
    """``native/gemmt.c`` compiled to a shared library (once per source and compiler)."""
    cc = os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc"
    compiler = shutil.which(cc.split()[0])
    if compiler is None:
        raise SystemExit(f"blocked_gemmt: no C compiler ({cc})")
    tag = hashlib.sha256(SOURCE.read_bytes() + compiler.encode()).hexdigest()[:16]
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "shellobstacle"
    target = cache / f"gemmt-{tag}.so"
    if not target.exists():
        cache.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        flags = ["-O2", "-fPIC", "-shared", "-fvisibility=hidden"]
        subprocess.run([compiler, *flags, str(SOURCE), "-o", str(tmp), "-ldl"], check=True)
        os.replace(tmp, target)
    return target


def load() -> ctypes.CDLL:
    """Build and load the blocked DGEMMT ahead of PETSc's OpenBLAS; returns the library."""
    from shellobstacle.compat import load_mpi_first

    if "petsc4py.PETSc" in sys.modules:
        raise SystemExit("blocked_gemmt: PETSc is loaded already; load the DGEMMT first")
    load_mpi_first()  # (the wheel's OpenBLAS links its MPI)
    library = ctypes.CDLL(str(build()), mode=os.RTLD_GLOBAL | os.RTLD_NOW)
    library.shellobstacle_gemmt_init.argtypes = [ctypes.c_char_p]
    if library.shellobstacle_gemmt_init(str(openblas()).encode()) != 0:
        raise SystemExit("blocked_gemmt: no dgemm_/dgemmt_ in the wheel's OpenBLAS")
    return library


def calls() -> dict[str, int] | None:
    """DGEMMT calls so far in this process, taken in blocks or passed to OpenBLAS; None when
    the blocked DGEMMT is not loaded."""
    counter = getattr(ctypes.CDLL(None), "shellobstacle_gemmt_calls", None)
    if counter is None:
        return None
    counter.argtypes, counter.restype = [ctypes.c_int], ctypes.c_long
    return {"blocked": counter(1), "forwarded": counter(0)}


def main() -> int:
    """Load the blocked DGEMMT, then run a benchmark script (``*.py``) or a ``shellobstacle``
    command with the remaining arguments."""
    load()
    if len(sys.argv) > 1 and sys.argv[1].endswith(".py"):
        sys.argv = sys.argv[1:]
        runpy.run_path(sys.argv[0], run_name="__main__")
        return 0
    sys.argv = ["shellobstacle", *sys.argv[1:]]
    from shellobstacle.__main__ import main as command

    return command()


if __name__ == "__main__":
    raise SystemExit(main())
