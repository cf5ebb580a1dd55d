"""The clamped circular plate at large deflection: nonlinear Koiter against Föppl–von Kármán.

Issue 57's plate (disk of radius 0.5, ε = 0.005 so thickness t = 0.01, λ = 1.5, μ = 1 so
ν = 0.3, dead load p³ = −s · 3.628e-6, clamped and immovable edge), P2 with the C⁰ interior
penalty, loaded by :class:`~shellobstacle.solvers.nonlinear.load_stepping.LoadStepping` along
one path through the load factors ``s`` at which the energy estimate of Timoshenko &
Woinowsky-Krieger §97, ``w₀/t + 0.488 (w₀/t)³ = s · 1.488``, gives ``w₀/t`` = 0.5, 1, 2, 3.
The reference is the axisymmetric Föppl–von Kármán plate solved by central differences
(``foppl_von_karman_collocation`` of tests/models/test_nonlinear_koiter.py). Prints a
Markdown table per mesh size: ``s``, TW-K's ``w₀/t``, Föppl–von Kármán's, the package's
centre deflection, their difference, and the load steps and Newton steps.

    .venv/bin/python benchmarks/nonlinear_plate.py --h 0.1,0.05
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mpi4py import MPI

import dolfinx
import numpy as np

from shellobstacle.geometry.surface import Surface
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.models.nonlinear_koiter import NonlinearKoiterProblem
from shellobstacle.post.sections import sample
from shellobstacle.solvers.nonlinear.load_stepping import LoadStepping
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from foppl_von_karman import foppl_von_karman_collocation

P, T = 3.628e-6, 0.01
JIT = {"cffi_extra_compile_args": ["-O0", "-g0"], "timeout": 600}
RATIOS = (0.5, 1.0, 2.0, 3.0)


def table(h: float) -> None:
    """Print the table at mesh size ``h``."""
    loads = [(w + 0.488 * w**3) / 1.488 for w in RATIOS]
    reference = foppl_von_karman_collocation([s * P for s in loads])
    shell = Shell(
        Surface.from_strings(["y1", "y2", "0"]),
        Material(0.005, 1.5, 1.0),
        Load(("0", "0", repr(-P))),
        Obstacle(),
        "koiter",
    )
    mesh = create_mesh(DomainSpec(kind="disk", h=h, radius=0.5), MPI.COMM_WORLD, ghosted=True)
    problem = NonlinearKoiterProblem(shell, mesh, Discretization(degree=2, bending="c0ip"),
                                     jit_options=JIT)  # fmt: skip
    stepping = LoadStepping(problem, first_step=0.5, max_step=8.0)
    tree = dolfinx.geometry.bb_tree(mesh, 2)
    dofs = problem.V.dofmap.index_map.size_global * 3
    print(f"\nh = {h} ({dofs} unknowns)\n")
    print("| s | TW-K w₀/t | FvK w₀/t | package w₀/t | difference | load steps | Newton steps |")
    print("|---|---|---|---|---|---|---|")
    start, done = time.perf_counter(), 1
    for ratio, s, w_ref in zip(RATIOS, loads, reference, strict=True):
        steps = stepping.solve(s).steps
        _, values = sample(problem.zeta, np.zeros((1, 3)), tree)
        w = -values[0, 2]
        new = steps[done:]
        done = len(steps)
        newton = sum(step.newton_iterations for step in new)
        print(f"| {s:.4f} | {ratio:.1f} | {w_ref / T:.5f} | {w / T:.5f} | "
              f"{100 * (w - w_ref) / w_ref:+.2f} % | {len(new)} | {newton} |")  # fmt: skip
    print(f"\n({time.perf_counter() - start:.1f} s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", default="0.1,0.05", help="mesh sizes, comma-separated")
    for h in parser.parse_args().h.split(","):
        table(float(h))


if __name__ == "__main__":
    main()
