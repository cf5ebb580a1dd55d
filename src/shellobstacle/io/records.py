"""What every record file of a run shares: written atomically on rank 0 (a reader never sees
half a file), JSON with arrays as lists, and the versions and process tuning the run had."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import socket
from pathlib import Path
from typing import Any

from mpi4py import MPI

import shellobstacle

__all__ = ["atomic_write", "jsonable", "versions", "write_json"]


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


def versions(comm=MPI.COMM_WORLD) -> dict[str, Any]:
    """Package, library, interpreter and machine versions for a results record, and the
    process tuning that changes timings (:mod:`shellobstacle.tuning`)."""
    from petsc4py import PETSc

    import dolfinx
    import numpy
    import sympy

    from shellobstacle import tuning

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
        "tuning": tuning.policies(),
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }
