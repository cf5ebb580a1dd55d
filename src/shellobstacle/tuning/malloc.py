"""Freed memory kept in the process: glibc's malloc neither unmaps nor trims it.

A solve allocates and frees large blocks many times (submatrices, MUMPS' factors and working
space). glibc serves a block above its mmap threshold with its own ``mmap`` and unmaps it when
it is freed, and gives the top of its heap back when more than 128 kB are free there, so the
next large block is fresh memory whose pages are faulted in again. :func:`keep_freed_memory`
serves every block from the heap (``M_MMAP_MAX = 0``) and never trims it
(``M_TRIM_THRESHOLD = −1``): freed memory is reused without new page faults, and the process
keeps its peak memory until it ends. The same for any Python process, before it starts:
``GLIBC_TUNABLES=glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=18446744073709551615``.

Nothing is changed when the user tuned malloc (a ``glibc.malloc`` tunable in
``GLIBC_TUNABLES``, or one of :data:`USER_VARIABLES`) or off glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
from collections.abc import Callable, Mapping

__all__ = ["KEPT", "USER_VARIABLES", "keep_freed_memory", "user_tuned"]

KEPT = "keeps freed memory"
USER_VARIABLES = (
    "MALLOC_MMAP_MAX_",
    "MALLOC_MMAP_THRESHOLD_",
    "MALLOC_TRIM_THRESHOLD_",
    "MALLOC_TOP_PAD_",
)
M_TRIM_THRESHOLD, M_MMAP_MAX = -1, -4  # mallopt's parameters (glibc's malloc.h)


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
    """Whether ``environ`` tunes glibc's malloc itself."""
    if "glibc.malloc." in environ.get("GLIBC_TUNABLES", ""):
        return True
    return any(name in environ for name in USER_VARIABLES)


def keep_freed_memory(environ: Mapping[str, str] = os.environ) -> str:
    """Serve all blocks from glibc's heap and never trim it, unless the user tuned malloc.

    Returns :data:`KEPT`, or why malloc was left as it is.
    """
    if user_tuned(environ):
        return "as the user tuned it"
    mallopt = _mallopt()
    if mallopt is None:
        return "unchanged (not glibc)"
    if not (mallopt(M_MMAP_MAX, 0) and mallopt(M_TRIM_THRESHOLD, -1)):
        return "unchanged (mallopt refused)"
    return KEPT
