"""What Koiter's model costs against the membrane model at equal dofs (docs/model.md §8).

The paper's problem (spherical cap, its load, ε = 10⁻³) with the continuation κ = h^0.5, h,
h^1.5 on a disk mesh, solved by Newton with the direct solver:

- membrane P1 on the mesh of size h (the paper's discretization),
- membrane P2 and Koiter P2 on the mesh of size 2h (about the same dofs), Koiter with both
  bending forms (hybrid, the default, and C⁰-IP).

The configurations are solved in turn, ``--repeat`` rounds after one untimed round that
compiles the forms (FFCx caches them on disk; both form times are recorded), all in this
process: a machine whose speed drifts slows every configuration of a round alike, so each
row's ratio to membrane P1 is taken round by round (the median of the rounds' ratios). A row
gives the median wall time of the continuation (forms compiled, solver set-up included), the
Newton steps, the dofs, the stiffness matrix's nonzeros, the solver's phases (seconds of the
last round: set-up with the stiffness assembly, factorizations, ...) and the process's peak
resident memory at the end. One JSON line per row.

    .venv/bin/python benchmarks/koiter_cost.py --h 0.01 --repeat 3
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import time

PAPER_LOAD = "Piecewise((-(2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.06), (0, True))"


def paper_shell_and_mesh(model: str, h: float) -> tuple:
    """The paper's shell (ε = 10⁻³) as ``model`` and a disk mesh of size ``h`` (ghosted for
    Koiter's facet terms)."""
    from shellobstacle.api import make_mesh
    from shellobstacle.geometry.surface import Surface
    from shellobstacle.mesh.domains import DomainSpec
    from shellobstacle.spec import Load, Material, Obstacle, Shell

    shell = Shell(
        Surface.spherical_cap(1.0, 0.85),
        Material(1e-3, 0.4, 0.012),
        Load(("0", "0", PAPER_LOAD)),
        Obstacle(),
        model,
    )
    mesh = make_mesh(DomainSpec(kind="disk", h=h, radius=0.5), ghosted=model == "koiter")
    return shell, mesh


CONFIGURATIONS = (
    ("membrane", 1, None),
    ("membrane", 2, None),
    ("koiter", 2, "c0ip"),
    ("koiter", 2, "hybrid"),
)


def solve(shell, mesh, degree: int, bending: str | None) -> dict:
    """One continuation: its seconds (forms compiled first, apart), steps and phases."""
    from mpi4py import MPI
    from petsc4py import PETSc

    from shellobstacle.mesh.measures import mesh_size
    from shellobstacle.models.problem import PenalizedProblem
    from shellobstacle.penalty.spec import PenaltySpec
    from shellobstacle.solvers.newton.continuation import continuation
    from shellobstacle.solvers.newton.solver import NewtonSolver
    from shellobstacle.spec import Discretization

    kappas = PenaltySpec(exponent=1.5).ladder(mesh_size(mesh))
    t = time.perf_counter()
    disc = Discretization(degree=degree, bending=bending or "hybrid")
    problem = PenalizedProblem(shell, mesh, disc)
    compiled = time.perf_counter()
    solver = NewtonSolver(problem)
    result = continuation(problem, solver, kappas)
    MPI.COMM_WORLD.barrier()
    done = time.perf_counter()
    K = problem.stiffness()
    return {
        "forms": compiled - t,
        "seconds": done - compiled,
        "steps": [s.newton.iterations for s in result],
        "dofs": problem.num_dofs,
        "phases": {k: round(v, 4) for k, v in solver.timings.items()},
        "nnz": int(K.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]),
    }


def rows(h: float, repeat: int) -> list[dict]:
    """The configurations solved in ``repeat`` timed rounds after an untimed one."""
    from mpi4py import MPI

    from shellobstacle.mesh.measures import mesh_size

    setups = []
    for model, degree, _ in CONFIGURATIONS:
        size = h if degree == 1 else 2 * h
        setups.append((*paper_shell_and_mesh(model, size), size))
    runs: list[list[dict]] = [[] for _ in CONFIGURATIONS]
    for _ in range(repeat + 1):
        for k, ((_, degree, bending), (shell, mesh, _)) in enumerate(
            zip(CONFIGURATIONS, setups, strict=True)
        ):
            runs[k].append(solve(shell, mesh, degree, bending))
    base = [r["seconds"] / r["dofs"] for r in runs[0][1:]]
    out = []
    for (model, degree, bending), (_, mesh, size), done in zip(
        CONFIGURATIONS, setups, runs, strict=True
    ):
        timed = done[1:]
        ratios = [r["seconds"] / r["dofs"] / b for r, b in zip(timed, base, strict=True)]
        out.append(
            {
                "model": model,
                "degree": degree,
                "bending": bending,
                "target_h": size,
                "h": mesh_size(mesh),
                "dofs": timed[-1]["dofs"],
                "newton_steps": timed[-1]["steps"],
                "seconds_median": statistics.median(r["seconds"] for r in timed),
                "seconds": [r["seconds"] for r in timed],
                "per_dof_vs_membrane_p1": [round(x, 3) for x in ratios],
                "per_dof_vs_membrane_p1_median": round(statistics.median(ratios), 3),
                "phases_last": timed[-1]["phases"],
                "stiffness_nnz": timed[-1]["nnz"],
                "forms_seconds_first": done[0]["forms"],
                "forms_seconds_cached": statistics.median(r["forms"] for r in timed),
                "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                "ranks": MPI.COMM_WORLD.size,
            }
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--h", type=float, default=0.01, help="mesh size of the P1 run")
    parser.add_argument("--repeat", type=int, default=3, help="timed rounds")
    args = parser.parse_args()
    from mpi4py import MPI

    out = rows(args.h, args.repeat)
    if MPI.COMM_WORLD.rank == 0:
        for row in out:
            print(json.dumps(row), flush=True)
        for row in out:
            print(
                f"{row['model']:>8} P{row['degree']} {row['bending'] or '':>6}  "
                f"{row['dofs']:>8} dofs  "
                f"{row['seconds_median']:7.2f} s  Newton {row['newton_steps']}  "
                f"{row['per_dof_vs_membrane_p1_median']:4.2f}× the membrane P1 time per dof "
                f"(rounds: {row['per_dof_vs_membrane_p1']})"
            )


if __name__ == "__main__":
    main()
