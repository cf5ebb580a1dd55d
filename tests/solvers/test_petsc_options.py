"""``[solver.petsc_options]`` (the ``petsc_options`` of every options class) reaches the PETSc
objects of the chosen method under their prefixes, and an option no object reads is reported."""

from __future__ import annotations

import copy
import dataclasses
import tomllib
import warnings
from pathlib import Path
from typing import Any

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np
import pytest
from cli_helpers import assert_user_error, run

from shellobstacle.api import make_mesh
from shellobstacle.config.loader import ConfigError, load_config, parse_config
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.solvers.vi.active_set import ActiveSetSolver
from shellobstacle.solvers.vi.options import ActiveSetOptions, SnesVIOptions
from shellobstacle.solvers.vi.snes_vi import SnesVISolver

SMALL = Path(__file__).parents[2] / "examples" / "small.toml"
pytestmark = pytest.mark.mpi
COARSE = ["domain.h=0.08"]


@pytest.fixture(scope="module")
def cfg() -> Any:
    return load_config(SMALL, COARSE)


@pytest.fixture(scope="module")
def mesh(cfg: Any) -> Any:
    return make_mesh(cfg.domain)


def _newton(cfg: Any, mesh: Any, **changes: Any) -> tuple[NewtonSolver, np.ndarray]:
    kappas = cfg.penalty.ladder(mesh_size(mesh))
    problem = PenalizedProblem(cfg.shell, mesh, cfg.discretization, kappa=kappas[0])
    solver = NewtonSolver(problem, dataclasses.replace(cfg.solver, **changes))
    continuation(problem, solver, kappas)
    return solver, problem.zeta.x.array.copy()


def test_the_options_reach_newtons_jacobian_solver(cfg: Any, mesh: Any) -> None:
    """The KSP, its PC and MUMPS' factor take the options; the solution stays the same."""
    options = {"ksp_type": "gmres", "mat_mumps_icntl_14": 77}
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # every option is read
        solver, zeta = _newton(cfg, mesh, contact_zone=False, petsc_options=options)
    ksp = solver.linear.ksp
    assert ksp.getOptionsPrefix().startswith("shellobstacle_newton")
    assert ksp.getType() == "gmres"
    assert ksp.getPC().getFactorMatrix().getMumpsIcntl(14) == 77
    plain, reference = _newton(cfg, mesh, contact_zone=False)
    assert plain.linear.ksp.getType() == "cg"  # the options stay with their solver
    assert np.allclose(zeta, reference, rtol=0, atol=1e-10 * np.abs(reference).max())


def test_the_options_reach_the_contact_zones_factorizations(cfg: Any, mesh: Any) -> None:
    solver, _ = _newton(cfg, mesh, petsc_options={"mat_mumps_icntl_14": 66})
    prefixes = solver.user_options.prefixes
    assert prefixes and all(p.startswith("shellobstacle_zone") for p in prefixes)
    assert any(PETSc.Options().used(p + "mat_mumps_icntl_14") for p in prefixes)


def test_a_misspelled_option_is_reported(cfg: Any, mesh: Any) -> None:
    with pytest.warns(RuntimeWarning, match=r"solver.petsc_options.ksp_tyep: no PETSc object"):
        _newton(cfg, mesh, contact_zone=False, petsc_options={"ksp_tyep": "gmres"})


def test_a_misspelled_option_is_reported_when_newton_fails(cfg: Any, mesh: Any) -> None:
    """The report follows a solve that raised ConvergenceError too (on every rank)."""
    from shellobstacle.solvers.base import ConvergenceError

    options = {"ksp_tyep": "gmres"}
    unread = r"solver.petsc_options.ksp_tyep: no PETSc object"
    with pytest.warns(RuntimeWarning, match=unread), pytest.raises(ConvergenceError):
        _newton(cfg, mesh, contact_zone=False, max_iterations=1, petsc_options=options)


def test_an_option_read_on_some_ranks_only_is_not_reported() -> None:
    """PETSc's telescope gathers multigrid's coarse level onto fewer ranks (here one), and
    its inner solver exists on those only: its options count as read on every rank (no
    warning), and the solution is multigrid's without it."""
    cfg = load_config(SMALL, [*COARSE, "domain.refinements=1"])
    mesh = make_mesh(cfg.domain)
    options = {
        "mg_coarse_pc_type": "telescope",
        "mg_coarse_pc_telescope_reduction_factor": MPI.COMM_WORLD.size,
        "mg_coarse_telescope_pc_type": "cholesky",
        "mg_coarse_telescope_pc_factor_mat_solver_type": "mumps",
    }
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # every option is read somewhere
        solver, zeta = _newton(cfg, mesh, linear_solver="multigrid", petsc_options=options)
    assert solver.linear.levels == 2
    assert solver.linear.ksp.getPC().getMGCoarseSolve().getPC().getType() == "telescope"
    _, reference = _newton(cfg, mesh, linear_solver="multigrid")
    assert np.allclose(zeta, reference, rtol=0, atol=1e-8 * np.abs(reference).max())


def test_a_bad_value_is_a_config_error(cfg: Any, mesh: Any) -> None:
    with pytest.raises(ConfigError, match=r"solver.petsc_options: PETSc failed"):
        _newton(cfg, mesh, contact_zone=False, petsc_options={"ksp_type": "no_such_ksp"})


def test_the_options_reach_the_nodal_methods(cfg: Any, mesh: Any) -> None:
    """snes-vi: the SNES and its line search; active-set: its factorization."""
    disc = dataclasses.replace(cfg.discretization, penalty_quadrature="vertex")
    problem = PenalizedProblem(cfg.shell, mesh, disc)
    vi = SnesVISolver(problem, SnesVIOptions(petsc_options={"snes_linesearch_type": "bt"}))
    assert vi.snes.getOptionsPrefix().startswith("shellobstacle_vi")
    assert vi.snes.getLineSearch().getType() == "bt"  # the options' word over line_search's l2
    problem.zeta.x.array[:] = 0.0
    options = ActiveSetOptions(petsc_options={"mat_mumps_icntl_14": 55})
    solver = ActiveSetSolver(problem, options)
    assert solver.solve().converged
    assert solver.ksp.getPC().getFactorMatrix().getMumpsIcntl(14) == 55


def test_the_config_table_builds_the_options() -> None:
    """``[solver.petsc_options]`` or ``--set solver.petsc_options.<name>=…`` fill the chosen
    method's options (and Newton's); a name that is no option name is refused."""
    cfg = load_config(SMALL, ["solver.petsc_options.ksp_type=gmres"])
    assert cfg.solver.petsc_options == {"ksp_type": "gmres"}
    assert cfg.resolved["solver"]["petsc_options"] == {"ksp_type": "gmres"}
    cfg = load_config(
        SMALL, ["solver.method=active-set", "solver.petsc_options.mat_mumps_icntl_14=40"]
    )
    assert cfg.method_options.petsc_options == {"mat_mumps_icntl_14": 40}
    data = tomllib.loads(SMALL.read_text())
    for bad, needle in (
        ({"-ksp_type": "cg"}, "'-ksp_type' is not a PETSc option name"),
        ({"ksp_type": [1]}, "solver.petsc_options.ksp_type must be a string"),
        ("ksp_type=cg", "must be a table of PETSc options"),
    ):
        broken = copy.deepcopy(data)
        broken["solver"] = {"petsc_options": bad}
        with pytest.raises(ConfigError, match=needle):
            parse_config(broken, "small.toml")


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")
def test_solve_refuses_a_bad_value_in_one_line(tmp_path: Path, capsys) -> None:
    args = ["solve", str(SMALL), "-o", str(tmp_path / "x"), "-q", "--set", "domain.h=0.1"]
    code, _, err = run(capsys, *args, "--set", "solver.petsc_options.ksp_type=no_such_ksp")
    assert_user_error(code, err, "solver.petsc_options: PETSc failed", "no_such_ksp")
