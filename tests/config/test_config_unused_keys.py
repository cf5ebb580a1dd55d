"""A key that the chosen kind or method does not read is reported, naming the key and the kind
(``shellobstacle.config.schema.SELECTORS``, ``Key.when``), instead of being silently ignored."""

from __future__ import annotations

import copy
import tomllib
import warnings
from pathlib import Path
from typing import Any

from mpi4py import MPI

import pytest

from shellobstacle.cli.main import main
from shellobstacle.config.loader import load_config, parse_config

EXAMPLES = Path(__file__).parents[2] / "examples"
PAPER = EXAMPLES / "paper.toml"
BASE: dict[str, Any] = tomllib.loads(PAPER.read_text())
ELLIPSE = {"kind": "ellipse", "semi_axes": [0.5, 0.4], "h": 0.1}
POLYGON = {"kind": "polygon", "vertices": [[0, 0], [0.4, 0], [0, 0.4]], "h": 0.1}

CASES = [
    ({"surface": {"theta": ["y1", "y2", "0"]}}, "surface.theta", "surface.kind = 'spherical_cap'"),
    ({"domain": {"semi_axes": [0.5, 0.4]}}, "domain.semi_axes", "domain.kind = 'disk'"),
    ({"domain": {**POLYGON, "radius": 0.5}}, "domain.radius", "domain.kind = 'polygon'"),
    ({"domain": {**ELLIPSE, "corners": [[0, 0], [1, 1]]}}, "domain.corners", "'ellipse'"),
    ({"solver": {"bs_rtol": 1e-9}}, "solver.bs_rtol", "solver.method = 'newton'"),
    ({"solver": {"xi": 1e4}}, "solver.xi", "solver.method = 'newton'"),
    ({"solver": {"vi_type": "ssls"}}, "solver.vi_type", "solver.method = 'newton'"),
    ({"solver": {"proximal_tol": 1e-7}}, "solver.proximal_tol", "solver.method = 'newton'"),
    (
        {"solver": {"method": "brezis-sibony", "linear_solver": "iterative"}},
        "solver.linear_solver",
        "solver.method = 'brezis-sibony'",
    ),
    (
        {"solver": {"method": "active-set", "rtol": 1e-8}},
        "solver.rtol",
        "solver.method = 'active-set'",
    ),
    (
        {"solver": {"method": "snes-vi"}},
        "penalty.exponent",
        "solver.method = 'snes-vi' solves the nodal constraint exactly",
    ),
    ({"discretization": {"bending": "c0ip"}}, "discretization.bending", "model.kind = 'membrane'"),
    (
        {"discretization": {"interior_penalty": 8.0}},
        "discretization.interior_penalty",
        "model.kind = 'membrane'",
    ),
]


def _merged(change: dict[str, Any]) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    for section, values in change.items():
        if section == "domain":
            data["domain"] = {**({} if "kind" in values else data["domain"]), **values}
        else:
            data.setdefault(section, {}).update(values)
    return data


@pytest.mark.parametrize(("change", "key", "selector"), CASES, ids=[c[1] for c in CASES])
def test_a_key_the_choice_does_not_read_is_reported(
    change: dict[str, Any], key: str, selector: str
) -> None:
    """One warning naming the file, the key and the kind or method that does not read it."""
    with pytest.warns(UserWarning) as caught:
        parse_config(_merged(change), "my.toml")
    messages = [str(w.message) for w in caught if f"{key} is ignored" in str(w.message)]
    assert len(messages) == 1, messages
    assert messages[0].startswith(f"my.toml: {key} is ignored: ") and selector in messages[0]


def test_the_key_given_by_set_is_named_by_its_set() -> None:
    with pytest.warns(UserWarning, match=r"^--set solver.bs_rtol=1e-9: solver.bs_rtol is ignored"):
        load_config(PAPER, ["solver.bs_rtol=1e-9"])


@pytest.mark.parametrize("path", sorted(EXAMPLES.glob("*.toml")), ids=lambda p: p.name)
def test_the_examples_use_every_key_they_give(path: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_config(path)


@pytest.mark.parametrize(
    ("sets", "method"),
    [
        (["solver.bs_rtol=1e-6", "solver.xi=2e4"], "brezis-sibony"),
        (["solver.vi_type=ssls", "solver.rtol=1e-9"], "snes-vi"),
        (["solver.proximal_tol=1e-7", "solver.max_iterations=30"], "proximal-galerkin"),
        (["solver.max_iterations=30"], "active-set"),
        (["discretization.bending=c0ip", "discretization.interior_penalty=9.0"], None),
    ],
)
def test_a_key_the_choice_reads_is_not_reported(sets: list[str], method: str | None) -> None:
    more = (
        [f"solver.method={method}"] if method else ["model.kind=koiter", "discretization.degree=2"]
    )
    if method in ("snes-vi", "proximal-galerkin", "active-set"):
        more.append("penalty.exponent=1.5")  # (the nodal methods' own warning is tested above)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_config(PAPER, [*more, *sets])
    named = [str(w.message) for w in caught if any(s.split("=")[0] in str(w.message) for s in sets)]
    assert named == []


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI test runs serially")
def test_solve_prints_the_warning(tmp_path: Path, capsys) -> None:
    """The command reports it once the config is accepted (and the log keeps it)."""
    out = tmp_path / "out"
    sets = ["domain.h=0.1", "output.paraview=false", "output.figures=false", "solver.vi_type=ssls"]
    args = ["solve", str(PAPER), "-o", str(out)]
    assert main([*args, *(a for s in sets for a in ("--set", s))]) == 0
    err = capsys.readouterr()
    text = err.out + err.err
    assert "solver.vi_type is ignored: solver.method = 'newton' does not use it" in text
    assert "solver.vi_type is ignored" in (out / "log.txt").read_text()


def test_an_experiment_names_the_methods_it_runs_besides_the_configs() -> None:
    """``experiment solvers`` runs Brezis–Sibony beside Newton: its keys are read (and reach
    its options), not reported."""
    from shellobstacle.experiments.options import EXPERIMENT_READS

    sets = ["solver.bs_rtol=1e-6", "solver.mass=lumped"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cfg = load_config(PAPER, sets, EXPERIMENT_READS["solvers"])
    options = cfg.options_of("brezis-sibony")
    assert (options.rtol, options.mass, options.start) == (1e-6, "lumped", "linearized")
    with pytest.warns(UserWarning, match="solver.bs_rtol is ignored"):
        load_config(PAPER, sets, EXPERIMENT_READS["koiter-limit"])
