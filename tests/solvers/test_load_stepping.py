"""The solvers of the nonlinear Koiter energy (docs/model.md §11.1–11.2): the energy-decreasing
Newton method, load stepping with step control, and the limit point.

- from a compressed start, where the tangent has negative eigenvalues, Newton shifts
  the tangent and reaches the solution it reaches from ``ζ = 0``;
- a load that Newton with full steps (SNES) cannot reach from ``ζ = 0`` is reached by load
  stepping after cuts, and its answer is another path's;
- each step is recorded and logged; a stepping that cannot go on away from a limit point raises
  a one-line ConvergenceError naming the load reached;
- on the paper's cap under its load the path meets a limit point near ``s = 0.0128``: load
  stepping stops there with a LimitPointError, where full-step Newton at ``s = 0.02`` converges,
  silently, to an unstable equilibrium off the path.
"""

from __future__ import annotations

import logging

from mpi4py import MPI

import numpy as np
import pytest
from conftest import make_paper_shell

from shellobstacle.geometry.surface import Surface
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.models.nonlinear_koiter import NonlinearKoiterProblem
from shellobstacle.solvers.nonlinear.load_stepping import LimitPointError, LoadStepping
from shellobstacle.solvers.nonlinear.newton import EnergyNewton
from shellobstacle.solvers.result import ConvergenceError
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

C0IP = Discretization(degree=2, bending="c0ip")
#: the tangent's kernels are large: -O0 compiles them many times faster than -O2
JIT = {"cffi_extra_compile_args": ["-O0", "-g0"], "timeout": 600}


def plate_problem(comm: MPI.Comm = MPI.COMM_SELF) -> NonlinearKoiterProblem:
    """Issue 57's clamped plate (disk of radius 0.5, ε = 0.005, ν = 0.3) at ``h = 0.1``; at
    load factor 1 it deflects about one thickness."""
    shell = Shell(
        Surface.from_strings(["y1", "y2", "0"]),
        Material(0.005, 1.5, 1.0),
        Load(("0", "0", "-3.628e-6")),
        Obstacle(),
        "koiter",
    )
    mesh = create_mesh(DomainSpec(kind="disk", h=0.1, radius=0.5), comm, ghosted=True)
    return NonlinearKoiterProblem(shell, mesh, C0IP, jit_options=JIT)


def test_an_indefinite_tangent_is_shifted_to_a_descent_direction() -> None:
    """A radial contraction ``ζ_α = c y_α (|y|² − R²)`` compresses the plate beyond its
    buckling strain: the tangent there has negative eigenvalues, Newton shifts it, and it
    reaches the solution it reaches from 0 (to round-off)."""
    problem = plate_problem()
    newton = EnergyNewton(problem)
    problem.zeta.x.array[:] = 0.0
    assert newton.solve().shift == 0.0  # the path from 0 is positive definite
    reference = problem.zeta.x.array.copy()
    problem.zeta.interpolate(
        lambda x: np.vstack([0.02 * x[0] * (x[0] ** 2 + x[1] ** 2 - 0.25),
                             0.02 * x[1] * (x[0] ** 2 + x[1] ** 2 - 0.25), 0 * x[0]])
    )  # fmt: skip
    newton.tangent.assemble()
    assert newton.tangent.factor() > 5
    record = newton.solve()
    assert record.shift > 0 and record.step < 1
    difference = np.abs(problem.zeta.x.array - reference).max()
    assert difference < 1e-10 * np.abs(reference).max()
    newton.tangent.assemble()
    assert newton.tangent.factor() == 0


def test_load_stepping_reaches_what_full_newton_steps_cannot() -> None:
    """At 100 times the plate's load (6.1 thicknesses) full-step Newton from 0 diverges;
    load stepping asked for the whole load in one step cuts it, and reaches the state of a path
    that starts at 1/16 of the load and grows its steps."""
    problem = plate_problem()
    problem.load_factor.value = 100.0
    with pytest.raises(RuntimeError, match="smaller steps"):
        problem.solve()
    newton = EnergyNewton(problem, max_it=8)
    path = LoadStepping(problem, first_step=100.0, max_step=100.0, newton=newton).solve(100.0)
    assert path.cuts >= 1 and path.steps[-1].load_factor == 100.0
    reached = problem.zeta.x.array.copy()
    other = LoadStepping(problem, first_step=6.25, max_step=100.0, newton=newton).solve(100.0)
    assert other.cuts == 0
    assert np.abs(reached - problem.zeta.x.array).max() < 1e-8 * np.abs(reached).max()
    assert path.steps[-1].max_deflection / 0.01 == pytest.approx(6.105, abs=1e-3)


def test_each_step_is_recorded_and_logged(caplog: pytest.LogCaptureFixture) -> None:
    """A record per accepted step (the load factor, Newton steps, energy, largest |ζ_3|, current
    stiffness) and a log line per step; the plate stiffens (S grows above 1)."""
    problem = plate_problem()
    with caplog.at_level(logging.INFO, logger="shellobstacle.solvers.nonlinear.load_stepping"):
        path = LoadStepping(problem, first_step=0.5).solve(1.0)
    steps = path.steps[1:]
    assert [s.load_factor for s in steps] == [0.5, 1.0]
    assert all(s.newton_iterations >= 2 for s in steps)
    assert steps[1].energy < steps[0].energy < 0
    assert steps[1].max_deflection / 0.01 == pytest.approx(0.956, abs=1e-3)
    assert 1 < steps[0].stiffness < steps[1].stiffness
    lines = [r.getMessage() for r in caplog.records if "load factor" in r.getMessage()]
    assert len(lines) == 2 and "load factor 1: " in lines[1]


def test_a_stepping_that_cannot_go_on_says_where_it_stopped() -> None:
    """Newton with one step cannot converge at any load: the steps are cut to the minimum and
    the error (not a limit point: the path is at its linear stiffness) names s = 0."""
    problem = plate_problem()
    stepping = LoadStepping(problem, min_step=0.1, newton=EnergyNewton(problem, max_it=1))
    with pytest.raises(ConvergenceError, match="stopped at s = 0 ") as error:
        stepping.solve(1.0)
    assert not isinstance(error.value, LimitPointError)
    assert len(str(error.value).splitlines()) == 1


@pytest.mark.slow
def test_the_limit_point_of_the_paper_cap_is_detected() -> None:
    """The paper's cap under its load (concentrated near the apex) softens to a limit point
    near s = 0.0128 (h = 0.15): the stepping stops at the last stable state with the estimate
    of the limit load, where Newton with full steps at s = 0.02 converges, without a word, to an
    unstable equilibrium four times as deflected."""
    mesh = create_mesh(DomainSpec(kind="disk", h=0.15, radius=0.5), MPI.COMM_SELF, ghosted=True)
    problem = NonlinearKoiterProblem(make_paper_shell(model="koiter"), mesh, C0IP, jit_options=JIT)
    stepping = LoadStepping(
        problem, first_step=0.005, max_step=0.005, min_step=2e-4,
        newton=EnergyNewton(problem, max_it=10),
    )  # fmt: skip
    with pytest.raises(LimitPointError, match=r"limit point of the load near s = 0\.01") as error:
        stepping.solve(0.02)
    limit = error.value
    assert 0.011 < limit.load_factor < limit.estimate < 0.013
    assert limit.path.steps[-1].stiffness < 0.2 < limit.path.steps[1].stiffness
    assert limit.deflection == pytest.approx(stepping.deflection())
    stable = limit.deflection
    problem.zeta.x.array[:] = 0.0
    problem.load_factor.value = 0.02
    problem.solve()  # full steps: "converges"
    assert stepping.deflection() > 3 * stable
    stepping.newton.tangent.assemble()
    assert stepping.newton.tangent.factor() >= 1  # to an unstable equilibrium


@pytest.mark.mpi
def test_serial_and_parallel_paths_agree() -> None:
    """On two ranks (MUMPS' inertia over the distributed matrix) the path is the serial one."""
    if MPI.COMM_WORLD.size == 1:
        pytest.skip("compares a distributed path with a serial one")
    paths = []
    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):
        problem = plate_problem(comm)
        paths.append(LoadStepping(problem, first_step=0.5).solve(1.0).steps)
    assert [s.load_factor for s in paths[0]] == [s.load_factor for s in paths[1]]
    for a, b in zip(paths[0], paths[1], strict=True):
        assert a.max_deflection == pytest.approx(b.max_deflection, rel=1e-9)
        assert a.stiffness == pytest.approx(b.stiffness, rel=1e-7)
