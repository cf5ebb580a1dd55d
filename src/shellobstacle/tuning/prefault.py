"""Fresh heap pages faulted in ahead, on a spare core (``native/prefault.c``).

With freed memory kept (:mod:`.malloc`) every block comes from glibc's heap, which grows with
``brk``; the first write to each new page is a page fault in which the kernel clears the page,
slow on virtual machines whose host reclaims free memory. When a core is left over (fewer
ranks on the node than cores this process may run on), :func:`start_prefault` starts a helper
thread that populates every new heap page with ``madvise(MADV_POPULATE_WRITE)``: the same
page faults, taken on the spare core instead of the computing thread, the contents untouched.

Nothing is started (and the policy says why) when freed memory is not kept (the heap would
shrink and grow again), when no core is spare (as for 2 ranks on 2 cores), off Linux or before
Linux 5.14, or when the helper cannot be compiled or loaded. A forked child has no helper:
fork copies only the calling thread.
"""

from __future__ import annotations

import ctypes
import os
import subprocess
from collections.abc import Mapping

from shellobstacle.tuning.build import build, compiler

__all__ = [
    "local_ranks",
    "prefault_state",
    "prefaulted_gib",
    "refusal",
    "spare_core",
    "start_prefault",
    "usable_cores",
]

# ranks of this job on this node, as MPICH's hydra, Open MPI and PMI launchers announce them
LOCAL_SIZE_VARIABLES = ("MPI_LOCALNRANKS", "OMPI_COMM_WORLD_LOCAL_SIZE", "PMI_LOCAL_SIZE")

_library: ctypes.CDLL | None = None


def local_ranks(world_size: int, environ: Mapping[str, str] = os.environ) -> int:
    """Ranks on this node: the launcher's count if it gives one, else all ``world_size``."""
    for name in LOCAL_SIZE_VARIABLES:
        value = environ.get(name, "").strip()
        if value.isdigit() and int(value) > 0:
            return int(value)
    return world_size


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def spare_core(ranks_on_node: int, cores: int) -> bool:
    """Whether a core is left over for the helper thread."""
    return ranks_on_node < cores


def refusal(
    world_size: int, malloc_kept: bool, environ: Mapping[str, str], cores: int
) -> str | None:
    """Why the helper thread must not run (None: it may), before anything is built."""
    if not malloc_kept:
        return "freed memory is not kept"
    ranks = local_ranks(world_size, environ)
    if not spare_core(ranks, cores):
        return f"no spare core: {ranks} rank(s) on {cores} core(s)"
    return None


def start_prefault(
    world_size: int, malloc_kept: bool, environ: Mapping[str, str] = os.environ
) -> str:
    """Start the helper thread unless the malloc policy or the cores rule it out.

    ``world_size``: ranks of the job; ``malloc_kept``: whether freed memory is kept. Returns
    ``"on"``, or ``"off (why)"``.
    """
    global _library
    if _library is not None:
        return "on"
    reason = refusal(world_size, malloc_kept, environ, usable_cores())
    if reason is not None:
        return f"off ({reason})"
    cc = compiler()
    if cc is None:
        return "off (no C compiler)"
    try:
        library = ctypes.CDLL(str(build("prefault", cc, ["-lpthread"])))
    except (OSError, subprocess.SubprocessError) as err:
        return f"off (the helper did not build or load: {err})"
    library.shellobstacle_prefault_bytes.restype = ctypes.c_long
    library.shellobstacle_prefault_error.restype = ctypes.c_long
    library.shellobstacle_prefault_running.restype = ctypes.c_int
    error = library.shellobstacle_prefault_start()
    if error != 0:
        return f"off (the helper did not start: {os.strerror(error)})"
    _library = library
    return "on"


def prefault_state() -> str | None:
    """None while the helper runs (or was never started), else why it no longer does."""
    if _library is not None and (error := _library.shellobstacle_prefault_error()) != 0:
        return f"stopped: {os.strerror(error)}"
    if _library is not None and not _library.shellobstacle_prefault_running():
        return "a forked child: the helper thread stayed in the parent"
    return None


def prefaulted_gib() -> float:
    """GiB of heap the helper has populated so far in this process."""
    return 0.0 if _library is None else _library.shellobstacle_prefault_bytes() / 2**30
