"""The blocked DGEMMT under MUMPS (shellobstacle.blas, native/gemmt.c)."""

from __future__ import annotations

import ctypes
import itertools
import os
import subprocess
import sys

import numpy as np
import pytest

from shellobstacle import blas, cbuild

EXPECTED = (
    os.environ.get(blas.OPT_OUT, "").lower() != "openblas"
    and blas.openblas_path() is not None
    and cbuild.compiler() is not None
)
pytestmark = pytest.mark.skipif(
    not EXPECTED, reason=f"blocked DGEMMT not expected here: {blas.gemmt_policy()}"
)


def test_the_blocked_gemmt_is_in_use() -> None:
    """With the DOLFINx wheel, a C compiler and no opt-out, importing the package set it up."""
    assert blas.gemmt_policy() == "blocked"


def _gemmt(fn, uplo, ta, tb, n, k, alpha, A, B, beta, C) -> None:
    """Call the Fortran DGEMMT ``fn`` on column-major NumPy arrays (C updated in place)."""
    ch = [ctypes.c_char(x.encode()) for x in (uplo, ta, tb)]
    i = [ctypes.c_int(v) for v in (n, k, A.shape[0], B.shape[0], C.shape[0])]
    fn(
        *(ctypes.byref(c) for c in ch), ctypes.byref(i[0]), ctypes.byref(i[1]),
        ctypes.byref(ctypes.c_double(alpha)), A.ctypes.data_as(ctypes.c_void_p),
        ctypes.byref(i[2]), B.ctypes.data_as(ctypes.c_void_p), ctypes.byref(i[3]),
        ctypes.byref(ctypes.c_double(beta)), C.ctypes.data_as(ctypes.c_void_p),
        ctypes.byref(i[4]), ctypes.c_size_t(1), ctypes.c_size_t(1), ctypes.c_size_t(1),
    )  # fmt: skip


def _functions() -> tuple:
    """Our dgemmt_ (as PETSc sees it: the global symbol) and OpenBLAS' own."""
    from petsc4py import PETSc  # noqa: F401  (loads the wheel's OpenBLAS)

    ours = ctypes.CDLL(None).dgemmt_  # the process' global lookup: the first dgemmt_
    theirs = ctypes.CDLL(str(blas.openblas_path()), mode=os.RTLD_NOLOAD).dgemmt_
    return ours, theirs


@pytest.mark.parametrize(
    ("uplo", "ta", "tb", "n", "k", "alpha", "beta"),
    [
        (u, a, b, n, k, al, be)
        for u, a, b in itertools.product("LU", "NT", "NT")
        for n, k, al, be in [(700, 64, -1.0, 1.0), (300, 17, 0.5, 0.0), (257, 130, 2.0, -0.5)]
    ]
    + [("L", "N", "T", 900, 0, 1.0, 0.5), ("U", "T", "N", 600, 33, 0.0, 2.0)]
    + [("L", "N", "T", 200, 40, -1.0, 1.0), ("l", "n", "t", 1000, 96, -1.0, 1.0)],
)
def test_blocked_gemmt_equals_openblas(uplo, ta, tb, n, k, alpha, beta) -> None:
    """Our DGEMMT gives OpenBLAS' result on the triangle (to round-off, bitwise where it passes
    the call on) and leaves the other triangle bitwise as it was; β = 0 ignores C (NaN)."""
    ours, theirs = _functions()
    lower, a_plain, b_plain = uplo in "Ll", ta in "Nn", tb in "Nn"
    rng = np.random.default_rng(n + k)
    A = np.asfortranarray(rng.standard_normal((n + 3, k) if a_plain else (k + 2, n)))
    B = np.asfortranarray(rng.standard_normal((k + 1, n) if b_plain else (n + 5, k)))
    C0 = np.asfortranarray(rng.standard_normal((n + 4, n)))
    if beta == 0.0:
        C0[:n, :n][np.tril_indices(n) if lower else np.triu_indices(n)] = np.nan
    C1, C2 = C0.copy(order="F"), C0.copy(order="F")
    before = blas.gemmt_calls()
    _gemmt(ours, uplo, ta, tb, n, k, alpha, A, B, beta, C1)
    _gemmt(theirs, uplo, ta, tb, n, k, alpha, A, B, beta, C2)
    after = blas.gemmt_calls()
    blocked = n > 256 and k > 0 and alpha != 0.0
    assert after["blocked"] - before["blocked"] == int(blocked)
    assert after["forwarded"] - before["forwarded"] == int(not blocked)
    tri = np.tril(np.ones((n, n), bool)) if lower else np.triu(np.ones((n, n), bool))
    assert np.array_equal(C1[:n, :n][~tri], C0[:n, :n][~tri])  # the other triangle
    assert np.array_equal(C1[n:], C0[n:])  # rows beyond n (ldc > n)
    assert np.isfinite(C1[:n, :n][tri]).all()
    # the triangle against NumPy and against OpenBLAS
    opA = A[:n, :] if a_plain else A[:k, :n].T
    opB = B[:k, :] if b_plain else B[:n, :k].T
    old = np.where(np.isnan(C0[:n, :n]), 0.0, C0[:n, :n])
    exact = alpha * (opA[:, :k] @ opB[:, :n]) + beta * old
    scale = np.abs(exact).max()
    assert np.abs(C1[:n, :n][tri] - exact[tri]).max() <= 1e-13 * scale
    if blocked:
        assert np.abs(C1[:n, :n][tri] - C2[:n, :n][tri]).max() <= 1e-13 * scale
    else:
        assert np.array_equal(C1, C2)


LAPLACIAN_3D = """
import json, sys
import shellobstacle.compat
from petsc4py import PETSc
from shellobstacle import blas, cbuild
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
print(json.dumps({"policy": blas.gemmt_policy(), "calls": blas.gemmt_calls(),
                  "x": x.array.tolist(), "residual": r.norm() / b.norm()}))
"""


def _factorize(env_extra: dict[str, str]) -> dict:
    import json

    env = {**os.environ, **env_extra}
    out = subprocess.run(
        [sys.executable, "-c", LAPLACIAN_3D], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.splitlines()[-1])


def test_mumps_cholesky_runs_on_the_blocked_gemmt() -> None:
    """In a fresh interpreter MUMPS' LDLᵀ calls our DGEMMT (large fronts in blocks) and solves
    as with OpenBLAS' own (SHELLOBSTACLE_GEMMT=openblas) to round-off."""
    blocked = _factorize({})
    plain = _factorize({blas.OPT_OUT: "openblas"})
    assert blocked["policy"] == "blocked" and blocked["calls"]["blocked"] > 0
    assert plain["policy"].startswith("openblas") and plain["calls"] == {
        "blocked": 0,
        "forwarded": 0,
    }
    assert blocked["residual"] < 1e-13 and plain["residual"] < 1e-13
    x, y = np.array(blocked["x"]), np.array(plain["x"])
    assert np.abs(x - y).max() <= 1e-12 * np.abs(y).max()
