"""How much 2 ranks can speed batch 1 up: the parts that do not scale, and Amdahl's bound.

Runs batch 1 as ``benchmarks/batch1.py`` does (same arguments) with PETSc's event log on,
and adds to its JSON line the seconds of the parts that run on one rank or do not get
faster on several (largest rank):

- ``gmsh_s``: gmsh's coarse mesh (rank 0 alone; the rest of ``mesh_s`` is refinement);
- ``analysis_s``: MUMPS' analysis (ordering and symbolic factorization, sequential on the
  host rank) of each factorization the solver sets up, by matrix (``K_II``, the zone's
  ``S``, the coarse seed), and ``numeric_s`` their first numeric factorizations.

With a serial line and a 2-rank line::

    .venv/bin/python benchmarks/scaling_bound.py --target 0.0029 > serial.jsonl
    .venv/bin/mpiexec -n 2 .venv/bin/python benchmarks/scaling_bound.py --target 0.0029 > mpi2.jsonl
    .venv/bin/python benchmarks/scaling_bound.py --bound serial.jsonl mpi2.jsonl

the last prints one JSON line per pair: the measured speed-up and the bound, the speed-up 2
ranks would give if gmsh, the analyses and the zone's condensed steps (``condense``:
``S``'s numeric factorizations and solves, measured not to scale) kept their 2-rank seconds
and everything else took half its serial time.
"""

from __future__ import annotations

import json
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

_HERE = Path(__file__).parent
_ANALYSIS = ("MatCholFctrSym", "MatLUFactorSym")
_NUMERIC = ("MatCholFctrNum", "MatLUFactorNum")


def bound(serial: dict, parallel: dict) -> dict:
    """Measured speed-up and Amdahl's bound from a serial and a parallel line of this script."""

    def sequential(rec: dict) -> float:
        s_analysis = rec["analysis_s"].get("S", 0.0)  # inside condense already
        return (
            rec["gmsh_s"]
            + sum(rec["analysis_s"].values())
            - s_analysis
            + rec["timings"]["condense"]
        )

    t1, tp, p = serial["total_s"], parallel["total_s"], parallel["ranks"]
    seq1, seqp = sequential(serial), sequential(parallel)
    ideal = seqp + (t1 - seq1) / p
    return {
        "dofs": serial["dofs"],
        "ranks": p,
        "serial_s": t1,
        "parallel_s": tp,
        "speedup": t1 / tp,
        "sequential_serial_s": seq1,
        "sequential_parallel_s": seqp,
        "bound_parallel_s": ideal,
        "speedup_bound": t1 / ideal,
    }


def _lines(path: str) -> list[dict]:
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def _instrumented_batch1() -> None:
    """Batch 1 with the extra fields (see the module docstring)."""
    sys.path.insert(0, str(_HERE))
    import batch1  # (after the path; it imports the package first)
    import record
    from mpi4py import MPI
    from petsc4py import PETSc

    from shellobstacle import domains
    from shellobstacle.solvers import coarse_space, contact_zone

    PETSc.Log.begin()
    extra: dict = {"gmsh_s": 0.0, "analysis_s": defaultdict(float), "numeric_s": defaultdict(float)}

    def events(names: tuple[str, ...]) -> float:
        return sum(PETSc.Log.Event(name).getPerfInfo()["time"] for name in names)

    def attributed(name: Callable[[tuple], str], f: Callable) -> Callable:
        def g(*args: Any, **kwargs: Any) -> Any:
            a, n = events(_ANALYSIS), events(_NUMERIC)
            out = f(*args, **kwargs)
            extra["analysis_s"][name(args)] += events(_ANALYSIS) - a
            extra["numeric_s"][name(args)] += events(_NUMERIC) - n
            return out

        return g

    def matrix(args: tuple) -> str:
        what = args[1]
        return "K_II" if what == "K_II" else "S" if "Schur" in what else "whole"

    contact_zone._set_up = attributed(matrix, contact_zone._set_up)
    coarse_space.CoarseSpace.__init__ = attributed(
        lambda args: "coarse", coarse_space.CoarseSpace.__init__
    )
    gmsh_arrays = domains._gmsh_arrays

    def timed_gmsh(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        out = gmsh_arrays(*args, **kwargs)
        extra["gmsh_s"] += time.perf_counter() - t
        return out

    domains._gmsh_arrays = timed_gmsh
    emit = record.emit

    def emit_with_parts(rec: dict, comm: MPI.Comm) -> None:
        rec["gmsh_s"] = comm.allreduce(extra["gmsh_s"], op=MPI.MAX)
        for key in ("analysis_s", "numeric_s"):
            rec[key] = {k: comm.allreduce(v, op=MPI.MAX) for k, v in sorted(extra[key].items())}
        emit(rec, comm)

    batch1.emit = emit_with_parts
    batch1.main()


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "--bound":
        for serial, parallel in zip(_lines(sys.argv[2]), _lines(sys.argv[3]), strict=True):
            rec = bound(serial, parallel)
            print(
                json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in rec.items()})
            )
        return
    _instrumented_batch1()


if __name__ == "__main__":
    main()
