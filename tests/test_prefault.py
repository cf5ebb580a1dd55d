"""The heap's new pages faulted in by a helper thread on a spare core (shellobstacle.prefault)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from mpi4py import MPI

from shellobstacle import cbuild, prefault
from shellobstacle.memory import malloc_policy

CORES = prefault.usable_cores()
EXPECTED_ON = (
    sys.platform == "linux"
    and malloc_policy() == "kept"
    and os.environ.get(prefault.OPT_OUT, "").lower() != "off"
    and prefault.local_ranks(MPI.COMM_WORLD.size) < CORES
    and cbuild.compiler() is not None
    and tuple(map(int, os.uname().release.split(".")[:2])) >= (5, 14)
)


def test_local_ranks_from_the_launcher_else_the_world() -> None:
    assert prefault.local_ranks(4, {}) == 4
    assert prefault.local_ranks(4, {"MPI_LOCALNRANKS": "2"}) == 2
    assert prefault.local_ranks(8, {"OMPI_COMM_WORLD_LOCAL_SIZE": "3"}) == 3
    assert prefault.local_ranks(8, {"PMI_LOCAL_SIZE": "x", "MPI_LOCALNRANKS": ""}) == 8


@pytest.mark.parametrize(
    ("world", "kept", "environ", "cores", "reason"),
    [
        (1, True, {}, 2, None),
        (1, True, {prefault.OPT_OUT: "OFF"}, 2, "SHELLOBSTACLE_PREFAULT=off"),
        (1, False, {}, 2, "freed memory is not kept"),
        (1, True, {}, 1, "no spare core: 1 rank(s) on 1 core(s)"),
        (2, True, {}, 2, "no spare core: 2 rank(s) on 2 core(s)"),
        (2, True, {}, 4, None),
        (8, True, {"MPI_LOCALNRANKS": "2"}, 4, None),
        (8, True, {"MPI_LOCALNRANKS": "4"}, 4, "no spare core: 4 rank(s) on 4 core(s)"),
    ],
)
def test_the_helper_runs_only_with_kept_memory_a_spare_core_and_no_opt_out(
    world: int, kept: bool, environ: dict, cores: int, reason: str | None
) -> None:
    got = prefault.refusal(world, kept, environ, cores)
    assert got == reason if reason is None else got.startswith(reason)


def test_the_policy_is_recorded_as_expected_here() -> None:
    policy = prefault.prefault_policy()
    assert (policy == "on") == EXPECTED_ON, policy
    assert policy == "on" or policy.startswith("off (")


# Blocks of many sizes allocated, filled with their own pattern and checked after the helper
# had time to populate the heap under them: the helper must not change a single value.
STRESS = """
import json, time
import numpy as np
import shellobstacle.compat
from shellobstacle.prefault import prefault_policy, prefaulted_gib
rng = np.random.default_rng(7)
before, blocks, bad = prefaulted_gib(), [], 0
for i in range(40):
    n = int(rng.integers(1, 12 << 20))  # up to 96 MiB of float64: the heap grows
    a = np.empty(n)
    a[:] = i + np.arange(n) % 1021
    blocks.append((i, a))
    if i % 8 == 7:
        time.sleep(0.05)
        for k, b in blocks:
            bad += int(np.count_nonzero(b != k + np.arange(b.size) % 1021))
        blocks = blocks[4:]  # freed: kept in the heap, reused by later blocks
time.sleep(0.2)
print(json.dumps({"policy": prefault_policy(), "bad": bad, "gib": prefaulted_gib() - before}))
"""


def _run(code: str, **environ: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != prefault.OPT_OUT} | environ
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not EXPECTED_ON, reason="the helper thread is not expected here")
def test_the_helper_populates_the_growing_heap_and_changes_no_value() -> None:
    got = _run(STRESS)
    assert got["policy"] == "on"
    assert got["bad"] == 0
    assert got["gib"] > 0.5  # the heap grew by hundreds of MiB, populated by the helper


def test_opting_out_in_a_fresh_interpreter() -> None:
    code = (
        "import json, shellobstacle.compat\n"
        "from shellobstacle.prefault import prefault_policy, prefaulted_gib\n"
        "print(json.dumps({'policy': prefault_policy(), 'gib': prefaulted_gib()}))"
    )
    got = _run(code, **{prefault.OPT_OUT: "off"})
    assert got == {"policy": "off (SHELLOBSTACLE_PREFAULT=off)", "gib": 0.0}


FORK = """
import json, os
import shellobstacle.compat
from shellobstacle.prefault import prefault_policy
parent = prefault_policy()
r, w = os.pipe()
pid = os.fork()
if pid == 0:
    os.write(w, prefault_policy().encode())
    os._exit(0)
os.waitpid(pid, 0)
child = os.read(r, 1000).decode()
print(json.dumps({"parent": parent, "child": child, "after": prefault_policy()}))
"""


@pytest.mark.skipif(not EXPECTED_ON, reason="the helper thread is not expected here")
def test_a_forked_child_says_it_has_no_helper() -> None:
    got = _run(FORK)
    assert got["parent"] == got["after"] == "on"
    assert got["child"] == "off (a forked child: the helper thread stayed in the parent)"


@pytest.mark.mpi
def test_ranks_without_a_spare_core_run_no_helper() -> None:
    """Under mpiexec the policy follows the ranks on this node and the cores."""
    ranks = prefault.local_ranks(MPI.COMM_WORLD.size)
    policy = prefault.prefault_policy()
    if ranks >= CORES:
        assert policy == f"off (no spare core: {ranks} rank(s) on {CORES} core(s))"
    else:
        assert (policy == "on") == EXPECTED_ON
