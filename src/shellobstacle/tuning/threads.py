"""NumPy's BLAS: one thread per rank under MPI unless the user chose otherwise.

NumPy's wheels bring their own threaded OpenBLAS, which starts as many threads as there are
cores. Under ``mpiexec`` every rank does so, and the ranks' threads then compete for the same
cores (the contact zone's dense products are much slower on 2 ranks of a 2-core
machine). :func:`limit_blas_threads` sets ``OPENBLAS_NUM_THREADS=1`` before NumPy is loaded
when there is more than one rank and neither ``OMP_NUM_THREADS`` nor ``OPENBLAS_NUM_THREADS``
is set (hybrid MPI + threads keeps the user's choice). PETSc and MUMPS run on the DOLFINx
wheel's single-threaded OpenBLAS and are not affected.
"""

from __future__ import annotations

import os
import sys
from collections.abc import MutableMapping

__all__ = ["USER_VARIABLES", "limit_blas_threads"]

USER_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def limit_blas_threads(ranks: int, environ: MutableMapping[str, str] = os.environ) -> str:
    """One NumPy BLAS thread per rank when ``ranks > 1`` and the user set no thread count.

    Returns ``"one per rank"``, or ``"off (why)"``.
    """
    if ranks <= 1:
        return "off (one rank)"
    for name in USER_VARIABLES:
        if environ.get(name):
            return f"off ({name}={environ[name]} is the user's)"
    if "numpy" in sys.modules:
        return "off (NumPy was loaded before the tuning)"
    environ["OPENBLAS_NUM_THREADS"] = "1"
    return "one per rank"
