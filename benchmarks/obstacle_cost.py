"""The cost of a curved obstacle against the plane at equal dofs (docs/perf/obstacles.md).

The paper's problem (``examples/paper.toml``) at ``domain.h`` (0.0029: about 329k dofs) on
its plane and pressed onto a large ball (``examples/cap_on_ball.toml`` with the radius given),
alternated in one process after one warm-up solve of each (which compiles the forms). Prints
one line per solve (time, Newton steps, linearization passes, the seconds of setting up
Newton's solver over all passes, dofs, contact area) and the median ratio ball/plane.

    .venv/bin/python benchmarks/obstacle_cost.py [--h 0.0029] [--radius 100] [--pairs 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from shellobstacle.api import solve
from shellobstacle.config.loader import load_config
from shellobstacle.post.contact import Postprocessor

EXAMPLES = Path(__file__).parents[1] / "examples"


def one(path: Path, overrides: list[str]) -> tuple[float, str]:
    t = time.perf_counter()
    r = solve(load_config(path, overrides))
    seconds = time.perf_counter() - t
    assert r.converged, r.error
    area = Postprocessor(r.problem, r.constraint).contact()["contact_area"]
    line = (
        f"{path.stem:12s} {seconds:7.2f} s  Newton steps {r.iterations:3d}  passes "
        f"{r.extra.get('linearizations', '-')}  set-up {r.timings.get('setup', 0.0):5.2f} s  "
        f"dofs {r.problem.num_dofs}  contact area {area:.6g}"
    )
    return seconds, line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", type=float, default=0.0029)
    parser.add_argument("--radius", type=float, default=100.0)
    parser.add_argument("--pairs", type=int, default=3)
    args = parser.parse_args()
    plane = (EXAMPLES / "paper.toml", [f"domain.h={args.h}"])
    R = args.radius
    ball = (
        EXAMPLES / "cap_on_ball.toml",
        [f"domain.h={args.h}", f"obstacle.radius={R}", f"obstacle.center=[0, 0, {-R}]"],
    )
    print(f"# obstacle cost, domain.h = {args.h}, ball radius {R:g} ({time.strftime('%F %T')})")
    for case in (plane, ball):
        print("warm-up:", one(*case)[1], flush=True)
    ratios = []
    for _ in range(args.pairs):
        t_plane, line = one(*plane)
        print(line, flush=True)
        t_ball, line = one(*ball)
        print(line, flush=True)
        ratios.append(t_ball / t_plane)
    print(f"ball/plane: median {statistics.median(ratios):.2f} (min {min(ratios):.2f}, "
          f"max {max(ratios):.2f}) over {len(ratios)} pairs")  # fmt: skip


if __name__ == "__main__":
    main()
