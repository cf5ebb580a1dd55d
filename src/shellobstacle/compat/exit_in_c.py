"""A signal that ends the process with a chosen exit status, also inside a long call into C.

Upstream: CPython runs a Python signal handler only between bytecodes ("a long-running
calculation implemented purely in C ... may run uninterrupted for an arbitrary amount of time",
the :mod:`signal` documentation), and petsc4py holds the GIL through a MUMPS factorization (a
Python thread does not run meanwhile), so no Python code can end the process then. A signal
whose default action would, ends it as a crash: PETSc's default signal handler catches
``SIGTERM``, prints an error dump and calls ``MPI_Abort``; with ``-no_signal_handler``,
MPICH's ``mpiexec`` reports the rank that died of it as "BAD TERMINATION"; on one process a
``SIGTERM`` during a factorization ends in a segmentation fault (docs/perf/interrupt.md). No
upstream release changes this: it applies to every version. :func:`exit_on` installs a handler
with the C library's ``signal``, which runs at once on the busy thread and exits with the given
status (without it, ``tests/cli/test_interrupt.py``'s stops inside gmsh and MUMPS end with a
signal's status instead of 130).
"""

from __future__ import annotations

import functools
import os
from typing import Any

__all__ = ["exit_on"]

#: the C-level handlers installed (kept alive while installed), by signal
_handlers: dict[int, Any] = {}


def exit_on(signum: int, status: int) -> bool:
    """Make ``signum`` end the process at once with ``status``, also inside a call into C;
    False (nothing changed) where the C library cannot be reached.

    The handler reaches ``os._exit`` through C functions only (no bytecode runs, where a
    pending Ctrl-C would raise ``KeyboardInterrupt`` instead; nothing it interrupted is
    resumed). Nothing is flushed: a caller whose files are written atomically loses none.
    """
    if signum in _handlers:
        return True
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        # the C function ``partial`` calls the C function ``os._exit``; the signal number that
        # the prototype leaves out is ignored
        handler = ctypes.CFUNCTYPE(None)(functools.partial(os._exit, status))
        libc.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]
        libc.signal.restype = ctypes.c_void_p
        failed = ctypes.c_void_p(-1).value  # SIG_ERR
        if libc.signal(signum, ctypes.cast(handler, ctypes.c_void_p)) == failed:
            return False
    except (OSError, AttributeError, ImportError):
        return False
    _handlers[signum] = handler
    return True
