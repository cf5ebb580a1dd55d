"""The shape registry: a shape of obstacle is one class declaring its kind, summary and
parameters plus one ``register`` line, validated by that declaration, and everything that lists
the shapes (the config's keys and choices, the config reference, the user guide, a picture's
title) reads it."""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_helpers import run
from conftest import CAP_ON_COARSE_DISK

from shellobstacle.config.loader import parse_config
from shellobstacle.config.schema import SCHEMA, reference_text
from shellobstacle.geometry.surface import Geometry
from shellobstacle.messages import ConfigError
from shellobstacle.obstacle import SHAPES, Obstacle, Parameter, from_spec, register
from shellobstacle.obstacle.shapes import example, shape_table
from shellobstacle.spec import Obstacle as ObstacleSpec

DOCS = Path(__file__).parents[2] / "docs"

#: the paper's cap on a coarse disk over the obstacle that :func:`_config` appends
CONFIG = (
    CAP_ON_COARSE_DISK
    + """

[load]
p = ["0", "0", "Piecewise((-(2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.15), (0, True))"]

[penalty]
exponent = 1.5

[output]
paraview = false
figures = false
"""
)
PARABOLOID = '[obstacle]\nkind = "paraboloid"\na = 0.2\n'
#: the same obstacle as a formula
FORMULA = '[obstacle]\nkind = "expression"\ng = "x3 + 0.2*(x1**2 + x2**2)"\n'


class Paraboloid(Obstacle):
    """Above the paraboloid ``x3 = c − a(x1² + x2²)``: ``g = x3 − c + a(x1² + x2²)``."""

    kind = "paraboloid"
    summary = "above the paraboloid x3 = c − a(x1² + x2²) (a test's shape)"
    parameters = (
        Parameter("a", "float", "the paraboloid's curvature a", example=0.2),
        Parameter("c", "float", "the height c of its apex", default=0.0),
    )

    def __init__(self, a: float, c: float = 0.0, offset: float = 0.0) -> None:
        super().__init__(offset)
        self.a, self.apex = a, c

    def describe(self) -> str:
        return f"the paraboloid x3 = {self.apex:g} − {self.a:g}(x1² + x2²)"

    def value(self, G: Geometry, x: Sequence[Any]) -> Any:
        return x[2] - self.apex + self.a * (x[0] ** 2 + x[1] ** 2)

    def gradient(self, G: Geometry, x: Sequence[Any]) -> list[Any]:
        return [2 * self.a * x[0], 2 * self.a * x[1], 1.0]


@pytest.fixture
def paraboloid() -> Iterator[type[Obstacle]]:
    shape = register(Paraboloid)  # the one registry line
    yield shape
    del SHAPES["paraboloid"]


def _config(obstacle: str) -> Any:
    return parse_config(tomllib.loads(CONFIG + obstacle), "paraboloid.toml")


def test_a_registered_shape_is_in_the_config_reference(capsys, paraboloid) -> None:
    """Its kind among the choices, its own key, and a key it shares with the plane."""
    code, out, _ = run(capsys, "config-reference")
    assert code == 0 and out.strip() == reference_text().strip()
    assert "paraboloid: above the paraboloid x3 = c − a(x1² + x2²) (a test's shape)" in out
    assert "(one of plane, sphere, cylinder, expression, paraboloid) |" in out
    assert "| `a` | float | — | paraboloid: the paraboloid's curvature a |" in out
    assert (
        "| `c` | float | 0.0 | plane/paraboloid: the plane's offset along q (plane); the height "
        "c of its apex (paraboloid) |" in out
    )


def test_a_registered_shape_is_validated_by_its_declaration(paraboloid) -> None:
    """The API and the config refuse what the declaration refuses, with one message."""
    assert ObstacleSpec(kind="paraboloid", a=1).parameters == {"a": 1.0, "c": 0.0}
    cases = [
        ({}, "obstacle.kind = 'paraboloid' needs obstacle.a"),
        ({"a": True}, "obstacle.a must be a number, got True"),
        ({"a": 0.2, "radius": 1.0}, "obstacle.radius is not read by obstacle.kind = 'paraboloid'"),
    ]
    for given, message in cases:
        with pytest.raises(ValueError, match=re.escape(message)):
            ObstacleSpec(kind="paraboloid", **given)
        toml = "".join(f"{k} = {str(v).lower()}\n" for k, v in given.items())
        with pytest.raises(ConfigError, match=re.escape(message)):
            _config('[obstacle]\nkind = "paraboloid"\n' + toml)
    with pytest.raises(ValueError, match=r"set obstacle\.kind = 'paraboloid', or remove it"):
        ObstacleSpec(kind="plane", a=0.2)


@pytest.mark.mpi
def test_a_registered_shape_solves_as_its_formula(paraboloid) -> None:
    """Through the API: the same ζ and contact as ``g`` written as an expression."""
    from mpi4py import MPI

    from shellobstacle.api import solve
    from shellobstacle.post.contact import Postprocessor
    from shellobstacle.post.pictures import describe

    shape, formula = (solve(_config(text)) for text in (PARABOLOID, FORMULA))
    assert shape.converged and formula.converged
    assert isinstance(shape.problem.obstacle, Paraboloid) and shape.problem.linearized
    assert describe(shape.problem.obstacle) == "the paraboloid x3 = 0 − 0.2(x1² + x2²)"
    zeta, other = shape.problem.zeta.x.array, formula.problem.zeta.x.array
    difference = MPI.COMM_WORLD.allreduce(float(np.max(np.abs(zeta - other))), op=MPI.MAX)
    size = MPI.COMM_WORLD.allreduce(float(np.max(np.abs(other))), op=MPI.MAX)
    assert difference <= 1e-10 * size
    area = [
        Postprocessor(r.problem, r.constraint).contact()["contact_area"] for r in (shape, formula)
    ]
    assert area[0] > 0 and area[0] == pytest.approx(area[1], rel=1e-10)


def test_a_registered_shape_solves_from_a_config_file(capsys, paraboloid, tmp_path) -> None:
    """Through the command line: ``kind = "paraboloid"`` in a TOML file; the result folder's
    config holds the shape and its parameters and loads again."""
    path = tmp_path / "paraboloid.toml"
    path.write_text(CONFIG + PARABOLOID)
    code, _, err = run(capsys, "solve", str(path), "-o", str(tmp_path / "out"), "-q")
    assert code == 0, err
    resolved = tomllib.loads((tmp_path / "out" / "config.toml").read_text())
    assert resolved["obstacle"] == {
        "kind": "paraboloid",
        "a": 0.2,
        "c": 0.0,
        "contact_face": "middle",
    }
    again = parse_config(resolved, "config.toml")
    assert again.shell.obstacle == ObstacleSpec(kind="paraboloid", a=0.2)


def test_a_declaration_is_checked_when_it_is_registered(paraboloid) -> None:
    with pytest.raises(ValueError, match="already registered"):
        register(Paraboloid)
    with pytest.raises(ValueError, match="not a subclass of Obstacle"):
        register(object)  # type: ignore[arg-type]
    bad = {
        "its constructor takes no argument 'b'": Parameter("b", "float", "b", default=0.0),
        "obstacle.c is a float for obstacle.kind = 'plane'": Parameter(
            "c", "float[3]", "c", example=(0.0, 0.0, 0.0)
        ),
        "obstacle.a must be > 0, got -1.0": Parameter("a", "float", "a", default=-1.0, above=0),
        "a has neither a default nor an example": Parameter("a", "float", "a"),
    }
    for message, parameter in bad.items():
        shape = type("Bad", (Paraboloid,), {"kind": "bad", "parameters": (parameter,)})
        with pytest.raises(ValueError, match=re.escape(message)):
            register(shape)
    assert "bad" not in SHAPES


def test_every_shape_builds_from_its_declaration() -> None:
    """Each registered shape's examples make a valid obstacle of its class, which describes
    itself in words; every key the shapes declare is a key of ``[obstacle]``."""
    for kind, shape in SHAPES.items():
        obstacle = from_spec(ObstacleSpec(kind=kind, **example(kind)))
        assert type(obstacle) is shape and obstacle.describe().startswith("the ")
        assert {p.name for p in shape.parameters} <= set(SCHEMA["obstacle"])


def test_the_user_guide_lists_every_shape() -> None:
    text = (DOCS / "user-guide.md").read_text()
    table = re.search(r"<!-- shapes: [^\n]*-->\n(.*?)<!-- end of shapes -->", text, re.S)
    assert table is not None
    assert table.group(1).strip() == shape_table(), (
        "regenerate the table between the markers of docs/user-guide.md with: python -c "
        "'from shellobstacle.obstacle.shapes import shape_table; print(shape_table())'"
    )
    for kind in SHAPES:
        assert f"| `{kind}` |" in table.group(1)
