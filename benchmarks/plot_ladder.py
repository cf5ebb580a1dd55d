"""Tables and a log–log plot of phase time against dofs from ``ladder.py`` JSON lines.

    .venv/bin/python benchmarks/plot_ladder.py docs/perf/ladder/ladder_1.93M_direct_serial.jsonl \
        docs/perf/ladder/ladder_1.93M_direct_mpi2.jsonl --png ladder.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

PHASES = (
    "mesh_s",
    "checks_s",
    "compile_s",
    "newton_setup_s",
    "newton_coarse_s",
    "newton_assemble_s",
    "newton_factorize_s",
    "newton_zone_s",
    "newton_condense_s",
    "newton_zone_newton_s",
    "newton_solve_s",
    "newton_line_search_s",
    "newton_predict_s",
    "continuation_s",
    "output_s",
)


def main() -> None:
    """Print Markdown tables (with fitted exponents) and write the figure."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("files", nargs="+")
    ap.add_argument("--png", required=True)
    args = ap.parse_args()
    fig, axes = plt.subplots(1, len(args.files), figsize=(6 * len(args.files), 4.5), squeeze=False)
    for ax, name in zip(axes[0], args.files, strict=True):
        ax.set_prop_cycle(color=plt.cm.tab20(np.linspace(0, 1, len(PHASES))))
        rows = [json.loads(line) for line in Path(name).read_text().splitlines() if line.strip()]
        dofs = np.array([r["dofs"] for r in rows], float)
        ranks = rows[0]["ranks"]
        print(f"\n### {Path(name).name}: {ranks} rank(s), {rows[0]['linear_solver']} solver\n")
        head = ["dofs", "h", "Newton", "LU", *(p[:-2] for p in PHASES), "peak RSS MB"]
        print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
        for r in rows:
            cells = [str(r["dofs"]), f"{r['h']:.4g}", "/".join(map(str, r["newton"]))]
            cells.append("/".join(map(str, r.get("factorizations", []))) or "–")
            cells += [f"{r.get(p, float('nan')):.2f}" for p in PHASES]
            cells.append(f"{r['peak_rss_mb_total']:.0f}")
            print("| " + " | ".join(cells) + " |")
        fits = []
        for p in PHASES:
            t = np.array([r.get(p, np.nan) for r in rows], float)
            keep = np.isfinite(t) & (t > 0)
            if keep.sum() >= 2:
                slope = np.polyfit(np.log(dofs[keep]), np.log(t[keep]), 1)[0]
                fits.append(f"{p[:-2]} {slope:.2f}")
                ax.loglog(dofs[keep], t[keep], "o-", label=f"{p[:-2]} (slope {slope:.2f})")
        print("\nfitted exponents of time ∝ dofs^k: " + ", ".join(fits))
        ax.set_xlabel("dofs")
        ax.set_ylabel("seconds")
        ax.set_title(f"{rows[0]['linear_solver']}, {ranks} rank(s): phase time vs dofs")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.png, dpi=150)


if __name__ == "__main__":
    main()
