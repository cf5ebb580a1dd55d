"""``[adapt]`` in the configuration: present (even empty) it switches adaptivity on; every
mistake is one line naming the key and the fix (exit 2 from the command line)."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

from mpi4py import MPI

import pytest

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.cli.main import main
from shellobstacle.config.loader import ConfigError, parse_config, to_toml
from shellobstacle.config.schema import reference_text

ROOT = Path(__file__).parents[2]
PAPER: dict[str, Any] = tomllib.loads((ROOT / "examples" / "paper.toml").read_text())


def _with(adapt: dict[str, Any] | None, **sections: dict[str, Any]) -> dict[str, Any]:
    data = copy.deepcopy(PAPER)
    if adapt is not None:
        data["adapt"] = adapt
    for name, table in sections.items():
        data.setdefault(name, {}).update(table)
    return data


def test_absent_and_empty() -> None:
    assert parse_config(_with(None)).adapt is None
    assert "adapt" not in parse_config(_with(None)).resolved
    cfg = parse_config(_with({}))
    assert cfg.adapt == AdaptOptions()
    assert cfg.resolved["adapt"]["fraction"] == 0.5
    assert "[adapt]" in to_toml(cfg.resolved)
    full = {"fraction": 0.3, "max_levels": 4, "target_dofs": 9000, "kappa": "local"}
    assert parse_config(_with(full)).adapt == AdaptOptions(0.3, 4, None, 9000, "local", False)


@pytest.mark.parametrize(
    ("adapt", "sections", "words"),
    [
        ({"fraction": 0.0}, {}, ["adapt.fraction", "(0, 1]"]),
        ({"fraction": 1.5}, {}, ["adapt.fraction"]),
        ({"max_levels": -1}, {}, ["adapt.max_levels"]),
        ({"max_levels": 1000}, {}, ["adapt.max_levels", "60"]),
        ({"target_error": 0.0}, {}, ["adapt.target_error"]),
        ({"target_dofs": 0}, {}, ["adapt.target_dofs"]),
        ({"kappa": "smallest"}, {}, ["adapt.kappa", "'largest'"]),
        ({"fractoin": 0.5}, {}, ["fractoin", "did you mean 'fraction'"]),
        ({"target_dofs": 1.5}, {}, ["adapt.target_dofs", "integer"]),
        (
            {},
            {"model": {"kind": "koiter"}, "discretization": {"degree": 2}},
            ["[adapt]", "model.kind = 'membrane'"],
        ),
        ({}, {"solver": {"method": "brezis-sibony"}}, ["[adapt]", "solver.method"]),
        (
            {"kappa": "local"},
            {"penalty": {"kappa": 1e-4, "exponent": None}},
            ["adapt.kappa", "penalty.exponent"],
        ),
    ],
)
def test_mistakes_name_the_key(adapt, sections, words) -> None:
    data = _with(adapt, **sections)
    if data["penalty"].get("exponent", 0) is None:
        del data["penalty"]["exponent"]
    with pytest.raises(ConfigError) as info:
        parse_config(data, "c.toml")
    for word in words:
        assert word in str(info.value), str(info.value)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")
def test_a_mistake_exits_2_from_the_command_line(tmp_path, capsys) -> None:
    path = tmp_path / "c.toml"
    path.write_text(to_toml(_with({"fraction": 2.0})))
    assert main(["solve", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "adapt.fraction" in err[0] and "Traceback" not in err[0]
    assert main(["experiment", "adaptive", str(ROOT / "examples" / "paper.toml"), "--dofs",
                 "10", "--reference-dofs", "5", "-o", str(tmp_path / "e")]) == 2  # fmt: skip
    assert "--dofs" in capsys.readouterr().err


def test_the_reference_lists_the_section() -> None:
    text = reference_text()
    assert "## [adapt] (optional section" in text
    for key in ("fraction", "max_levels", "target_error", "target_dofs", "kappa", "free_boundary"):
        assert f"| `{key}` |" in text
