"""Newton against the Brezis–Sibony iteration (38) on the paper's problem (docs/model.md §6–7).

The disk ``|y| < 0.5`` is meshed by gmsh for each target size; ``κ = h^q``. Prints one JSON
line per mesh (iterations, times, contraction bound against observed factor, distance
between the two solutions) and a last line with the fitted exponent of the Brezis–Sibony
iteration count, ``iterations ∝ h^slope``.

    .venv/bin/python benchmarks/brezis_sibony.py --sizes 0.1,0.07,0.05
    .venv/bin/python benchmarks/brezis_sibony.py --out results/solvers   # + CSV and PNG

``--sizes`` are gmsh targets; the largest cell diameter obtained is printed as ``h``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from mpi4py import MPI

from shellobstacle.config.loader import load_config
from shellobstacle.experiments.common import fit_rate
from shellobstacle.experiments.solvers import compare_solvers, write_solver_comparison
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.solvers.brezis_sibony.iteration import BrezisSibonyOptions

PAPER = Path(__file__).resolve().parents[1] / "src/shellobstacle/configs/paper.toml"


def main(argv: list[str] | None = None) -> int:
    """Run the comparison and print JSON lines on rank 0."""
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("--sizes", default="0.1,0.07,0.05", help="gmsh target sizes of the disk")
    ap.add_argument("--q", type=float, default=1.5, help="κ = h^q")
    ap.add_argument("--max-iterations", type=int, default=200_000)
    ap.add_argument("--mass", default="consistent", choices=("consistent", "lumped"))
    ap.add_argument("--out", type=Path, default=None, help="also write solvers.csv/.png here")
    args = ap.parse_args(argv)
    comm = MPI.COMM_WORLD

    def emit(record: dict) -> None:
        if comm.rank == 0:
            clean = {k: None if isinstance(v, float) and math.isnan(v) else v
                     for k, v in record.items()}  # fmt: skip
            print(json.dumps(clean), flush=True)

    cfg = load_config(PAPER)
    meshes = [DomainSpec(kind="disk", radius=0.5, h=float(s)) for s in args.sizes.split(",")]
    options = BrezisSibonyOptions(
        start="linearized", mass=args.mass, max_iterations=args.max_iterations
    )
    t0 = time.perf_counter()
    rows = compare_solvers(cfg, meshes, args.q, bs_options=options)
    for row in rows:
        emit({k: (round(v, 6) if isinstance(v, float) and k.endswith("seconds") else v)
              for k, v in row.items()})  # fmt: skip
    fit = [r for r in rows if r["bs_converged"] and r["bs_iterations"] > 0]
    summary = {
        "slope_iterations_vs_h": fit_rate([r["h"] for r in fit], [r["bs_iterations"] for r in fit]),
        "slope_lambda_max_vs_h": fit_rate([r["h"] for r in rows], [r["lambda_max"] for r in rows]),
        "slope_iterations_vs_condition": fit_rate(
            [r["lambda_max"] / r["lambda_min"] for r in fit], [r["bs_iterations"] for r in fit]
        ),
        "fitted_on": len(fit),
        "ranks": comm.size,
        "total_seconds": round(time.perf_counter() - t0, 2),
    }
    if args.out is not None:
        written = write_solver_comparison(rows, args.out)
        summary["csv"], summary["png"] = str(written["csv"]), str(written["png"])
    emit(summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
