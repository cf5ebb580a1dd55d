"""NumPy's BLAS: one thread per rank under MPI unless the user chose otherwise, and a warning
for forced kernels known to crash it.

NumPy's wheels bring their own threaded OpenBLAS (``scipy-openblas``), which starts as many
threads as there are cores. Under ``mpiexec`` every rank does so, and the ranks' threads then
compete for the same cores: on this project's 2-core machine the steps on the contact zone
(dense products with ``T``) took three times as long on 2 ranks (docs/performance.md, sixth
session). PETSc and MUMPS run on the DOLFINx wheel's single-threaded OpenBLAS and are not
affected.

:func:`limit_blas_threads` runs when :mod:`shellobstacle.compat` is imported: on more than one
rank, and when none of ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` is set, NumPy's BLAS gets
one thread per rank. Setting either variable (hybrid MPI + threads) keeps the user's choice.

:func:`coretype_warning` names a known crash: NumPy 2.5.2-2.5.5 ship OpenBLAS 0.3.34, which died
of a segmentation fault in a plain 500 x 500 matrix product when ``OPENBLAS_CORETYPE`` forced its
``Haswell`` or ``Zen`` kernels on this project's AVX-512 machine (NumPy 2.5.1's OpenBLAS 0.3.33
did not; ``benchmarks/numpy_coretype.py`` checks a machine, docs/performance.md, twelfth
session). Some machines set that variable for older OpenBLAS builds.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["blas_threads", "coretype_warning", "limit_blas_threads", "numpy_blas_config"]

USER_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")

# OPENBLAS_CORETYPE values (lower case) that crashed NumPy's OpenBLAS of the release below
CRASHING_CORETYPES = ("haswell", "zen")
CRASHING_OPENBLAS = "OpenBLAS 0.3.34"

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


def numpy_blas_config() -> str:
    """The configuration string of NumPy's BLAS (``"OpenBLAS 0.3.34.237.2 ..."``), or ``""``."""
    import numpy

    with contextlib.suppress(Exception):  # (show_config's layout is NumPy's, not ours)
        blas = numpy.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return str(blas.get("openblas configuration", ""))
    return ""


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
        "on an AVX-512 machine: unset OPENBLAS_CORETYPE for this run, or install numpy<=2.5.1 "
        "(OpenBLAS 0.3.33). benchmarks/numpy_coretype.py tells whether this machine is affected."
    )
