"""``shellobstacle doctor``: the environment, the versions, and the process tuning in force.

It prints the versions of the key dependencies, the environment variables that tune the
process (docs/user-guide.md, "Process tuning") and the threads of NumPy's BLAS, and names
known problems of an environment, with their fix: a release outside the range pyproject.toml
pins (the tested one), a forced OpenBLAS kernel family that crashed NumPy's BLAS, MUMPS'
selected inverse entries out of reach (the contact zone's condensation then falls back to one
factorization per κ), broken entries of the FFCx cache (:mod:`.jit_cache`), which ``--repair``
removes.
"""

from __future__ import annotations

import contextlib
import os
import platform
from collections.abc import Mapping

from shellobstacle.cli import jit_cache

__all__ = [
    "CRASHING_CORETYPES",
    "blas_threads",
    "coretype_warning",
    "numpy_blas_config",
    "repair_cache",
    "report",
]

#: OPENBLAS_CORETYPE values (lower case) with which NumPy's OpenBLAS 0.3.34 (NumPy
#: 2.5.2–2.5.5) died of a segmentation fault in a 500 × 500 matrix product on an AVX-512
#: machine (``benchmarks/numpy_coretype.py`` checks a machine)
CRASHING_CORETYPES = ("haswell", "zen")
CRASHING_OPENBLAS = "OpenBLAS 0.3.34"


def numpy_blas_config() -> str:
    """The configuration string of NumPy's BLAS (``"OpenBLAS 0.3.34.237.2 ..."``), or ``""``."""
    import numpy

    with contextlib.suppress(Exception):  # (show_config's layout is NumPy's, not ours)
        blas = numpy.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return str(blas.get("openblas configuration", ""))
    return ""


def blas_threads(config: str) -> int | None:
    """The threads of NumPy's BLAS, the OpenBLAS of configuration ``config`` (threadpoolctl)."""
    from threadpoolctl import threadpool_info

    version = config.split()[1] if config.startswith("OpenBLAS ") else None
    threads = [p["num_threads"] for p in threadpool_info() if p.get("version") == version]
    return threads[0] if threads else None


def coretype_warning(
    environ: Mapping[str, str] = os.environ, config: str | None = None
) -> str | None:
    """What to tell the user when ``OPENBLAS_CORETYPE`` forces kernels that crashed NumPy's
    OpenBLAS (``config``: its configuration string, NumPy's by default); None otherwise."""
    coretype = environ.get("OPENBLAS_CORETYPE", "").strip()
    if coretype.lower() not in CRASHING_CORETYPES:
        return None
    config = numpy_blas_config() if config is None else config
    if not config.startswith(CRASHING_OPENBLAS):
        return None
    return (
        f"OPENBLAS_CORETYPE={coretype} forces kernels with which NumPy's BLAS "
        f"({config.split('  ')[0]}) crashed with a segmentation fault in a plain matrix product "
        "on an AVX-512 machine: unset OPENBLAS_CORETYPE, or install numpy<=2.5.1 (OpenBLAS "
        "0.3.33). benchmarks/numpy_coretype.py tells whether this machine is affected."
    )


def _memory_gib() -> float | None:
    with contextlib.suppress(OSError, ValueError, IndexError), open("/proc/meminfo") as f:
        return int(f.readline().split()[1]) / 2**20
    return None


def _pictures() -> str:
    """The PyVista and VTK releases that draw the 3D pictures, or why there are none."""
    import importlib.metadata

    try:
        found = [f"{n} {importlib.metadata.version(n)}" for n in ("pyvista", "vtk")]
    except importlib.metadata.PackageNotFoundError as err:
        return f"off ({err.name} is not installed: pip install 'shellobstacle[pictures]')"
    return ", ".join(found) + " (drawn off screen in a process of their own)"


def report(installed: str) -> tuple[list[str], list[str]]:
    """``(lines, problems)``: what the doctor prints, and the problems found with their fix.

    ``installed``: how DOLFINx is installed (:func:`shellobstacle.compat.bootstrap`).
    """
    from mpi4py import MPI

    from shellobstacle import dependencies
    from shellobstacle.io.records import versions
    from shellobstacle.solvers.zone.mumps import selected_inverse_available

    v = versions()
    config = numpy_blas_config()
    threads = blas_threads(config) if config else "?"
    releases = dependencies.installed_versions()
    memory = _memory_gib()
    lines = [
        f"shellobstacle {v['shellobstacle']} on Python {v['python']} ({platform.platform()})",
        f"machine: {v['machine']}, {v['cpus']} CPUs"
        + (f", {memory:.1f} GiB" if memory is not None else ""),
        f"DOLFINx {v['dolfinx']} ({installed}), PETSc {v['petsc']}",
        f"dependencies: {dependencies.summary(releases)}",
        f"MPI: {MPI.Get_library_version().splitlines()[0].strip()}, {v['mpi_ranks']} rank(s)",
        f"NumPy's BLAS: {config.split('  ')[0] or 'not an OpenBLAS'}, {threads} thread(s)",
        f"3D pictures: {_pictures()}",
        "process tuning (docs/user-guide.md): "
        + (" ".join(f"{k}={val}" for k, val in v["environment"].items()) or "none set"),
    ]
    problems = dependencies.out_of_range(releases, dependencies.pinned_ranges())
    if (warning := coretype_warning()) is not None:
        problems.append(warning)
    if (reason := selected_inverse_available()) is not None:
        problems.append(
            f"MUMPS' selected inverse entries are out of reach ({reason}): the direct solver "
            "falls back to one factorization per κ (solver.contact_zone has no effect)"
        )
    if broken := jit_cache.broken_entries():
        problems.append(_broken_cache(broken))
    return lines, problems


def _broken_cache(broken: list[jit_cache.BrokenEntry]) -> str:
    """The problem of broken FFCx cache entries, with the fix."""
    shown = "; ".join(f"{e.source.name}: {e.why}" for e in broken[:3])
    more = f"; {len(broken) - 3} more" if len(broken) > 3 else ""
    return (
        f"{len(broken)} broken entr{'y' if len(broken) == 1 else 'ies'} in the FFCx cache "
        f"{broken[0].source.parent} ({shown}{more}): every compilation of those forms fails; "
        "shellobstacle doctor --repair removes the files at fault"
    )


def repair_cache() -> list[str]:
    """Repair the broken entries of the FFCx cache; what was removed, one line each."""
    removed = jit_cache.repair(jit_cache.broken_entries())
    return [f"repaired the FFCx cache: removed {path}" for path in removed]
