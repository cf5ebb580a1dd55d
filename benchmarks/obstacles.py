"""Curved obstacles against the plane and the exact VI (the numbers of docs/results/obstacles.md).

On the paper's cap (docs/model.md §7) over the square ``[−1/4, 1/4]²`` with ``n × n`` cells
(nested meshes as ``n`` doubles), and on a flat Koiter plate, it prints one table per study:

1. ``radius``: balls of radius R whose top touches the plane x3 = 0 at the origin, against the
   plane: ``max |ζ_R − ζ_plane|`` and its rate in R (predicted 1: the ball lies ``ρ²/(2R)``
   below the plane over a contact region of radius ρ);
2. ``kappa``: the vertex penalty at κ against active-set's exact VI on the ball of radius 2
   (predicted rate 1 in κ), with active-set's KKT residuals;
3. ``mesh``: the ball of radius 2 and the plane under refinement, κ = h^1.5 (Gauss penalty)
   and active-set: ``max |ζ_h − ζ_finest|`` at the coarse vertices and the observed rate;
4. ``face``: ζ_3's minimum for the middle surface and the lower face (predicted shift ε);
5. ``koiter``: a clamped flat Koiter plate (P2) pressed onto a ball of radius 1, penalty
   against active-set as κ → 0 (predicted rate 1), with the KKT residuals.

    .venv/bin/python benchmarks/obstacles.py [--only radius,kappa,mesh,face,koiter]
"""

from __future__ import annotations

import argparse
import math
import time

from mpi4py import MPI

import dolfinx
import numpy as np

from shellobstacle.api import solve_problem
from shellobstacle.geometry.surface import Surface
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post.contact import Postprocessor
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

PAPER_LOAD = "Piecewise((-(2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.06), (0, True))"
VERTEX = Discretization(penalty_quadrature="vertex")


def paper(obstacle: Obstacle) -> Shell:
    """The paper's shell (its cap, material and load) over ``obstacle``."""
    return Shell(
        Surface.spherical_cap(1.0, 0.85),
        Material(1e-3, 0.4, 0.012),
        Load(("0", "0", PAPER_LOAD)),
        obstacle,
    )


def ball(radius: float, top: float = 0.0, **kw) -> Obstacle:
    """The ball of ``radius`` whose top is at ``x3 = top`` above the origin."""
    return Obstacle(kind="sphere", center=(0.0, 0.0, top - radius), radius=radius, **kw)


def square(n: int, half: float = 0.25) -> dolfinx.mesh.Mesh:
    return dolfinx.mesh.create_rectangle(MPI.COMM_WORLD, [[-half, -half], [half, half]], [n, n])


PAPER_PENALTY = PenaltySpec(exponent=1.5)


def run(shell: Shell, n: int, penalty=PAPER_PENALTY, disc=None, method="newton"):
    """Solve; ``(ζ at the vertices (n+1)² × 3, result, contact, seconds)``."""
    t = time.perf_counter()
    r = solve_problem(shell, square(n), penalty, disc, method=method)
    seconds = time.perf_counter() - t
    assert r.converged, r.error
    V = r.problem.V
    x = V.tabulate_dof_coordinates()[:, :2]
    zeta = r.problem.zeta.x.array.reshape(-1, 3)
    order = np.lexsort((np.round(x[:, 0], 12), np.round(x[:, 1], 12)))
    return (x[order], zeta[order]), r, Postprocessor(r.problem, r.constraint).contact(), seconds


def at(points_values, coarse_points) -> np.ndarray:
    """The values at ``coarse_points`` (a subset of the points)."""
    points, values = points_values
    index = {(round(p[0], 10), round(p[1], 10)): i for i, p in enumerate(points)}
    return values[[index[(round(p[0], 10), round(p[1], 10))] for p in coarse_points]]


def exact_line(r, c) -> str:
    """active-set's passes, contact and KKT residuals (its last step's record)."""
    kkt = ", ".join(f"{k} {v:.1e}" for k, v in r.steps[-1].record.kkt.items())
    return (
        f"active-set: {r.extra['linearizations']} passes, contact area "
        f"{c['contact_area']:.6g}, max violation {c['max_violation']:.1e}, KKT {kkt}"
    )


def rate(a: float, b: float, ratio: float) -> float:
    return math.log(a / b) / math.log(ratio)


def radius_study(n: int) -> None:
    print(f"\n## radius: balls against the plane, n = {n}, κ = h^1.5 (Gauss penalty)")
    print("| R | max abs(ζ_R − ζ_plane) | rate in R | passes | Newton steps | seconds |")
    print("|---|---|---|---|---|---|")
    (_, plane), r0, _, s0 = run(paper(Obstacle()), n)
    print(f"| plane | — | — | — | {r0.iterations} | {s0:.1f} |")
    last = None
    for R in (10.0, 100.0, 1000.0):
        (_, z), r, _, s = run(paper(ball(R)), n)
        e = float(np.max(np.abs(z - plane)))
        shown = "—" if last is None else f"{rate(last, e, 10):.3f}"
        passes = r.extra["linearizations"]
        print(f"| {R:g} | {e:.3e} | {shown} | {passes} | {r.iterations} | {s:.1f} |")
        last = e


def kappa_study(n: int) -> None:
    print(f"\n## kappa: vertex penalty against active-set, ball R = 2, n = {n}")
    (_, exact), r, c, _ = run(paper(ball(2.0)), n, None, VERTEX, "active-set")
    print(exact_line(r, c))
    print("| κ | max abs(ζ_κ − ζ) | rate in κ | contact area | passes |")
    print("|---|---|---|---|---|")
    last = None
    for k in (1e-3, 1e-4, 1e-5, 1e-6):
        (_, z), r, c, _ = run(paper(ball(2.0)), n, PenaltySpec(kappa=k), VERTEX)
        e = float(np.max(np.abs(z - exact)))
        shown = "—" if last is None else f"{rate(last, e, 10):.3f}"
        passes = r.extra["linearizations"]
        print(f"| {k:g} | {e:.3e} | {shown} | {c['contact_area']:.6g} | {passes} |")
        last = e


def mesh_study(ns: list[int]) -> None:
    print(f"\n## mesh: nested squares n = {ns}, error at the coarse vertices against n = {ns[-1]}")
    print("| obstacle | method | n | max abs(ζ_h − ζ_finest) | rate in h | nodal contact area |")
    print("|---|---|---|---|---|---|")
    cases = [
        ("plane", Obstacle(), "newton", PenaltySpec(exponent=1.5), None),
        ("ball R = 2", ball(2.0), "newton", PenaltySpec(exponent=1.5), None),
        ("plane", Obstacle(), "active-set", None, VERTEX),
        ("ball R = 2", ball(2.0), "active-set", None, VERTEX),
    ]
    for name, obstacle, method, penalty, disc in cases:
        runs = [run(paper(obstacle), n, penalty, disc, method) for n in ns]
        finest = runs[-1][0]
        last = None
        for n, (pv, _, c, _) in zip(ns[:-1], runs[:-1], strict=True):
            e = float(np.max(np.abs(pv[1] - at(finest, pv[0]))))
            shown = "—" if last is None else f"{rate(last, e, 2):.2f}"
            area = c["contact_area_nodal"]  # at the vertices for both methods
            print(f"| {name} | {method} | {n} | {e:.3e} | {shown} | {area:.5g} |")
            last = e


def face_study(n: int) -> None:
    print(f"\n## face: the lower face θ − ε a_3 against the middle surface, n = {n}")
    print("| obstacle | middle: min ζ_3 | lower: min ζ_3 | shift | ε |")
    print("|---|---|---|---|---|")
    for name, make in (
        ("plane", lambda **kw: Obstacle(**kw)),
        ("ball R = 2", lambda **kw: ball(2.0, **kw)),
    ):
        mins = []
        for face in ("middle", "lower"):
            _, r, _, _ = run(paper(make(contact_face=face)), n)
            mins.append(Postprocessor(r.problem).zeta3_range()[0])
        print(f"| {name} | {mins[0]:.6f} | {mins[1]:.6f} | {mins[1] - mins[0]:.6f} | 0.001 |")


def koiter_study(n: int) -> None:
    print(f"\n## koiter: a flat clamped Koiter plate (P2) pressed onto a ball R = 1, n = {n}")
    plate = Shell(
        Surface.from_strings(["y1", "y2", "0.01"]),
        Material(1e-2, 0.4, 0.012),
        Load(("0", "0", "-2e-4*exp(-50*(y1**2 + y2**2))")),
        ball(1.0),
        "koiter",
    )
    p2 = Discretization(degree=2)
    _, r, c, _ = run(plate, n, None, p2, "active-set")
    exact = r.problem.zeta.x.array.copy()
    print(exact_line(r, c) + " (the constraint at every P2 node)")
    print("The Gauss penalty enforces g ≥ 0 at its Gauss points, active-set at the P2 nodes: the")
    print("penalty converges in κ to the Gauss-point VI; the last column is the two constraints'")
    print("difference.")
    print(
        "| κ | max abs(ζ_κ − ζ_10κ) | rate in κ | contact area | passes | max abs(ζ_κ − ζ_nodes) |"
    )
    print("|---|---|---|---|---|---|")
    last, previous = None, None
    for k in (1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        _, r, c, _ = run(plate, n, PenaltySpec(kappa=k), p2)
        z = r.problem.zeta.x.array.copy()
        e = math.nan if previous is None else float(np.max(np.abs(z - previous)))
        shown = "—" if last is None or math.isnan(last) else f"{rate(last, e, 10):.3f}"
        to_nodes = float(np.max(np.abs(z - exact)))
        print(
            f"| {k:g} | {e:.3e} | {shown} | {c['contact_area']:.6g} | "
            f"{r.extra['linearizations']} | {to_nodes:.3e} |"
        )
        last, previous = e, z


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="radius,kappa,mesh,face,koiter")
    parser.add_argument(
        "--n", type=int, default=32, help="cells per side (the single-mesh studies)"
    )
    parser.add_argument("--mesh", default="16,32,64,128", help="the mesh study's n")
    args = parser.parse_args()
    only = args.only.split(",")
    print(f"# curved obstacles ({time.strftime('%Y-%m-%d')}, {MPI.COMM_WORLD.size} rank(s))")
    if "radius" in only:
        radius_study(args.n)
    if "kappa" in only:
        kappa_study(args.n)
    if "mesh" in only:
        mesh_study([int(v) for v in args.mesh.split(",")])
    if "face" in only:
        face_study(args.n)
    if "koiter" in only:
        koiter_study(args.n // 2)


if __name__ == "__main__":
    main()
