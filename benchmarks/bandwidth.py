"""How much two cores of this machine gain over one on the iterative solver's kernels.

The iterative solver's time is sparse matrix products (the Chebyshev smoothers of GAMG's
V-cycle, the Jacobian's product) and vector updates, both limited by memory bandwidth, not by
arithmetic. This measures them without MPI: ``--processes`` independent processes at the same
time, each with its own P1 vector-Laplacian matrix (block size 2, the sparsity of the split's
ζ_α block) of ``--rows`` rows, run ``MatMult`` and ``VecWAXPY`` for ``--seconds`` and report
their rate. The aggregate rate of two processes over that of one bounds what 2 ranks can gain
on those kernels, whatever the communication costs. One JSON line per process and size.

    .venv/bin/python benchmarks/bandwidth.py --processes 1
    .venv/bin/python benchmarks/bandwidth.py --processes 2
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import time


def kernels(tag: int, rows: int, seconds: float, barrier) -> dict:
    """Products and triads on a ``rows``-row matrix for ``seconds`` each; their rates."""
    from mpi4py import MPI

    import dolfinx
    import dolfinx.fem.petsc
    import ufl

    n = max(2, round(math.sqrt(rows / 2.0)) - 1)  # 2 (n + 1)² rows
    mesh = dolfinx.mesh.create_unit_square(MPI.COMM_SELF, n, n)
    V = dolfinx.fem.functionspace(mesh, ("Lagrange", 1, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = dolfinx.fem.form(ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx + ufl.inner(u, v) * ufl.dx)
    A = dolfinx.fem.petsc.assemble_matrix(a)
    A.assemble()
    x, y = A.createVecs()
    w = x.duplicate()
    x.set(1.0)
    y.set(0.5)
    A.mult(x, y)  # first touch of every page outside the timing
    w.waxpy(2.0, x, y)
    info = A.getInfo()
    nnz = int(info["nz_used"])
    size = A.getSize()[0]
    rates = {}
    for name, op, nbytes in (
        ("matmult", lambda: A.mult(x, y), nnz * 12 + size * 16),
        ("waxpy", lambda: w.waxpy(2.0, x, y), size * 24),
    ):
        barrier.wait()
        count = 0
        t0 = time.perf_counter()
        while (elapsed := time.perf_counter() - t0) < seconds:
            op()
            count += 1
        rates[name] = {"calls": count, "s_per_call": elapsed / count,
                       "gb_per_s": nbytes * count / elapsed / 1e9}  # fmt: skip
    return {"process": tag, "rows": size, "nnz": nnz, **rates}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--processes", type=int, default=1, help="processes at the same time")
    ap.add_argument(
        "--rows", default="110000,220000,650000,1300000",
        help="matrix rows per process (comma-separated); 2 (n + 1)² rows are made",
    )  # fmt: skip
    ap.add_argument("--seconds", type=float, default=3.0, help="per kernel and size")
    args = ap.parse_args()
    context = multiprocessing.get_context("spawn")
    for rows in (int(r) for r in args.rows.split(",")):
        barrier = context.Manager().Barrier(args.processes)
        pool = context.Pool(args.processes)
        work = [(k, rows, args.seconds, barrier) for k in range(args.processes)]
        results = pool.starmap(kernels, work)
        pool.close()  # (not terminate: PETSc would report the signal)
        pool.join()
        for row in results:
            row["processes"] = args.processes
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
