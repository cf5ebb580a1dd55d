"""Freed memory kept in the process (shellobstacle.memory)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from shellobstacle.memory import OPT_OUT, _mallopt, user_tuned

pytestmark = pytest.mark.skipif(_mallopt() is None, reason="not glibc: malloc is left alone")

# A 256 MiB block (above glibc's largest mmap threshold), touched and freed: how much of it
# the process still holds after the free.
PROBE = """
import ctypes, ctypes.util, json, resource
import shellobstacle.compat
from shellobstacle.memory import malloc_policy
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
print(json.dumps({"policy": malloc_policy(),
                  "held_mib": (rss() - before) / 2**20}))
"""


def _probe(**environ: str) -> dict:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in (OPT_OUT, "GLIBC_TUNABLES") and not k.startswith("MALLOC_")
    }
    out = subprocess.run(
        [sys.executable, "-c", PROBE], env=env | environ, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_freed_block_stays_in_the_process() -> None:
    kept = _probe()
    assert kept["policy"] == "kept"
    assert kept["held_mib"] > 200  # freed, not given back: the next block reuses its pages


@pytest.mark.parametrize(
    "environ",
    [{OPT_OUT: "system"}, {"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=0"}],
    ids=["opt-out", "user-tunable"],
)
def test_a_user_choice_leaves_malloc_alone(environ: dict[str, str]) -> None:
    system = _probe(**environ)
    assert system["policy"] == "system"
    assert system["held_mib"] < 50  # glibc's own mmap for a block this large, unmapped at free


def test_user_settings_are_recognized() -> None:
    assert not user_tuned({})
    assert not user_tuned({"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX512F", OPT_OUT: "kept"})
    assert user_tuned({OPT_OUT: "System"})
    assert user_tuned({"MALLOC_ARENA_MAX": "2"}) is False
    assert user_tuned({"MALLOC_TRIM_THRESHOLD_": "0"})
    assert user_tuned({"GLIBC_TUNABLES": "glibc.malloc.mmap_max=0"})
