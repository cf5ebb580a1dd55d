"""The Python API's dataclasses (:mod:`shellobstacle.spec`, the penalty's) refuse what the
config refuses, with the config's message (the config prefixes the file or the ``--set`` that
gave it)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from cli_helpers import BASE, changed

from shellobstacle.config.loader import ConfigError, load_config, parse_config
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

EXAMPLES = Path(__file__).parents[2] / "examples"
PAPER = str(EXAMPLES / "paper.toml")
BALL = str(EXAMPLES / "cap_on_ball.toml")
INF = math.inf


@pytest.mark.parametrize(
    ("config", "sets", "make"),
    [
        (BALL, ["obstacle.c=0.3"], lambda: _ball(c=0.3)),
        (PAPER, ["obstacle.radius=5.0"], lambda: Obstacle(kind="plane", radius=5.0)),
        (PAPER, ['obstacle.side="inside"'], lambda: Obstacle(kind="plane", side="inside")),
        (BALL, ["obstacle.q=[0, 0, 2]"], lambda: _ball(q=(0, 0, 2))),
        (BALL, ["obstacle.center=[true, 0, 0]"], lambda: _ball(center=(True, 0, 0))),
        (BALL, ["obstacle.radius=true"], lambda: _ball(radius=True)),
        (PAPER, ["material.epsilon=inf"], lambda: Material(INF, 0.4, 0.012)),
        (PAPER, ["material.mu=true"], lambda: Material(0.001, 0.4, True)),
        (PAPER, ["discretization.degree=true"], lambda: Discretization(degree=True)),
        (PAPER, ["discretization.degree=2.0"], lambda: Discretization(degree=2.0)),
        (PAPER, ["discretization.quadrature_degree=2.5"], lambda: Discretization(1, **_QD)),
        (PAPER, ["discretization.interior_penalty=inf"], lambda: Discretization(**_IP)),
        (PAPER, ["load.parameters.a=inf"], lambda: Load(("0", "0", "0"), {"a": INF})),
        (PAPER, ['load.p=["0", "0", true]'], lambda: Load(("0", "0", True))),
        (PAPER, ["penalty.exponent=true"], lambda: PenaltySpec(exponent=True)),
        (PAPER, ["penalty.kappa=inf"], lambda: PenaltySpec(kappa=INF)),
        (PAPER, ["penalty.continuation=1"], lambda: PenaltySpec(exponent=1.5, continuation=1)),
    ],
)
def test_the_api_refuses_what_the_config_refuses_with_its_message(
    config: str, sets: list[str], make: Callable[[], Any]
) -> None:
    with pytest.raises(ConfigError) as from_config:
        load_config(config, sets)
    with pytest.raises(ValueError) as from_api:
        make()
    assert str(from_config.value).endswith(str(from_api.value)), (from_config, from_api)


_QD: dict[str, Any] = {"quadrature_degree": 2.5}
_IP: dict[str, Any] = {"interior_penalty": INF}


def _ball(**kw: Any) -> Obstacle:
    """``Obstacle(kind="sphere", center=(0, 0, -1), radius=1, **kw)`` (``kw`` may replace
    them)."""
    return Obstacle(**{"kind": "sphere", "center": (0, 0, -1), "radius": 1, **kw})


def test_a_key_the_kind_does_not_read_at_its_default_is_accepted() -> None:
    """``q = (0, 0, 1)`` is the default: a ball built with it is a ball."""
    ball = _ball(q=(0.0, 0.0, 1.0))
    assert ball.radius == 1.0 and ball.keys() == (
        "kind",
        "center",
        "radius",
        "side",
        "contact_face",
    )


def test_the_numbers_the_config_converts_the_api_converts() -> None:
    """The config turns the numbers of ``load.p`` into their text and every number into a
    float; so does the API."""
    assert Load((0, 0, 1)).p == ("0.0", "0.0", "1.0")
    assert Material(1, 0, 1) == Material(1.0, 0.0, 1.0)
    assert isinstance(_ball().radius, float)


def test_a_result_folders_config_holds_only_the_keys_its_obstacle_reads() -> None:
    """``--set obstacle.kind`` leaves the file's plane keys unread (a warning): the resolved
    config (a result folder's ``config.toml``) leaves them out, so that it loads again."""
    with pytest.warns(UserWarning, match="obstacle.q is ignored"):
        cfg = load_config(PAPER, ['obstacle.kind="expression"', 'obstacle.g="x3"'])
    assert "q" not in cfg.resolved["obstacle"]
    again = parse_config({k: dict(v) for k, v in cfg.resolved.items()}, "config.toml")
    assert again.shell.obstacle == cfg.shell.obstacle


def config_message(changes: dict[str, Any]) -> str:
    """The ConfigError of ``BASE`` with ``changes``, without its ``c.toml: `` prefix."""
    with pytest.raises(ConfigError) as info:
        parse_config(changed(changes), "c.toml")
    text = str(info.value)
    assert text.startswith("c.toml: "), text
    return text.removeprefix("c.toml: ")


@pytest.mark.parametrize(
    ("make", "changes"),
    [
        (lambda: PenaltySpec(kappa=0.0), {"penalty": {"kappa": 0.0}}),
        (lambda: PenaltySpec(kappa=-1e-6), {"penalty": {"kappa": -1e-6}}),
        (lambda: PenaltySpec(exponent=0.0), {"penalty": {"exponent": 0.0}}),
        (lambda: PenaltySpec(exponent=25.0), {"penalty": {"exponent": 25.0}}),
        (
            lambda: PenaltySpec(kappa=1e-6, exponent=1.5),
            {"penalty": {"kappa": 1e-6, "exponent": 1.5}},
        ),
        (lambda: PenaltySpec(), {"penalty": {}}),
        (lambda: DomainSpec("square", h=0.1), {"domain.kind": "square"}),
        (lambda: DomainSpec("disk", h=0.0), {"domain.h": 0.0}),
        (lambda: DomainSpec("disk", h=-0.1), {"domain.h": -0.1}),
        (lambda: DomainSpec("disk"), {"domain": {"kind": "disk", "radius": 0.5}}),
        (lambda: DomainSpec("disk", h=0.1, refinements=9), {"domain.refinements": 9}),
        (lambda: DomainSpec("disk", h=2.0), {"domain.h": 2.0}),
        (lambda: DomainSpec("disk", h=0.1, radius=-0.5), {"domain.radius": -0.5}),
        (lambda: Discretization(transverse="fixed"), {"discretization": {"transverse": "fixed"}}),
        (lambda: Discretization(degree=3), {"discretization": {"degree": 3}}),
    ],
)
def test_api_raises_the_configs_message(make, changes) -> None:
    with pytest.raises(ValueError) as info:
        make()
    assert str(info.value) == config_message(changes)


def test_api_model_kind_is_validated() -> None:
    cfg = parse_config(BASE)
    with pytest.raises(ValueError) as info:
        Shell(cfg.shell.surface, cfg.shell.material, cfg.shell.load, model="plate")
    assert str(info.value) == config_message({"model": {"kind": "plate"}})
