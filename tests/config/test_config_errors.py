"""What the config refuses: exit code 2 and one line that names the file, the key or the
quantity, never a traceback.

Each test runs the command line (``shellobstacle.cli.main``) on a config written to
``tmp_path`` (``examples/small.toml`` with a coarse mesh, h = 0.1, and one change) and checks
the message text, not only the exit code: the file itself (missing, not TOML, not text, a
directory; a byte-order mark is read), unknown or missing keys and sections, wrong types,
values out of range, and the meshes ``[domain]`` names. Expressions: test_expression_errors.py;
broken assumptions: test_geometry_errors.py; ``--set`` and the other arguments:
tests/cli/test_command_line_errors.py; the API's dataclasses: test_spec_validation.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import BASE, DELETE, assert_user_error, check_error, run, serial, write_config

from shellobstacle.config.loader import load_config, to_toml

pytestmark = serial

# --------------------------------------------------------------------------- the file itself


def test_config_file_that_does_not_exist(capsys, tmp_path) -> None:
    missing = tmp_path / "nowhere.toml"
    code, _, err = run(capsys, "check", str(missing))
    assert_user_error(code, err, "nowhere.toml", "does not exist")


def test_invalid_toml(capsys, tmp_path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text('[surface\nkind = "spherical_cap"\n')
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err, "broken.toml", "not valid TOML", "line 1")


def test_binary_config_file(capsys, tmp_path) -> None:
    path = tmp_path / "bin.toml"
    path.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(128, 256)))
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err, "bin.toml", "not a text file", "not UTF-8")


def test_directory_as_config_file(capsys, tmp_path) -> None:
    folder = tmp_path / "configs.toml"
    folder.mkdir()
    code, _, err = run(capsys, "check", str(folder))
    assert_user_error(code, err, "configs.toml", "is a directory")
    assert "does not exist" not in err


def test_config_with_a_byte_order_mark_is_read(tmp_path) -> None:
    plain = write_config(tmp_path, {}, "plain.toml")
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    assert load_config(bom).resolved == load_config(plain).resolved


def test_check_reads_a_config_with_a_byte_order_mark(capsys, tmp_path) -> None:
    path = tmp_path / "bom.toml"
    path.write_bytes("\ufeff".encode() + to_toml(BASE).encode())
    code, out, err = run(capsys, "check", str(path))
    assert code == 0, err
    assert "immersion" in out


# --------------------------------------------------------------------------- keys and types


@pytest.mark.parametrize(
    ("changes", "needles"),
    [
        ({"material.epsilom": 0.001}, ("unknown key 'epsilom' in [material]", "'epsilon'")),
        ({"domain.hh": 0.1}, ("unknown key 'hh' in [domain]", "did you mean 'h'")),
        ({"penalty.exponnent": 2.0}, ("unknown key 'exponnent'", "did you mean 'exponent'")),
        ({"load.zzz": 1}, ("unknown key 'zzz' in [load]", "valid keys: p, parameters")),
        ({"surface.kind": "sphere"}, ("surface.kind = 'sphere'", "did you mean 'spherical_cap'")),
        ({"materail": {"mu": 1.0}}, ("unknown section [materail]", "did you mean 'material'")),
    ],
)
def test_unknown_or_misspelled_key_gets_a_suggestion(capsys, tmp_path, changes, needles) -> None:
    check_error(capsys, tmp_path, changes, *needles)


def test_missing_required_key(capsys, tmp_path) -> None:
    check_error(capsys, tmp_path, {"material.mu": DELETE}, "missing key 'mu' in [material]")


def test_missing_key_the_kind_needs(capsys, tmp_path) -> None:
    check_error(
        capsys, tmp_path, {"surface.offset": DELETE}, "[surface] needs 'offset'", "spherical_cap"
    )


@pytest.mark.parametrize("section", ["surface", "domain", "material", "load"])
def test_missing_section(capsys, tmp_path, section: str) -> None:
    check_error(capsys, tmp_path, {section: DELETE}, f"missing section [{section}]")


@pytest.mark.parametrize(
    ("changes", "needles"),
    [
        ({"material.mu": "abc"}, ("material.mu must be a number", "'abc'")),
        ({"material.epsilon": True}, ("material.epsilon must be a number", "True")),
        ({"domain.refinements": 1.5}, ("domain.refinements must be an integer", "1.5")),
        ({"output": {"figures": "yes"}}, ("output.figures must be true or false", "'yes'")),
        ({"obstacle": {"q": [0.0, 1.0]}}, ("obstacle.q must be a list of 3 values",)),
        ({"load.p": ["0", "0", ["-1"]]}, ("load.p[3] must be a string expression",)),
        ({"load.parameters": {"ell": "big"}}, ("load.parameters.ell must be a number",)),
        ({"domain": {"kind": "polygon", "h": 0.1, "vertices": [1, 2]}}, ("domain.vertices",)),
        ({"material": 0.001}, ("[material] must be a table",)),
        ({"penalty.exponent": float("nan")}, ("penalty.exponent must be finite",)),
    ],
)
def test_wrong_type(capsys, tmp_path, changes, needles) -> None:
    check_error(capsys, tmp_path, changes, *needles)


def test_choice_message_bounds_the_value(tmp_path) -> None:
    from shellobstacle.config.loader import ConfigError

    path = write_config(tmp_path, {"solver.method": "x" * 10_000})
    with pytest.raises(ConfigError, match=r"\(10000 characters\)") as info:
        load_config(path)
    assert len(str(info.value)) < 600


# --------------------------------------------------------------------------- values out of range


@pytest.mark.parametrize(
    ("changes", "needles"),
    [
        ({"material.epsilon": 0.0}, ("material.epsilon must be > 0", "got 0.0")),
        ({"material.epsilon": -1e-3}, ("material.epsilon must be > 0", "got -0.001")),
        ({"material.mu": 0.0}, ("material.mu must be > 0",)),
        ({"material.mu": -0.012}, ("material.mu must be > 0",)),
        ({"material.lambda": -0.4}, ("material.lambda must be >= 0", "got -0.4")),
        ({"domain.h": 0.0}, ("domain.h must be > 0",)),
        ({"domain.h": -0.1}, ("domain.h must be > 0",)),
        ({"domain.h": 2.0}, ("mesh size h=2.0", "exceeds the domain's diameter 1")),
        ({"domain.radius": -0.5}, ("disk radius must be positive",)),
        ({"domain.refinements": -1}, ("domain.refinements must be in 0..8",)),
        ({"discretization": {"degree": 3}}, ("discretization.degree must be 1 or 2", "got 3")),
        ({"discretization": {"quadrature_degree": 0}}, ("discretization.quadrature_degree",)),
        (
            {"penalty": {"kappa": 0.0}},
            ("penalty.kappa must be > 0", "got 0.0"),
        ),
        ({"penalty": {"kappa": -1e-6}}, ("penalty.kappa must be > 0",)),
        ({"penalty": {"exponent": 0.0}}, ("penalty.exponent must be in (0, 20]",)),
        (
            {"penalty": {"kappa": 1e-6, "exponent": 1.5}},
            ("give either penalty.kappa or penalty.exponent, not both",),
        ),
        ({"penalty": {}}, ("[penalty] needs 'kappa'", "'exponent'")),
        ({"obstacle": {"q": [0.0, 0.0, 0.0]}}, ("obstacle.q = (0, 0, 0)", "nonzero normal")),
        ({"solver": {"max_iterations": 0}}, ("solver.max_iterations must be >= 1",)),
        ({"solver": {"xi": -1.0}}, ("solver.xi must be > 0",)),
        ({"load.parameters": {"sin": 1.0}}, ("load.parameters: 'sin' cannot be used",)),
        (
            {"domain": {"kind": "polygon", "h": 0.1, "vertices": [[0, 0], [1, 1], [0, 1], [1, 0]]}},
            ("polygon must be simple",),
        ),
    ],
)
def test_out_of_range(capsys, tmp_path, changes, needles) -> None:
    check_error(capsys, tmp_path, changes, *needles)


# --------------------------------------------------------------------------- meshes


def test_mesh_file_that_does_not_exist(capsys, tmp_path) -> None:
    check_error(
        capsys,
        tmp_path,
        {"domain": {"kind": "file", "path": "missing.msh"}},
        "mesh file",
        str(tmp_path / "missing.msh"),
        "does not exist",
    )


def test_file_domain_without_path(capsys, tmp_path) -> None:
    check_error(capsys, tmp_path, {"domain": {"kind": "file"}}, "kind 'file' needs path")


def _quad_mesh(path: Path) -> None:
    """A gmsh .msh of quadrilaterals (recombined) on a square."""
    import gmsh

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("quads")
        square = gmsh.model.occ.addRectangle(-0.3, -0.3, 0.0, 0.6, 0.6)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [square], 1, name="domain")
        gmsh.option.setNumber("Mesh.RecombineAll", 1)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.15)
        gmsh.model.mesh.generate(2)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def test_mesh_file_of_quadrilaterals(capsys, tmp_path) -> None:
    _quad_mesh(tmp_path / "quads.msh")
    assert (tmp_path / "quads.msh").stat().st_size > 0
    check_error(
        capsys,
        tmp_path,
        {"domain": {"kind": "file", "path": "quads.msh"}},
        "quads.msh",
        "is not made of linear triangles",
        "Quadrilateral",
    )


def test_rectangle_without_h(capsys, tmp_path) -> None:
    """A rectangle is meshed at the size ``h`` (no default, docs/config-reference.md): without
    it the config is refused."""
    corners = [[-0.3, -0.3], [0.3, 0.3]]
    check_error(
        capsys,
        tmp_path,
        {"domain": {"kind": "rectangle", "corners": corners}},
        "[domain] needs 'h' (target mesh size) for kind = 'rectangle'",
    )
