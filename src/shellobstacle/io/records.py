"""What every record file of a run shares: written atomically on rank 0 (a reader never sees
half a file), JSON with arrays as lists, and the versions and process environment the run had."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import socket
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mpi4py import MPI

import shellobstacle

__all__ = [
    "TIMING_VARIABLES",
    "atomic_write",
    "jsonable",
    "process_environment",
    "versions",
    "write_json",
]

#: the environment variables that change a run's timings, not its numbers (docs/user-guide.md,
#: "Process tuning"): BLAS threads, glibc's malloc, libraries loaded ahead
TIMING_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_CORETYPE",
    "MALLOC_MMAP_MAX_",
    "MALLOC_MMAP_THRESHOLD_",
    "MALLOC_TRIM_THRESHOLD_",
    "MALLOC_TOP_PAD_",
    "MALLOC_ARENA_MAX",
    "GLIBC_TUNABLES",
    "LD_PRELOAD",
)


def atomic_write(path: Path, text: str, comm=MPI.COMM_WORLD) -> None:
    """Write ``text`` on rank 0 to a temporary file and rename it into place."""
    if comm.rank != 0:
        return
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json(path: Path, data: Any, comm=MPI.COMM_WORLD) -> None:
    """Atomically write ``data`` as indented JSON (rank 0)."""
    atomic_write(path, json.dumps(data, indent=2, default=jsonable) + "\n", comm)


def jsonable(obj: Any) -> Any:
    """``obj`` as JSON can hold it: arrays as lists, anything else as its string."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)


def process_environment(environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """The :data:`TIMING_VARIABLES` set in ``environ``, with their values."""
    return {name: environ[name] for name in TIMING_VARIABLES if name in environ}


def versions(comm=MPI.COMM_WORLD) -> dict[str, Any]:
    """Package, library, interpreter and machine versions for a results record, and the
    environment variables that change timings (:func:`process_environment`)."""
    from petsc4py import PETSc

    import dolfinx
    import numpy
    import sympy

    petsc = ".".join(map(str, PETSc.Sys.getVersion()))
    return {
        "shellobstacle": shellobstacle.__version__,
        "dolfinx": dolfinx.__version__,
        "petsc": petsc,
        "numpy": numpy.__version__,
        "sympy": sympy.__version__,
        "python": platform.python_version(),
        "mpi_ranks": comm.size,
        "machine": f"{platform.machine()} {platform.system()} {socket.gethostname()}",
        "cpus": os.cpu_count(),
        "environment": process_environment(),
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }
