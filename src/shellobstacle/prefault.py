"""Fresh heap pages faulted in ahead, on a spare core (``native/prefault.c``).

With freed memory kept (:mod:`shellobstacle.memory`) every block comes from glibc's heap,
which grows with ``brk``; the first write to each new page is a page fault in which the
kernel clears the page. On this project's virtual machine that costs 2.5–3.8 s per GiB of
memory the guest has not used before (0.2–0.3 s per GiB right after a first use), and in a
serial solve at 1.93 M dofs the kernel's page clearing was 18–19 % of all CPU samples, for
about 5 GiB faulted in (docs/performance.md, thirteenth session).

:func:`start_prefault` runs when :mod:`shellobstacle.compat` is imported. When a core is
left over (fewer ranks on the node than cores this process may run on), it starts a helper
thread that populates every new heap page with ``madvise(MADV_POPULATE_WRITE)``: the same
page faults, taken on the spare core instead of the computing thread, and the contents
untouched. Large blocks (MUMPS' factors, GiBs at 1.93 M dofs) move the heap's end at once and
are then written over seconds, so the helper runs ahead of the writes; growing the heap ahead
of its needs as well (``M_TOP_PAD`` 64 or 256 MiB) gained nothing more that runs could show
and cost that much resident memory even in small solves, so glibc's default (128 kB) stays.

Nothing is started (and :func:`prefault_policy` says why) with
``SHELLOBSTACLE_PREFAULT=off``, when freed memory is not kept (the heap would shrink and
grow again), when no core is spare (as for 2 ranks on 2 cores), off Linux or before Linux
5.14, or when the helper cannot be compiled or loaded. A forked child (``multiprocessing``'s
``fork``) has no helper: fork copies only the calling thread, and its policy says so.
"""

from __future__ import annotations

import ctypes
import os
import subprocess
from collections.abc import Mapping

from shellobstacle.cbuild import build, compiler

__all__ = [
    "OPT_OUT",
    "local_ranks",
    "prefault_policy",
    "prefaulted_gib",
    "refusal",
    "spare_core",
    "start_prefault",
    "usable_cores",
]

OPT_OUT = "SHELLOBSTACLE_PREFAULT"  # "off": no helper thread
# ranks of this job on this node, as MPICH's hydra, Open MPI and PMI launchers announce them
LOCAL_SIZE_VARIABLES = ("MPI_LOCALNRANKS", "OMPI_COMM_WORLD_LOCAL_SIZE", "PMI_LOCAL_SIZE")

_policy = "off (not started)"
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
    if environ.get(OPT_OUT, "").strip().lower() == "off":
        return f"{OPT_OUT}=off"
    if not malloc_kept:
        return "freed memory is not kept: SHELLOBSTACLE_MALLOC or a malloc setting"
    ranks = local_ranks(world_size, environ)
    if not spare_core(ranks, cores):
        return f"no spare core: {ranks} rank(s) on {cores} core(s)"
    return None


def start_prefault(
    world_size: int, malloc_kept: bool, environ: Mapping[str, str] = os.environ
) -> bool:
    """Start the helper thread unless the user, the malloc policy or the cores rule it out.

    ``world_size``: ranks of the job; ``malloc_kept``: whether
    :func:`shellobstacle.memory.keep_freed_memory` changed malloc. Returns whether it runs;
    :func:`prefault_policy` records the outcome.
    """
    global _policy, _library
    if _library is not None:
        return True
    reason = refusal(world_size, malloc_kept, environ, usable_cores())
    if reason is not None:
        _policy = f"off ({reason})"
        return False
    cc = compiler()
    if cc is None:
        _policy = "off (no C compiler)"
        return False
    try:
        library = ctypes.CDLL(str(build("prefault", cc, ["-lpthread"])))
    except (OSError, subprocess.SubprocessError) as err:
        _policy = f"off (the helper did not build or load: {err})"
        return False
    library.shellobstacle_prefault_bytes.restype = ctypes.c_long
    library.shellobstacle_prefault_error.restype = ctypes.c_long
    library.shellobstacle_prefault_running.restype = ctypes.c_int
    error = library.shellobstacle_prefault_start()
    if error != 0:
        _policy = f"off (the helper did not start: {os.strerror(error)})"
        return False
    _library = library
    _policy = "on"
    return True


def prefault_policy() -> str:
    """``"on"`` while the helper thread runs, else ``"off (why)"``."""
    if _library is not None and (error := _library.shellobstacle_prefault_error()) != 0:
        return f"off (stopped: {os.strerror(error)})"
    if _library is not None and not _library.shellobstacle_prefault_running():
        return "off (a forked child: the helper thread stayed in the parent)"
    return _policy


def prefaulted_gib() -> float:
    """GiB of heap the helper has populated so far in this process."""
    return 0.0 if _library is None else _library.shellobstacle_prefault_bytes() / 2**30
