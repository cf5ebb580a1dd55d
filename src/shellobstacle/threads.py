"""Threads of NumPy's BLAS under MPI: one per rank unless the user chose otherwise.

NumPy's wheels bring their own threaded OpenBLAS (``scipy-openblas``), which starts as many
threads as there are cores. Under ``mpiexec`` every rank does so, and the ranks' threads then
compete for the same cores: on this project's 2-core machine the steps on the contact zone
(dense products with ``T``) took three times as long on 2 ranks (docs/performance.md, sixth
session). PETSc and MUMPS run on the DOLFINx wheel's single-threaded OpenBLAS and are not
affected.

:func:`limit_blas_threads` runs when :mod:`shellobstacle.compat` is imported: on more than one
rank, and when none of ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` is set, NumPy's BLAS gets
one thread per rank. Setting either variable (hybrid MPI + threads) keeps the user's choice.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["blas_threads", "limit_blas_threads"]

USER_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")

# (set, get) entry points of the OpenBLAS builds NumPy ships or links
_SYMBOLS = (
    ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
    ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
    ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
    ("openblas_set_num_threads", "openblas_get_num_threads"),
)


@functools.cache
def _numpy_openblas() -> tuple[Callable[[int], Any], Callable[[], int]] | None:
    """The (set, get) thread functions of the OpenBLAS NumPy loaded, or None if not found
    (looked up once per process: NumPy's BLAS does not change once loaded)."""
    import numpy  # noqa: F401  (loads its BLAS)

    try:
        with open("/proc/self/maps") as maps:  # Linux; elsewhere nothing is changed
            paths = {line.split()[-1] for line in maps if "numpy" in line and "openblas" in line}
    except OSError:
        return None
    for path in sorted(paths):
        with contextlib.suppress(OSError):
            lib = ctypes.CDLL(path)
            for set_name, get_name in _SYMBOLS:
                if hasattr(lib, set_name) and hasattr(lib, get_name):
                    setter, getter = getattr(lib, set_name), getattr(lib, get_name)
                    setter.argtypes, setter.restype = [ctypes.c_int], None
                    getter.argtypes, getter.restype = [], ctypes.c_int
                    return setter, getter
    return None


def blas_threads() -> int | None:
    """Threads of NumPy's OpenBLAS (None if it is not an OpenBLAS this module can reach)."""
    functions = _numpy_openblas()
    return None if functions is None else int(functions[1]())


def limit_blas_threads(ranks: int, environ: Mapping[str, str] = os.environ) -> int | None:
    """One NumPy BLAS thread per rank when ``ranks > 1`` and the user set no thread count.

    Returns the thread count set, or None when nothing was changed (one rank, a user
    setting in ``environ``, or no reachable OpenBLAS).
    """
    if ranks <= 1 or any(environ.get(name) for name in USER_VARIABLES):
        return None
    functions = _numpy_openblas()
    if functions is None:
        return None
    functions[0](1)
    return 1
