"""Self-describing result folders: never overwritten silently, files written atomically."""

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

__all__ = ["ResultsError", "atomic_write", "prepare_folder", "versions", "write_json"]


class ResultsError(ValueError):
    """The output folder cannot be used as asked (it exists and holds results)."""


def prepare_folder(
    out: str | Path | None,
    default: str,
    overwrite: bool,
    comm=MPI.COMM_WORLD,
    resume: bool = False,
) -> Path:
    """Create the result folder (rank 0) and return it on every rank.

    With ``out=None`` a new folder ``default``, ``default-2``, ... is chosen so earlier
    results are never touched. An explicit ``out`` that exists and is not empty is
    refused unless ``overwrite``. With ``resume`` the folder must be given and hold the
    records of an interrupted run (``steps/meta.json``); it is then written into.

    Raises:
        ResultsError: the folder holds earlier results and ``overwrite`` is false, or
            ``resume`` is asked for without such a folder.
    """
    error = None
    path: Path | None = None
    if comm.rank == 0:
        if resume:
            path = None if out is None else Path(out)
            if path is None:
                error = "--resume needs -o OUT, the result folder of the interrupted run"
            elif not path.is_dir():
                error = (
                    f"--resume: '{path}' does not exist: there is nothing to resume "
                    "(run without --resume to start)"
                )
            elif not (path / "steps" / "meta.json").is_file():
                error = (
                    f"--resume: '{path}' holds no records of an interrupted run "
                    "(no steps/meta.json): cannot resume"
                )
        elif out is None:
            base = Path(default)
            path, k = base, 1
            while path.exists():
                k += 1
                path = base.with_name(f"{base.name}-{k}")
        else:
            path = Path(out)
            if path.exists() and any(path.iterdir()) and not overwrite:
                error = (
                    f"output folder '{path}' already holds results; choose another with -o, "
                    "or pass --overwrite to replace them (or --resume to continue an "
                    "interrupted experiment or reproduce run)"
                )
        if error is None and not resume:
            path.mkdir(parents=True, exist_ok=True)
    error, path = comm.bcast((error, path), root=0)
    if error:
        raise ResultsError(error)
    return Path(path)


def atomic_write(path: Path, text: str, comm=MPI.COMM_WORLD) -> None:
    """Write ``text`` on rank 0 to a temporary file and rename it into place."""
    if comm.rank != 0:
        return
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json(path: Path, data: Any, comm=MPI.COMM_WORLD) -> None:
    """Atomically write ``data`` as indented JSON (rank 0)."""
    atomic_write(path, json.dumps(data, indent=2, default=_jsonable) + "\n", comm)


def _jsonable(obj: Any) -> Any:
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
