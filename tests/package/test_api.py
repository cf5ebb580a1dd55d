"""The Python API: ``solve(spec, **overrides)`` on a config in any of its three forms, its
overrides checked as ``--set`` is, and the result's figures as attributes."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

from mpi4py import MPI

import numpy as np
import pytest

from shellobstacle import Config, DomainSpec, solve, solve_problem
from shellobstacle.config.loader import ConfigError, as_config, load_config
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.validity import assess
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.vi.options import ActiveSetOptions

SMALL = Path(__file__).parents[2] / "examples" / "small.toml"
COARSE = {"h": 0.1}  # a few hundred dofs: each solve takes a second or two


def _owned(result) -> np.ndarray:
    V = result.zeta.function_space
    return result.zeta.x.array[: V.dofmap.index_map.size_local * V.dofmap.index_map_bs]


@pytest.fixture(scope="module")
def by_path():
    return solve(SMALL, domain=COARSE)


def test_the_three_forms_of_a_spec_give_the_same_answer(by_path) -> None:
    """A path, the mapping read from it and the Config loaded from it (each with the same
    override), and a Config built in Python from the same objects, solve to the same ζ."""
    mapping = tomllib.loads(SMALL.read_text())
    config = load_config(SMALL, ["domain.h=0.1"])
    built = Config(config.shell, config.domain, penalty=config.penalty)
    assert by_path.converged
    for other in (
        solve(mapping, domain=COARSE),
        solve(load_config(SMALL), domain=COARSE),
        solve(config),
        solve(built),
    ):
        assert other.converged
        np.testing.assert_array_equal(_owned(other), _owned(by_path))
        assert other.contact == by_path.contact


def test_an_override_is_checked_with_the_configs_message() -> None:
    with pytest.raises(ConfigError) as from_set:
        load_config(SMALL, ["domain.h=-0.1"])
    with pytest.raises(ConfigError) as from_python:
        solve(SMALL, domain={"h": -0.1})
    assert str(from_set.value) == "--set domain.h=-0.1: domain.h must be > 0, got -0.1"
    assert str(from_python.value) == "domain={'h': -0.1}: domain.h must be > 0, got -0.1"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"domian": {"h": 0.1}}, "domian={'h': 0.1}: unknown section [domian]; did you mean"),
        ({"domain": {"hh": 0.1}}, "domain={'hh': 0.1}: unknown key 'hh' in [domain]; did you"),
        ({"domain": 0.1}, "domain=0.1: give a section as a mapping of its keys"),
    ],
)
def test_a_misspelled_override_is_refused_in_one_line(overrides, message) -> None:
    with pytest.raises(ConfigError) as err:
        solve(SMALL, **overrides)
    assert str(err.value).startswith(message)
    assert "\n" not in str(err.value)


def test_a_config_built_in_python_takes_the_loaders_defaults() -> None:
    koiter = load_config(Path(__file__).parents[2] / "examples" / "cylinder_koiter.toml")
    loaded = load_config(SMALL)
    assert Config(loaded.shell, loaded.domain, penalty=loaded.penalty) == dataclasses.replace(
        loaded, resolved={}, source="<python>"
    )
    assert Config(koiter.shell, koiter.domain, penalty=koiter.penalty).discretization.degree == 2
    nodal = Config(loaded.shell, loaded.domain, method="active-set")
    assert nodal.discretization.penalty_quadrature == "vertex"
    with pytest.raises(ConfigError, match=r"solver\.method = 'newton' needs a penalty"):
        Config(loaded.shell, loaded.domain)
    with pytest.raises(ConfigError, match="need a config read from TOML or given as a mapping"):
        solve(Config(loaded.shell, loaded.domain, penalty=loaded.penalty), domain=COARSE)


def test_an_options_object_is_the_one_set_of_options() -> None:
    """``solver=`` an instance of a method's options: that method, with those options (two
    Newton steps do not reach κ = 1e-10 from ζ = 0); another dataclass is refused."""
    failed = solve(
        SMALL,
        domain=COARSE,
        penalty={"kappa": 1e-10, "continuation": False},
        solver=NewtonOptions(max_iterations=2),
    )
    assert not failed.converged and "did not converge" in (failed.error or "")
    with pytest.warns(UserWarning, match="penalty.exponent is ignored"):  # (as with --set)
        exact = as_config(SMALL, {"solver": ActiveSetOptions(max_iterations=7)})
    assert (exact.method, exact.options) == ("active-set", ActiveSetOptions(max_iterations=7))
    assert exact.penalty is None and exact.resolved["solver"]["max_iterations"] == 7
    with pytest.raises(ConfigError, match=r"solver=DomainSpec\(…\) is not the options of"):
        solve(SMALL, solver=DomainSpec("disk", h=0.1))


def test_the_result_carries_its_figures(by_path) -> None:
    post = Postprocessor(by_path.problem, by_path.constraint)
    figures = post.contact()
    assert by_path.contact.area == figures["contact_area"] > 0
    assert by_path.contact.area_nodal == figures["contact_area_nodal"]
    assert by_path.contact.max_violation == figures["max_violation"]
    assert by_path.contact.count_nodal == figures["num_contact_nodes"]
    assert by_path.validity is by_path.validity  # computed once
    assert by_path.validity == assess(post, by_path.solved_kappa)
    assert by_path.zeta is by_path.problem.zeta and by_path.mesh is by_path.problem.mesh
    assert by_path.dofs == by_path.problem.num_dofs
    assert {"mesh", "checks", "compile", "solve"} <= set(by_path.timings)


@pytest.mark.mpi
def test_serial_equals_parallel() -> None:
    """``solve`` on every rank equals the same solve of the same mesh on one rank."""
    parallel = solve(SMALL, domain=COARSE)
    config = load_config(SMALL, ["domain.h=0.1"])
    mesh = create_mesh(config.domain, MPI.COMM_SELF)
    serial = solve_problem(
        config.shell, mesh, config.penalty, config.discretization, options=config.options
    )
    assert parallel.converged and serial.converged
    assert parallel.dofs == serial.dofs and parallel.h == serial.h
    assert parallel.contact.count_nodal == serial.contact.count_nodal
    assert parallel.contact.area == pytest.approx(serial.contact.area, rel=1e-8)
    assert parallel.validity.penetration == pytest.approx(serial.validity.penetration, rel=1e-6)
    assert [s.iterations for s in parallel.steps] == [s.iterations for s in serial.steps]
