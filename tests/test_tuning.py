"""The command line's opt-in process tuning (:mod:`shellobstacle.tuning`).

The test process itself is never tuned (the library does not tune): every check of a tuned
process runs in a fresh interpreter that applies the tuning first, as ``shellobstacle`` does.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from shellobstacle import tuning
from shellobstacle.tuning import gemmt, malloc, prefault, threads
from shellobstacle.tuning.build import compiler

GLIBC = malloc._mallopt() is not None
LINUX_5_14 = sys.platform == "linux" and tuple(map(int, os.uname().release.split(".")[:2])) >= (
    5,
    14,
)
GEMMT_EXPECTED = gemmt.openblas_path() is not None and compiler() is not None


def fresh(code: str, tuning_value: str | None = "on", ranks: int = 1, **environ: str) -> dict:
    """Run ``code`` in a fresh interpreter after ``tuning.apply(ranks)`` with
    ``SHELLOBSTACLE_TUNING=tuning_value`` (None: unset); ``code`` prints a JSON line last."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in (tuning.ENV, "GLIBC_TUNABLES", *threads.USER_VARIABLES)
        and not k.startswith("MALLOC_")
    }
    if tuning_value is not None:
        env[tuning.ENV] = tuning_value
    prelude = textwrap.dedent(f"""
        import json, os, sys
        from shellobstacle.compat import bootstrap
        bootstrap()
        from shellobstacle import tuning
        policies = tuning.apply({ranks})
    """)
    out = subprocess.run(
        [sys.executable, "-c", prelude + textwrap.dedent(code)],
        env=env | environ,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


# -- the switch --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("value", "knobs"),
    [
        (None, ()),
        ("", ()),
        ("on", tuning.KNOBS),
        (" ALL ", tuning.KNOBS),
        ("off", ()),
        ("none", ()),
        ("heap", ("heap",)),
        ("gemmt, threads", ("gemmt", "threads")),
    ],
)
def test_the_switch_names_the_knobs(value: str | None, knobs: tuple[str, ...]) -> None:
    environ = {} if value is None else {tuning.ENV: value}
    assert tuning.requested(environ) == knobs


def test_an_unknown_knob_is_refused_with_the_choices() -> None:
    with pytest.raises(ValueError, match=r"unknown tuning heep; use on, off or a comma"):
        tuning.requested({tuning.ENV: "heep,gemmt"})


def test_the_command_refuses_an_unknown_knob_with_exit_2() -> None:
    env = {**os.environ, tuning.ENV: "bogus"}
    out = subprocess.run(
        [sys.executable, "-m", "shellobstacle", "config-reference"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "SHELLOBSTACLE_TUNING='bogus': unknown tuning bogus" in lines[0]


def test_the_library_leaves_the_test_process_untuned() -> None:
    assert all(p.startswith("off (the library") for p in tuning.policies().values())
    assert gemmt.gemmt_calls() == {"blocked": 0, "forwarded": 0}
    assert prefault.prefaulted_gib() == 0.0


# -- heap: malloc keeps freed memory -----------------------------------------------------------
# A 256 MiB block (above glibc's largest mmap threshold), touched and freed: how much of it the
# process still holds after the free.
HELD = """
import ctypes, ctypes.util, resource
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
print(json.dumps({"heap": policies["heap"], "held_mib": (rss() - before) / 2**20}))
"""


@pytest.mark.skipif(not GLIBC, reason="not glibc: malloc is left alone")
def test_heap_tuning_keeps_a_freed_block_in_the_process() -> None:
    kept = fresh(HELD, "heap")
    assert kept["heap"].startswith(f"malloc {malloc.KEPT};")
    assert kept["held_mib"] > 200  # freed, not given back: the next block reuses its pages


@pytest.mark.skipif(not GLIBC, reason="not glibc: malloc is left alone")
@pytest.mark.parametrize(
    ("value", "environ"),
    [("off", {}), ("gemmt", {}), ("on", {"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=0"})],
    ids=["off", "other-knob", "user-tunable"],
)
def test_without_heap_tuning_malloc_is_glibcs(value: str, environ: dict[str, str]) -> None:
    system = fresh(HELD, value, **environ)
    assert not system["heap"].startswith(f"malloc {malloc.KEPT}")
    assert system["held_mib"] < 50  # glibc's own mmap for a block this large, unmapped at free


def test_user_malloc_settings_are_recognized() -> None:
    assert not malloc.user_tuned({})
    assert not malloc.user_tuned({"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX512F"})
    assert not malloc.user_tuned({"MALLOC_ARENA_MAX": "2"})
    assert malloc.user_tuned({"MALLOC_TRIM_THRESHOLD_": "0"})
    assert malloc.user_tuned({"GLIBC_TUNABLES": "glibc.malloc.mmap_max=0"})


# -- heap: the prefault helper -----------------------------------------------------------------
def test_local_ranks_from_the_launcher_else_the_world() -> None:
    assert prefault.local_ranks(4, {}) == 4
    assert prefault.local_ranks(4, {"MPI_LOCALNRANKS": "2"}) == 2
    assert prefault.local_ranks(8, {"OMPI_COMM_WORLD_LOCAL_SIZE": "3"}) == 3
    assert prefault.local_ranks(8, {"PMI_LOCAL_SIZE": "x", "MPI_LOCALNRANKS": ""}) == 8


@pytest.mark.parametrize(
    ("world", "kept", "environ", "cores", "reason"),
    [
        (1, True, {}, 2, None),
        (1, False, {}, 2, "freed memory is not kept"),
        (1, True, {}, 1, "no spare core: 1 rank(s) on 1 core(s)"),
        (2, True, {}, 2, "no spare core: 2 rank(s) on 2 core(s)"),
        (2, True, {}, 4, None),
        (8, True, {"MPI_LOCALNRANKS": "2"}, 4, None),
        (8, True, {"MPI_LOCALNRANKS": "4"}, 4, "no spare core: 4 rank(s) on 4 core(s)"),
    ],
)
def test_the_helper_runs_only_with_kept_memory_and_a_spare_core(
    world: int, kept: bool, environ: dict, cores: int, reason: str | None
) -> None:
    assert prefault.refusal(world, kept, environ, cores) == reason


PREFAULT_EXPECTED = GLIBC and LINUX_5_14 and compiler() is not None and prefault.usable_cores() > 1

# Blocks of many sizes allocated, filled with their own pattern and checked after the helper
# had time to populate the heap under them: the helper must not change a single value.
STRESS = """
import time
import numpy as np
from shellobstacle.tuning.prefault import prefaulted_gib
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
print(json.dumps({"heap": policies["heap"], "bad": bad, "gib": prefaulted_gib() - before}))
"""


@pytest.mark.skipif(not PREFAULT_EXPECTED, reason="the helper thread is not expected here")
def test_the_helper_populates_the_growing_heap_and_changes_no_value() -> None:
    got = fresh(STRESS, "heap")
    assert got["heap"] == f"malloc {malloc.KEPT}; prefault on"
    assert got["bad"] == 0
    assert got["gib"] > 0.5  # the heap grew by hundreds of MiB, populated by the helper


def test_tuning_off_starts_no_helper() -> None:
    code = """
    from shellobstacle.tuning.prefault import prefaulted_gib
    with open("/proc/self/maps") as maps:
        native = any("shellobstacle" in line for line in maps)
    print(json.dumps({"heap": policies["heap"], "gib": prefaulted_gib(), "native": native}))
    """
    got = fresh(code, "off")
    assert got == {"heap": "off (SHELLOBSTACLE_TUNING=off)", "gib": 0.0, "native": False}


UNTOUCHED = """
from shellobstacle.tuning.gemmt import gemmt_calls
from shellobstacle.tuning.prefault import prefaulted_gib
with open("/proc/self/maps") as maps:
    native = any("shellobstacle" in line for line in maps)
print(json.dumps({"policies": policies, "gib": prefaulted_gib(), "native": native,
                  "gemmt": gemmt_calls()}))
"""


def test_unset_is_off_a_fresh_process_applies_nothing() -> None:
    got = fresh(UNTOUCHED, None)
    assert got["policies"] == dict.fromkeys(tuning.KNOBS, "off (SHELLOBSTACLE_TUNING unset)")
    assert got["gib"] == 0.0 and not got["native"]
    assert got["gemmt"] == {"blocked": 0, "forwarded": 0}


@pytest.mark.skipif(not GLIBC, reason="not glibc: malloc is left alone")
def test_unset_leaves_malloc_glibcs() -> None:
    system = fresh(HELD, None)
    assert system["heap"] == "off (SHELLOBSTACLE_TUNING unset)"
    assert system["held_mib"] < 50


FORK = """
from shellobstacle.tuning.prefault import prefault_state
parent = prefault_state()
r, w = os.pipe()
pid = os.fork()
if pid == 0:
    os.write(w, (prefault_state() or "").encode())
    os._exit(0)
os.waitpid(pid, 0)
child = os.read(r, 1000).decode()
print(json.dumps({"parent": parent, "child": child, "after": prefault_state()}))
"""


@pytest.mark.skipif(not PREFAULT_EXPECTED, reason="the helper thread is not expected here")
def test_a_forked_child_says_it_has_no_helper() -> None:
    got = fresh(FORK, "heap")
    assert got["parent"] is None and got["after"] is None
    assert got["child"] == "a forked child: the helper thread stayed in the parent"


# -- gemmt: MUMPS' DGEMMT in DGEMM blocks ------------------------------------------------------
CASES = [
    (u, a, b, n, k, al, be)
    for u, a, b in itertools.product("LU", "NT", "NT")
    for n, k, al, be in [(700, 64, -1.0, 1.0), (300, 17, 0.5, 0.0), (257, 130, 2.0, -0.5)]
] + [
    ("L", "N", "T", 900, 0, 1.0, 0.5),
    ("U", "T", "N", 600, 33, 0.0, 2.0),
    ("L", "N", "T", 200, 40, -1.0, 1.0),
    ("l", "n", "t", 1000, 96, -1.0, 1.0),
]

# Every case through the process' dgemmt_ (the blocked one, as PETSc sees it) and through
# OpenBLAS' own; the arrays come back as lists for the checks in the test.
GEMMT_CASES = """
import ctypes
import numpy as np
from petsc4py import PETSc
from shellobstacle.tuning import gemmt
ours = ctypes.CDLL(None).dgemmt_
theirs = ctypes.CDLL(str(gemmt.openblas_path()), mode=os.RTLD_NOLOAD).dgemmt_
def call(fn, uplo, ta, tb, n, k, alpha, A, B, beta, C):
    ch = [ctypes.c_char(x.encode()) for x in (uplo, ta, tb)]
    i = [ctypes.c_int(v) for v in (n, k, A.shape[0], B.shape[0], C.shape[0])]
    fn(*(ctypes.byref(c) for c in ch), ctypes.byref(i[0]), ctypes.byref(i[1]),
       ctypes.byref(ctypes.c_double(alpha)), A.ctypes.data_as(ctypes.c_void_p),
       ctypes.byref(i[2]), B.ctypes.data_as(ctypes.c_void_p), ctypes.byref(i[3]),
       ctypes.byref(ctypes.c_double(beta)), C.ctypes.data_as(ctypes.c_void_p),
       ctypes.byref(i[4]), ctypes.c_size_t(1), ctypes.c_size_t(1), ctypes.c_size_t(1))
results = []
for uplo, ta, tb, n, k, alpha, beta in json.loads(sys.argv[1]):
    lower, a_plain, b_plain = uplo in "Ll", ta in "Nn", tb in "Nn"
    rng = np.random.default_rng(n + k)
    A = np.asfortranarray(rng.standard_normal((n + 3, k) if a_plain else (k + 2, n)))
    B = np.asfortranarray(rng.standard_normal((k + 1, n) if b_plain else (n + 5, k)))
    C0 = np.asfortranarray(rng.standard_normal((n + 4, n)))
    if beta == 0.0:
        C0[:n, :n][np.tril_indices(n) if lower else np.triu_indices(n)] = np.nan
    C1, C2 = C0.copy(order="F"), C0.copy(order="F")
    before = gemmt.gemmt_calls()
    call(ours, uplo, ta, tb, n, k, alpha, A, B, beta, C1)
    call(theirs, uplo, ta, tb, n, k, alpha, A, B, beta, C2)
    after = gemmt.gemmt_calls()
    tri = np.tril(np.ones((n, n), bool)) if lower else np.triu(np.ones((n, n), bool))
    opA = A[:n, :] if a_plain else A[:k, :n].T
    opB = B[:k, :] if b_plain else B[:n, :k].T
    old = np.where(np.isnan(C0[:n, :n]), 0.0, C0[:n, :n])
    exact = alpha * (opA[:, :k] @ opB[:, :n]) + beta * old
    scale = float(np.abs(exact).max())
    results.append({
        "blocked_calls": after["blocked"] - before["blocked"],
        "forwarded_calls": after["forwarded"] - before["forwarded"],
        "other_triangle_kept": bool(np.array_equal(C1[:n, :n][~tri], C0[:n, :n][~tri])),
        "rows_beyond_n_kept": bool(np.array_equal(C1[n:], C0[n:])),
        "finite": bool(np.isfinite(C1[:n, :n][tri]).all()),
        "error_vs_numpy": float(np.abs(C1[:n, :n][tri] - exact[tri]).max()) / scale,
        "error_vs_openblas": float(np.abs(C1[:n, :n][tri] - C2[:n, :n][tri]).max()) / scale,
        "identical_to_openblas": bool(np.array_equal(C1, C2)),
    })
print(json.dumps({"gemmt": policies["gemmt"], "results": results}))
"""


@pytest.mark.skipif(not GEMMT_EXPECTED, reason="no DOLFINx wheel OpenBLAS or no C compiler")
def test_the_blocked_gemmt_equals_openblas() -> None:
    """Our DGEMMT gives OpenBLAS' result on the triangle (to round-off; bitwise where it passes
    the call on) and leaves the other triangle bitwise as it was; β = 0 ignores C (NaN)."""
    env = {k: v for k, v in os.environ.items() if k != tuning.ENV} | {tuning.ENV: "gemmt"}
    prelude = (
        "import json, os, sys\nfrom shellobstacle.compat import bootstrap\nbootstrap()\n"
        "from shellobstacle import tuning\npolicies = tuning.apply(1)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", prelude + GEMMT_CASES, json.dumps(CASES)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["gemmt"] == "blocked"
    for (_, _, _, n, k, alpha, _), r in zip(CASES, got["results"], strict=True):
        blocked = n > 256 and k > 0 and alpha != 0.0
        assert r["blocked_calls"] == int(blocked) and r["forwarded_calls"] == int(not blocked)
        assert r["other_triangle_kept"] and r["rows_beyond_n_kept"] and r["finite"]
        assert r["error_vs_numpy"] <= 1e-13
        if blocked:
            assert r["error_vs_openblas"] <= 1e-13
        else:
            assert r["identical_to_openblas"]


LAPLACIAN_3D = """
from petsc4py import PETSc
from shellobstacle.tuning import gemmt
m = 18  # 7-point Laplacian on an m^3 grid: fronts of several hundred rows
n = m ** 3
A = PETSc.Mat().createAIJ([n, n], nnz=7, comm=PETSc.COMM_SELF)
for i in range(m):
    for j in range(m):
        for k in range(m):
            r = (i * m + j) * m + k
            A.setValue(r, r, 6.0)
            for di, dj, dk in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
                if i + di < m and j + dj < m and k + dk < m:
                    c = ((i + di) * m + j + dj) * m + k + dk
                    A.setValue(r, c, -1.0); A.setValue(c, r, -1.0)
A.assemble()
A.setOption(PETSc.Mat.Option.SPD, True)
b = A.createVecLeft(); b.array[:] = [((r * 7919) % 1000) / 1000.0 for r in range(n)]
x = A.createVecRight()
ksp = PETSc.KSP().create(PETSc.COMM_SELF); ksp.setOperators(A); ksp.setType("preonly")
ksp.getPC().setType("cholesky"); ksp.getPC().setFactorSolverType("mumps"); ksp.solve(b, x)
r = b.copy(); A.mult(x, r); r.axpy(-1.0, b)
print(json.dumps({"gemmt": policies["gemmt"], "calls": gemmt.gemmt_calls(),
                  "x": x.array.tolist(), "residual": r.norm() / b.norm()}))
"""


@pytest.mark.skipif(not GEMMT_EXPECTED, reason="no DOLFINx wheel OpenBLAS or no C compiler")
def test_mumps_cholesky_runs_on_the_blocked_gemmt() -> None:
    """MUMPS' LDLᵀ calls our DGEMMT (large fronts in blocks) and solves as with OpenBLAS' own
    (the knob off) to round-off."""
    blocked = fresh(LAPLACIAN_3D, "gemmt")
    plain = fresh(LAPLACIAN_3D, "off")
    assert blocked["gemmt"] == "blocked" and blocked["calls"]["blocked"] > 0
    assert plain["gemmt"].startswith("off") and plain["calls"] == {"blocked": 0, "forwarded": 0}
    assert blocked["residual"] < 1e-13 and plain["residual"] < 1e-13
    x, y = np.array(blocked["x"]), np.array(plain["x"])
    assert np.abs(x - y).max() <= 1e-12 * np.abs(y).max()


def test_gemmt_is_refused_once_petsc_is_loaded() -> None:
    if gemmt._library is not None:
        pytest.skip("the blocked DGEMMT is loaded in this process")
    from petsc4py import PETSc  # noqa: F401

    assert gemmt.block_gemmt({}) == "openblas (PETSc was loaded before the tuning)"


# -- threads: one NumPy BLAS thread per rank ---------------------------------------------------
THREADS = """
import numpy as np
from threadpoolctl import threadpool_info
counts = [p["num_threads"] for p in threadpool_info() if "numpy" in p["filepath"]]
print(json.dumps({"threads": policies["threads"], "counts": counts}))
"""


@pytest.mark.parametrize(
    ("ranks", "environ", "policy"),
    [
        (2, {}, "one per rank"),
        (1, {}, "off (one rank)"),
        (2, {"OMP_NUM_THREADS": "2"}, "off (OMP_NUM_THREADS=2 is the user's)"),
        (2, {"OPENBLAS_NUM_THREADS": "2"}, "off (OPENBLAS_NUM_THREADS=2 is the user's)"),
    ],
)
def test_numpy_gets_one_blas_thread_per_rank_unless_the_user_chose(
    ranks: int, environ: dict[str, str], policy: str
) -> None:
    got = fresh(THREADS, "threads", ranks=ranks, **environ)
    assert got["threads"] == policy
    assert got["counts"], "threadpoolctl found no BLAS of NumPy's"
    if policy == "one per rank":
        assert set(got["counts"]) == {1}
    elif environ:  # the user's count (OpenBLAS reads OMP_NUM_THREADS too)
        assert set(got["counts"]) == {2}


def test_threads_are_limited_after_numpy_was_loaded_too() -> None:
    """threadpoolctl limits the BLAS already loaded: no need to come before NumPy."""
    code = """
        import json, numpy
        from threadpoolctl import threadpool_info
        from shellobstacle.tuning import threads
        policy = threads.limit_blas_threads(2, {})
        counts = [p["num_threads"] for p in threadpool_info() if "numpy" in p["filepath"]]
        print(json.dumps({"policy": policy, "counts": counts}))
    """
    env = {k: v for k, v in os.environ.items() if k not in threads.USER_VARIABLES}
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["policy"] == "one per rank" and got["counts"] and set(got["counts"]) == {1}
