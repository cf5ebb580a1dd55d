"""Shared tail of the benchmark scripts: peak memory and one JSON line on rank 0."""

from __future__ import annotations

import json
import resource
from typing import Any

from mpi4py import MPI


def emit(rec: dict[str, Any], comm: MPI.Comm) -> None:
    """Add the peak RSS (largest rank and sum over ranks) and print ``rec`` on rank 0.

    Floats keep 6 significant digits.
    """
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rec["peak_rss_mb_per_rank_max"] = comm.allreduce(rss, op=MPI.MAX)
    rec["peak_rss_mb_total"] = comm.allreduce(rss, op=MPI.SUM)
    if comm.rank == 0:
        values = {k: float(f"{v:.6g}") if isinstance(v, float) else v for k, v in rec.items()}
        print(json.dumps(values), flush=True)
