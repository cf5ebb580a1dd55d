"""Multigrid on 4 ranks (oversubscribed on a small machine) equals the serial solve."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from mpi4py import MPI

import numpy as np
import pytest
from cli_helpers import mpiexec

pytestmark = [
    pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="starts its own 4 ranks"),
    pytest.mark.skipif(mpiexec() is None, reason="no mpiexec"),
]


def solve_and_gather() -> dict | None:
    """The continuation of tests/solvers/test_multigrid.py with the V-cycle on three levels
    (gmsh's disk at h = 0.16 refined twice: 2,139 dofs, small, since four ranks share however
    few cores):
    on rank 0 the contact area, whether every step converged, and ζ at the nodes sorted by
    coordinates."""
    from conftest import ladder, make_paper_shell

    from shellobstacle.mesh.domains import DomainSpec
    from shellobstacle.mesh.meshing import create_mesh
    from shellobstacle.models.problem import PenalizedProblem
    from shellobstacle.post.contact import Postprocessor
    from shellobstacle.solvers.newton.continuation import continuation
    from shellobstacle.solvers.newton.solver import NewtonOptions, NewtonSolver

    mesh = create_mesh(DomainSpec(kind="disk", radius=0.5, h=0.16, refinements=2))
    problem = PenalizedProblem(make_paper_shell(), mesh)
    solver = NewtonSolver(problem, NewtonOptions(linear_solver="multigrid"))
    steps = continuation(problem, solver, ladder(mesh))
    area = Postprocessor(problem).contact()["contact_area"]
    V = problem.zeta.function_space
    owned = V.dofmap.index_map.size_local
    x = V.tabulate_dof_coordinates()[:owned, :2]
    zeta = problem.zeta.x.array[: 3 * owned].reshape(owned, 3)
    parts = MPI.COMM_WORLD.gather((x, zeta), root=0)
    if MPI.COMM_WORLD.rank != 0:
        return None
    x = np.concatenate([p[0] for p in parts])
    zeta = np.concatenate([p[1] for p in parts])
    order = np.lexsort((np.round(x[:, 1], 12), np.round(x[:, 0], 12)))
    return {
        "ranks": MPI.COMM_WORLD.size,
        "levels": solver.linear.levels,
        "area": area,
        "converged": all(s.newton.converged for s in steps),
        "x": x[order].tolist(),
        "zeta": zeta[order].tolist(),
    }


#: run on every rank of ``mpiexec``; rank 0 prints the gathered result
CHILD = """
import json, sys
sys.path[:0] = sys.argv[1:]
from test_multigrid_ranks import solve_and_gather
result = solve_and_gather()
if result is not None:
    print(json.dumps(result))
"""


def _on_ranks(ranks: int) -> dict:
    command = [
        mpiexec(),
        "-n",
        str(ranks),
        sys.executable,
        "-c",
        CHILD,
        str(Path(__file__).parent),
        str(Path(__file__).parents[1]),
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # four ranks on however many cores
def test_four_ranks_equal_one() -> None:
    """The same nodes, the same contact area (the same active points) and ζ to the solver's
    tolerance on 4 ranks as serially (the 2-rank run of tests/solvers/test_multigrid.py checks
    2)."""
    serial, parallel = solve_and_gather(), _on_ranks(4)
    assert parallel["ranks"] == 4 and serial["levels"] == parallel["levels"] == 3
    assert serial["converged"] and parallel["converged"]
    np.testing.assert_allclose(parallel["x"], serial["x"], atol=1e-12)
    assert serial["area"] > 0
    assert abs(parallel["area"] - serial["area"]) <= 1e-10 * serial["area"]
    zs, zp = np.asarray(serial["zeta"]), np.asarray(parallel["zeta"])
    assert np.linalg.norm(zp - zs) <= 1e-8 * np.linalg.norm(zs)
