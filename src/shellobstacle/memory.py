"""Freed memory kept in the process: glibc's malloc neither unmaps nor trims it.

A solve allocates and frees large blocks many times (the stiffness' submatrices, MUMPS'
factors and working space, the zone's selected inverse entries). glibc serves a block above
its mmap threshold (128 kB, rising to at most 32 MB) with its own ``mmap`` and unmaps it when
it is freed, and gives the top of its heap back when more than 128 kB are free there, so the
next large block is fresh memory whose pages are faulted in again. On this project's machine
(a virtual machine) a first write of fresh memory costs 0.4–0.6 s per GiB, 13–20 times a
second write (``benchmarks/first_touch.py``; docs/performance.md, tenth session). A serial
solve at 1.93 M dofs faulted in 11.0 GiB for a 6.5 GB peak and took 60.1–60.9 s; with freed
memory kept, 4.1 GiB and 54.8–57.7 s.

:func:`keep_freed_memory` runs when :mod:`shellobstacle.compat` is imported: it tells glibc to
serve every block from its heap (``M_MMAP_MAX = 0``) and never to trim it
(``M_TRIM_THRESHOLD = -1``), so freed memory is reused without new page faults. The process
keeps its peak memory until it ends. Nothing is changed when the user tuned malloc (a
``glibc.malloc`` tunable in ``GLIBC_TUNABLES``, or one of :data:`USER_VARIABLES`), when
``SHELLOBSTACLE_MALLOC=system`` is set, or off glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
from collections.abc import Callable, Mapping

__all__ = ["OPT_OUT", "USER_VARIABLES", "keep_freed_memory", "malloc_policy", "user_tuned"]

OPT_OUT = "SHELLOBSTACLE_MALLOC"  # "system": leave glibc's malloc as it is
USER_VARIABLES = (
    "MALLOC_MMAP_MAX_",
    "MALLOC_MMAP_THRESHOLD_",
    "MALLOC_TRIM_THRESHOLD_",
    "MALLOC_TOP_PAD_",
)
M_TRIM_THRESHOLD, M_MMAP_MAX = -1, -4  # mallopt's parameters (glibc's malloc.h)

_policy = "system"


@functools.cache
def _mallopt() -> Callable[[int, int], int] | None:
    """glibc's ``mallopt``, or None off glibc."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
        libc.gnu_get_libc_version  # noqa: B018  (only glibc has it)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return mallopt


def user_tuned(environ: Mapping[str, str] = os.environ) -> bool:
    """Whether ``environ`` tunes glibc's malloc or opts out of :func:`keep_freed_memory`."""
    if environ.get(OPT_OUT, "").strip().lower() == "system":
        return True
    if "glibc.malloc." in environ.get("GLIBC_TUNABLES", ""):
        return True
    return any(name in environ for name in USER_VARIABLES)


def keep_freed_memory(environ: Mapping[str, str] = os.environ) -> bool:
    """Serve all blocks from glibc's heap and never trim it, unless the user chose otherwise.

    Returns whether malloc was changed.
    """
    global _policy
    if user_tuned(environ):
        return False
    mallopt = _mallopt()
    if mallopt is None:
        return False
    if not (mallopt(M_MMAP_MAX, 0) and mallopt(M_TRIM_THRESHOLD, -1)):
        return False
    _policy = "kept"
    return True


def malloc_policy() -> str:
    """``"kept"`` when :func:`keep_freed_memory` changed malloc in this process, else
    ``"system"``."""
    return _policy
