"""Dense matrix products in the OpenBLAS that PETSc and MUMPS run on: Gflop/s by size.

MUMPS' dense kernels (its fronts) run on the DOLFINx wheel's OpenBLAS. That library picks its
kernels for the CPU at load time, unless ``OPENBLAS_CORETYPE`` names them (the configuration
string in each line says which were used). One JSON line per size ``n``: C = A B with n × n
double matrices through ``cblas_dgemm``, about 2 Gflop per size, best of three.

``--gemmt`` times instead the update MUMPS makes in an LDLᵀ factorization, C := C − A Bᵀ on
the lower triangle of an n × n C with k columns (DGEMMT), by OpenBLAS' own DGEMMT, by the
blocked one of ``blocked_gemmt.py`` and, for comparison, by one DGEMM of the whole C (twice the
flops): milliseconds per call and Gflop/s counted on the triangle's n² k.

    OPENBLAS_CORETYPE=Haswell .venv/bin/python benchmarks/dgemm.py
    env -u OPENBLAS_CORETYPE .venv/bin/python benchmarks/dgemm.py
    .venv/bin/python benchmarks/dgemm.py --gemmt
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import sys
import time

import blocked_gemmt

if "--gemmt" in sys.argv:
    blocked_gemmt.load()  # before PETSc loads its OpenBLAS

# isort: split
from petsc4py import PETSc  # noqa: F401  (loads the wheel's OpenBLAS)

import numpy as np

ROW_MAJOR, NO_TRANS = 101, 111


def gemmt(config: str) -> None:
    """DGEMMT (OpenBLAS', blocked) against one whole DGEMM, at MUMPS-like shapes."""
    theirs = ctypes.CDLL(str(blocked_gemmt.openblas()), mode=os.RTLD_NOLOAD)
    ours = ctypes.CDLL(None).dgemmt_  # the process' first dgemmt_: the one MUMPS calls
    ref = ctypes.c_int
    rng = np.random.default_rng(0)
    for n, k in [(300, 48), (600, 64), (1500, 96), (3000, 128)]:
        A = np.asfortranarray(rng.random((n, k)))
        C = np.asfortranarray(rng.random((n, n)))
        ints = [ctypes.byref(ref(v)) for v in (n, k, n, n, n)]
        one, minus = ctypes.byref(ctypes.c_double(1.0)), ctypes.byref(ctypes.c_double(-1.0))
        a, c = A.ctypes.data_as(ctypes.c_void_p), C.ctypes.data_as(ctypes.c_void_p)
        L, N, T = (ctypes.byref(ctypes.c_char(x)) for x in (b"L", b"N", b"T"))
        hidden = (ctypes.c_size_t(1),) * 3
        args = (minus, a, ints[2], a, ints[3], one, c, ints[4])
        calls = {
            "openblas_gemmt": (theirs.dgemmt_, (L, N, T, ints[0], ints[1], *args, *hidden)),
            "blocked_gemmt": (ours, (L, N, T, ints[0], ints[1], *args, *hidden)),
            "whole_gemm": (theirs.dgemm_, (N, T, ints[0], ints[0], ints[1], *args, *hidden[:2])),
        }
        results, start = [], C.copy()  # each DGEMMT once on the same C: equal to round-off
        for name in ("openblas_gemmt", "blocked_gemmt"):
            C[:] = start
            calls[name][0](*calls[name][1])
            results.append(C.copy())
        if not np.allclose(results[0], results[1], rtol=1e-12, atol=1e-12 * n):
            raise RuntimeError("the blocked DGEMMT differs from OpenBLAS'")
        if not np.array_equal(np.triu(results[1], 1), np.triu(start, 1)):
            raise RuntimeError("the blocked DGEMMT wrote above the diagonal")
        repeats = max(1, int(2e9 / (n * n * k)))
        rec = {"benchmark": "gemmt", "n": n, "k": k, "petsc_blas": config}
        for name, (fn, fn_args) in calls.items():
            fn(*fn_args)
            best = np.inf
            for _ in range(3):
                t = time.perf_counter()
                for _ in range(repeats):
                    fn(*fn_args)
                best = min(best, (time.perf_counter() - t) / repeats)
            rec[f"{name}_ms"] = round(best * 1e3, 4)
            rec[f"{name}_gflops"] = round(n * n * k / best / 1e9, 2)
        print(json.dumps(rec), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--gemmt", action="store_true", help="time DGEMMT instead of DGEMM")
    args = ap.parse_args()
    blas = ctypes.CDLL("libopenblas.so.0", mode=getattr(os, "RTLD_NOLOAD", 0))
    blas.openblas_get_config.restype = ctypes.c_char_p
    config = blas.openblas_get_config().decode()
    if args.gemmt:
        gemmt(config)
        return
    rng = np.random.default_rng(0)
    for n in (64, 128, 256, 512, 1024, 2048):
        A, B = rng.random((n, n)), rng.random((n, n))
        C = np.zeros((n, n))
        args = (
            ROW_MAJOR, NO_TRANS, NO_TRANS, n, n, n, ctypes.c_double(1.0),
            A.ctypes.data_as(ctypes.c_void_p), n, B.ctypes.data_as(ctypes.c_void_p), n,
            ctypes.c_double(0.0), C.ctypes.data_as(ctypes.c_void_p), n,
        )  # fmt: skip
        blas.cblas_dgemm(*args)
        if not np.allclose(C, A @ B):
            raise RuntimeError("cblas_dgemm gave a wrong product")
        repeats = max(1, int(2e9 / (2 * n**3)))
        best = np.inf
        for _ in range(3):
            t = time.perf_counter()
            for _ in range(repeats):
                blas.cblas_dgemm(*args)
            best = min(best, time.perf_counter() - t)
        rec = {
            "benchmark": "dgemm", "n": n, "gflops": round(2 * n**3 * repeats / best / 1e9, 2),
            "openblas_coretype": os.environ.get("OPENBLAS_CORETYPE", "unset"),
            "petsc_blas": config,
        }  # fmt: skip
        print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
