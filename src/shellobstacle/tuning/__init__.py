"""Opt-in process tuning for long runs of the command line; never applied on import.

The ``shellobstacle`` command applies it (:func:`apply`, before MPI, PETSc and NumPy are
loaded); the library does not, so a script that imports :mod:`shellobstacle` keeps its
process as it is. ``SHELLOBSTACLE_TUNING`` chooses: unset or ``off`` (the default: nothing is
applied), ``on`` (all knobs), or a comma-separated list of the knobs below.
``shellobstacle doctor`` says what is active.

* ``heap`` (:mod:`.malloc`, :mod:`.prefault`): glibc's malloc keeps freed memory in the
  process, and on a spare core a helper thread faults the heap's new pages in ahead of the
  solver. On virtual machines whose host takes free memory back, touching fresh memory is
  slow, and a large solve spends much of its time faulting pages in (measured in
  docs/performance.md).
* ``gemmt`` (:mod:`.gemmt`): MUMPS' Cholesky factorizations call DGEMMT, which the DOLFINx
  wheel's OpenBLAS computes column by column; a DGEMMT made of DGEMM blocks replaces it.
* ``threads`` (:mod:`.threads`): under ``mpiexec``, NumPy's BLAS gets one thread per rank
  (threadpoolctl) unless ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` or
  ``MKL_NUM_THREADS`` is set.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

from shellobstacle.tuning import gemmt, malloc, prefault, threads

__all__ = ["ENV", "KNOBS", "apply", "policies", "requested", "setting"]

ENV = "SHELLOBSTACLE_TUNING"
KNOBS = ("heap", "gemmt", "threads")

_applied: dict[str, str] = {}


def requested(environ: Mapping[str, str] = os.environ) -> tuple[str, ...]:
    """The knobs ``SHELLOBSTACLE_TUNING`` asks for (none when it is unset or empty).

    Raises:
        ValueError: an unknown value, naming the choices.
    """
    value = environ.get(ENV, "").strip().lower()
    if value in ("", "off", "none"):
        return ()
    if value in ("on", "all"):
        return KNOBS
    names = tuple(v.strip() for v in value.split(",") if v.strip())
    unknown = [n for n in names if n not in KNOBS]
    if unknown:
        raise ValueError(
            f"{ENV}={environ[ENV]!r}: unknown tuning {', '.join(unknown)}; use on, off or a "
            f"comma-separated list of {', '.join(KNOBS)}"
        )
    return names


def apply(world_size: int, environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """Tune this process as ``SHELLOBSTACLE_TUNING`` asks; returns each knob's policy.

    Call it once, before PETSc and NumPy are loaded (the command line's entry point does).
    ``world_size``: the ranks of the MPI job.
    """
    wanted = requested(environ)
    for name in KNOBS:
        _applied[name] = f"off ({setting(environ)})"
    if "gemmt" in wanted:
        _applied["gemmt"] = gemmt.block_gemmt(environ)
    if "heap" in wanted:
        kept = malloc.keep_freed_memory(environ)
        helper = prefault.start_prefault(world_size, kept == malloc.KEPT, environ)
        _applied["heap"] = f"malloc {kept}; prefault {helper}"
    if "threads" in wanted:  # loads NumPy: last
        _applied["threads"] = threads.limit_blas_threads(world_size, environ)
    return policies()


def setting(environ: Mapping[str, str] = os.environ) -> str:
    """How ``SHELLOBSTACLE_TUNING`` is set, for reports: ``NAME=value`` or ``NAME unset``."""
    return f"{ENV}={environ[ENV]}" if ENV in environ else f"{ENV} unset"


def policies() -> dict[str, str]:
    """Each knob's state in this process: what it does, or ``off (why)``."""
    if not _applied:
        return dict.fromkeys(KNOBS, "off (the library leaves the process as it is)")
    return dict(_applied)
