"""The geometry checks (docs/model.md §3) on one mesh: seconds, memory faulted in, peak RSS.

Meshes the paper's configuration at ``--target``, then times ``check_assumptions`` once (as a
solve does, right after the mesh). One JSON line with a record per rank: ``checks_s``, the
memory faulted in during the checks (GiB, minor faults times 4 kB) and the process's peak RSS
so far (GiB). ``--label`` tags the line (e.g. which code ran).

    .venv/bin/python benchmarks/checks_phase.py --target 0.0012
    .venv/bin/mpiexec -n 2 .venv/bin/python benchmarks/checks_phase.py --target 0.0012
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

from mpi4py import MPI

# isort: split

from shellobstacle.api import make_mesh
from shellobstacle.checks.assumptions import check_assumptions
from shellobstacle.config.loader import load_config

PAPER = Path(__file__).parents[1] / "src" / "shellobstacle" / "configs" / "paper.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--target", type=float, default=0.0012, help="gmsh target size")
    ap.add_argument("--label", default="", help="a tag copied into the record")
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    cfg = load_config(PAPER, [f"domain.h={args.target}"])
    mesh = make_mesh(cfg.domain)
    before = resource.getrusage(resource.RUSAGE_SELF)
    t = time.perf_counter()
    check_assumptions(cfg.shell, mesh)
    seconds = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_SELF)
    rank = {
        "checks_s": round(seconds, 3),
        "faulted_gib": round((after.ru_minflt - before.ru_minflt) * 4096 / 2**30, 3),
        "peak_rss_gib": round(after.ru_maxrss / 2**20, 3),
    }
    ranks = comm.gather(rank)
    if comm.rank == 0:
        rec = {"benchmark": "checks_phase", "target": args.target, "label": args.label,
               "ranks": comm.size, "per_rank": ranks}  # fmt: skip
        print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
