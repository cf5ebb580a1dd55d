"""What Koiter's model costs against the membrane model at equal dofs (MODEL.md §8).

The paper's problem (spherical cap, its load, ε = 10⁻³) with the continuation κ = h^0.5, h,
h^1.5 on a disk mesh, solved by Newton with the direct solver:

- membrane P1 on the mesh of size h (the paper's discretization),
- membrane P2 and Koiter P2 on the mesh of size 2h (about the same dofs), Koiter with both
  bending forms (hybrid, the default, and C⁰-IP).

Each configuration is solved ``--repeat`` times in this process after one untimed solve that
compiles the forms (FFCx caches them on disk; both form times are recorded). The table gives
the median wall time of the continuation (forms compiled, solver set-up included), the Newton
steps, the dofs, the stiffness matrix's nonzeros, the solver's phases (seconds of the last
run: set-up with the stiffness assembly, factorizations, ...) and the process's peak resident
memory so far. One JSON line per row.

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
    from shellobstacle.domains import DomainSpec
    from shellobstacle.model import Load, Material, Obstacle, Shell
    from shellobstacle.pipeline import make_mesh
    from shellobstacle.surface import Surface

    shell = Shell(
        Surface.spherical_cap(1.0, 0.85),
        Material(1e-3, 0.4, 0.012),
        Load(("0", "0", PAPER_LOAD)),
        Obstacle(),
        model,
    )
    mesh = make_mesh(DomainSpec(kind="disk", h=h, radius=0.5), ghosted=model == "koiter")
    return shell, mesh


def run(model: str, degree: int, h: float, repeat: int, bending: str = "c0ip") -> dict:
    from mpi4py import MPI
    from petsc4py import PETSc

    from shellobstacle.measures import mesh_size
    from shellobstacle.model import Discretization, PenaltySpec
    from shellobstacle.problem import PenalizedProblem
    from shellobstacle.solvers.continuation import continuation
    from shellobstacle.solvers.newton import NewtonSolver

    shell, mesh = paper_shell_and_mesh(model, h)
    kappas = PenaltySpec(exponent=1.5).ladder(mesh_size(mesh))
    times, steps, dofs, forms = [], [], 0, []
    for k in range(repeat + 1):
        t = time.perf_counter()
        problem = PenalizedProblem(shell, mesh, Discretization(degree=degree, bending=bending))
        compiled = time.perf_counter()
        forms.append(compiled - t)
        solver = NewtonSolver(problem)
        result = continuation(problem, solver, kappas)
        MPI.COMM_WORLD.barrier()
        if k:  # the first run compiles (or loads) the forms
            times.append(time.perf_counter() - compiled)
        steps = [s.newton.iterations for s in result]
        dofs = problem.num_dofs
        phases = {k: round(v, 4) for k, v in solver.timings.items()}
        nnz = int(problem.stiffness().getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"])
        del problem, solver
    return {
        "model": model,
        "degree": degree,
        "bending": bending if model == "koiter" else None,
        "target_h": h,
        "h": mesh_size(mesh),
        "dofs": dofs,
        "newton_steps": steps,
        "seconds_median": statistics.median(times),
        "seconds": times,
        "phases_last": phases,
        "stiffness_nnz": nnz,
        "forms_seconds_first": forms[0],
        "forms_seconds_cached": statistics.median(forms[1:]),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "ranks": MPI.COMM_WORLD.size,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--h", type=float, default=0.01, help="mesh size of the P1 run")
    parser.add_argument("--repeat", type=int, default=3, help="timed solves per configuration")
    args = parser.parse_args()
    from mpi4py import MPI

    rows = [
        run("membrane", 1, args.h, args.repeat),
        run("membrane", 2, 2 * args.h, args.repeat),
        run("koiter", 2, 2 * args.h, args.repeat, "c0ip"),
        run("koiter", 2, 2 * args.h, args.repeat, "hybrid"),
    ]
    if MPI.COMM_WORLD.rank == 0:
        for row in rows:
            print(json.dumps(row), flush=True)
        base = rows[0]["seconds_median"] / rows[0]["dofs"]
        for row in rows:
            ratio = row["seconds_median"] / row["dofs"] / base
            print(
                f"{row['model']:>8} P{row['degree']} {row['bending'] or '':>6}  "
                f"{row['dofs']:>8} dofs  "
                f"{row['seconds_median']:7.2f} s  Newton {row['newton_steps']}  "
                f"{ratio:4.2f}× the membrane P1 time per dof"
            )


if __name__ == "__main__":
    main()
