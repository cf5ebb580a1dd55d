"""NumPy's BLAS: one thread per rank under MPI unless the user chose otherwise.

NumPy's wheels bring their own threaded OpenBLAS, which uses as many threads as there are
cores. Under ``mpiexec`` every rank does so, and the ranks' threads then compete for the same
cores (the contact zone's dense products are much slower on 2 ranks of a 2-core
machine). :func:`limit_blas_threads` loads NumPy and limits the BLAS libraries then loaded
to one thread each (:func:`threadpoolctl.threadpool_limits`: OpenBLAS, MKL, BLIS alike) when
there is more than one rank and the user set none of :data:`USER_VARIABLES` (hybrid MPI +
threads keeps the user's choice). PETSc and MUMPS run on the DOLFINx wheel's single-threaded
OpenBLAS and are not affected.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

__all__ = ["USER_VARIABLES", "limit_blas_threads"]

#: a thread count the user chose: the tuning leaves the BLAS alone
USER_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def limit_blas_threads(ranks: int, environ: Mapping[str, str] = os.environ) -> str:
    """One NumPy BLAS thread per rank when ``ranks > 1`` and the user set no thread count.

    Returns ``"one per rank"``, or ``"off (why)"``.
    """
    if ranks <= 1:
        return "off (one rank)"
    for name in USER_VARIABLES:
        if environ.get(name):
            return f"off ({name}={environ[name]} is the user's)"
    import numpy  # noqa: F401  (loads the BLAS to limit)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
    return "one per rank"
