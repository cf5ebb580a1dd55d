"""The user guide's process tuning (docs/user-guide.md, "Process tuning"): its variables do what
it says, in fresh processes, and a run records the ones that are set."""

from __future__ import annotations

import ctypes.util
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

from mpi4py import MPI

import pytest

from shellobstacle.io.records import TIMING_VARIABLES, process_environment

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="fresh processes, serially")

GUIDE = Path(__file__).parents[2] / "docs" / "user-guide.md"


def recipe() -> str:
    """The guide's "Process tuning" section."""
    text = GUIDE.read_text()
    start = text.index("\n## Process tuning\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end != -1 else len(text)]


def assignments(span_start: str) -> dict[str, str]:
    """The ``NAME=value`` pairs of the section's first code span that starts with
    ``span_start``."""
    (span,) = re.findall(rf"`({re.escape(span_start)}[^`]*)`", recipe())[:1]
    return dict(re.findall(r"([A-Z_]+)=(\S+)", span))


def fresh(code: str, **environ: str) -> dict:
    """Run ``code`` (which prints a JSON line last) in a fresh interpreter with ``environ``
    and none of the tuning variables of this process."""
    env = {k: v for k, v in os.environ.items() if k not in TIMING_VARIABLES} | environ
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.splitlines()[-1])


# A 256 MiB block (above glibc's largest mmap threshold), touched and freed: how much of it the
# process still holds after the free.
HELD = """
import ctypes, ctypes.util, json, resource
libc = ctypes.CDLL(ctypes.util.find_library("c"))
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()
n = 256 << 20
before = rss()
p = libc.malloc(n)
ctypes.memset(p, 1, n)
libc.free(p)
print(json.dumps({"held_mib": (rss() - before) / 2**20}))
"""


def glibc() -> bool:
    name = ctypes.util.find_library("c")
    return name is not None and hasattr(ctypes.CDLL(name), "gnu_get_libc_version")


@pytest.mark.skipif(not glibc(), reason="the malloc variables are glibc's")
def test_the_malloc_variables_keep_a_freed_block_in_the_process() -> None:
    kept = assignments("MALLOC_MMAP_MAX_")
    assert set(kept) == {"MALLOC_MMAP_MAX_", "MALLOC_TRIM_THRESHOLD_"}
    assert fresh(HELD, **kept)["held_mib"] > 200  # freed, kept: the next block reuses it
    assert fresh(HELD)["held_mib"] < 50  # glibc's own mmap, unmapped at the free
    tunables = assignments("GLIBC_TUNABLES")
    assert fresh(HELD, **tunables)["held_mib"] > 200


def test_the_thread_variable_gives_numpy_s_blas_one_thread() -> None:
    threads = assignments("OPENBLAS_NUM_THREADS")
    assert threads == {"OPENBLAS_NUM_THREADS": "1"}
    code = """
    import json, numpy
    from threadpoolctl import threadpool_info
    print(json.dumps([p["num_threads"] for p in threadpool_info() if "numpy" in p["filepath"]]))
    """
    assert fresh(code, **threads) == [1]


def test_a_run_records_the_tuning_variables_that_are_set() -> None:
    environ = {"OPENBLAS_NUM_THREADS": "1", "MALLOC_MMAP_MAX_": "0", "HOME": "/home/x"}
    assert process_environment(environ) == {"OPENBLAS_NUM_THREADS": "1", "MALLOC_MMAP_MAX_": "0"}
    assert process_environment({}) == {}
