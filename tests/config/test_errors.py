"""Every kind of user error: exit code 2 and one line that names the key or quantity.

Each test runs the command line (``shellobstacle.cli.main``) on a config written to
``tmp_path`` (``examples/small.toml`` with a coarse mesh, h = 0.1, and one change) and checks
the message text, not only the exit code: the failing key or quantity must be named, and no
traceback is shown. Internal errors (bugs) exit with 1 and a "please report" line with the
traceback. Checks run on the coarse mesh, so the file takes a few seconds.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

from mpi4py import MPI

import pytest
from cli_helpers import assert_user_error, run

from shellobstacle.config.loader import to_toml

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")

SMALL = Path(__file__).parents[2] / "examples" / "small.toml"
BASE: dict[str, Any] = tomllib.loads(SMALL.read_text())
BASE["domain"]["h"] = 0.1
DELETE = object()


def write_config(folder: Path, changes: dict[str, Any] | None = None, name: str = "c.toml") -> Path:
    """``examples/small.toml`` (h = 0.1) with ``{"section.key": value | DELETE}`` applied."""
    data = copy.deepcopy(BASE)
    for dotted, value in (changes or {}).items():
        section, _, key = dotted.partition(".")
        if not key:  # a whole section
            if value is DELETE:
                del data[section]
            else:
                data[section] = value
        elif value is DELETE:
            del data[section][key]
        else:
            data.setdefault(section, {})[key] = value
    # a "section" that is not a table has to come before the first [table]
    top = [f"{k} = {v!r}" for k, v in data.items() if not isinstance(v, dict)]
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    path = folder / name
    path.write_text("\n".join([*top, to_toml(tables)]))
    return path


def check_error(capsys, tmp_path, changes, *needles, command="check") -> str:
    """Write the changed config, run ``command`` on it and assert a user error."""
    path = write_config(tmp_path, changes)
    extra = ["-o", str(tmp_path / "out"), "-q"] if command == "solve" else []
    code, _, err = run(capsys, command, str(path), *extra)
    assert_user_error(code, err, *needles)
    return err


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


def test_malformed_set_option(capsys) -> None:
    code, _, err = run(capsys, "check", str(SMALL), "--set", "domainh0.1")
    assert_user_error(code, err, "--set 'domainh0.1'", "expected section.key=value")


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


def test_degree_3_through_set(capsys) -> None:
    """The same errors come from ``--set`` overrides, naming the ``--set``, not the file."""
    code, _, err = run(capsys, "check", str(SMALL), "--set", "discretization.degree=3")
    assert_user_error(
        code, err, "--set discretization.degree=3: discretization.degree must be 1 or 2"
    )
    assert "small.toml" not in err


# --------------------------------------------------------------------------- expressions


@pytest.mark.parametrize(
    ("changes", "needles"),
    [
        ({"load.p": ["0", "0", "1 +* y1"]}, ("load.p[3]: cannot parse '1 +* y1'",)),
        ({"load.p": ["0", "(", "0"]}, ("load.p[2]: cannot read '('",)),
        ({"load.p": ["", "0", "0"]}, ("load.p[1]: the expression is empty",)),
        ({"load.p": ["0", "0", "x*y1"]}, ("load.p[3]: unknown name 'x'", "allowed are")),
        ({"load.p": ["0", "0", "y1 < 0"]}, ("load.p[3]", "is not a scalar expression")),
        (
            {"load.p": ["0", "0", "1 if y1 < 0 else 0"]},
            ("load.p[3]", "Python's 'if' is not allowed", "Piecewise"),
        ),
        (
            {"surface": {"kind": "expression", "theta": ["y1", "y2", "0.3 - y1**2 -"]}},
            ("surface.theta[3]: cannot parse",),
        ),
        (
            {"surface": {"kind": "expression", "theta": ["y1", "y2", "0.3 - epsilon*y1**2"]}},
            ("surface.theta[3]: unknown name 'epsilon'",),
        ),
    ],
)
def test_unparsable_expression(capsys, tmp_path, changes, needles) -> None:
    check_error(capsys, tmp_path, changes, *needles)


@pytest.mark.parametrize(
    ("template", "needle"),
    [
        ("__import__('os').system('touch {p}')", "contains characters that are not allowed"),
        ("open('{p}', 'w')", "unknown name 'open'"),
        ("eval(\"open('{p}', 'w')\")", "unknown name 'eval'"),
        ("exp(y1); open('{p}', 'w')", "contains characters that are not allowed"),
        ("y1.__class__", "contains characters that are not allowed"),
        ("lambda: open('{p}', 'w')", "is not allowed"),
    ],
)
def test_unsafe_expression(capsys, tmp_path, monkeypatch, template: str, needle: str) -> None:
    """Code in an expression is refused and never runs."""
    monkeypatch.chdir(tmp_path)  # the payloads would create ./pwned
    target = tmp_path / "pwned"
    text = template.format(p="pwned")
    check_error(capsys, tmp_path, {"load.p": ["0", "0", text]}, "load.p[3]", needle)
    assert not target.exists()


def test_string_literal_payload_never_runs(capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    target = tmp_path / "pwned"
    text = 'exp("_" + "_import_" + "_(\'pathlib\').Path(\'pwned\').touch()")'
    path = write_config(tmp_path, {"load.p": ["0", "0", text]})
    code, _, err = run(capsys, "check", str(path))
    assert not target.exists(), "arbitrary code ran"
    assert_user_error(code, err, "load.p[3]")


def test_piecewise_without_a_default_branch(capsys, tmp_path) -> None:
    """ExpressionError from the translation to UFL (at solve time) is a user error too."""
    err = check_error(
        capsys,
        tmp_path,
        {"load.p": ["0", "0", "Piecewise((-1e-4, r < 0.1))"]},
        "needs a last branch (value, True)",
        command="solve",
    )
    assert "Piecewise" in err


def test_piecewise_without_a_default_branch_names_the_key(capsys, tmp_path) -> None:
    check_error(
        capsys, tmp_path, {"load.p": ["0", "0", "Piecewise((-1e-4, r < 0.1))"]}, "load.p[3]"
    )


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
    path = write_config(
        tmp_path, {"domain": {"kind": "rectangle", "corners": [[-0.3, -0.3], [0.3, 0.3]]}}
    )
    code, _, err = run(capsys, "check", str(path))
    assert code == 0 or "needs 'h'" in err, err


# --------------------------------------------------------------------------- broken assumptions

SADDLE = ["y1", "y2", "0.3 + 0.5*(y1**2 - y2**2)"]
ASSUMPTIONS = {
    "hyperbolic": (
        {"surface": {"kind": "expression", "theta": SADDLE}},
        ("elliptic", "K (Gaussian curvature)", "violates min K > 0", "saddle"),
    ),
    "flat": (
        {"surface": {"kind": "expression", "theta": ["y1", "y2", "0.3"]}},
        ("elliptic", "K (Gaussian curvature) = 0 ", "violates min K > 0"),
    ),
    "crosses the plane": (
        {"surface.offset": 0.95},
        ("inside half-space", "θ·q", "violates min θ·q > 0", "lower surface.offset"),
    ),
    "plane beside the shell": (
        {"obstacle": {"q": [1.0, 0.0, 0.0]}},
        ("normal towards obstacle", "a³·q", "violates min a³·q > 0"),
    ),
    "normal turns away": (
        {
            "surface": {"kind": "elliptic_paraboloid", "height": 1.0, "curvatures": [4.0, 4.0]},
            "obstacle": {"q": [0.6, 0.0, 0.8]},
        },
        ("normal towards obstacle", "a³·q = -0.", "must not turn its back"),
    ),
    "too thick": (
        {"material.epsilon": 2.0},
        ("thin shell", "ε·max|κ_principal| = 2", "violates max ε|κ| < 1", "reduce epsilon"),
    ),
}


#: θ_3 = √(0.1 − |y|²) on the disk |y| < 0.5: a square root of a negative number
NOT_DEFINED = {"surface": {"kind": "expression", "theta": ["y1", "y2", "sqrt(0.1 - r**2)"]}}


@pytest.mark.parametrize("case", list(ASSUMPTIONS))
def test_broken_assumption(capsys, tmp_path, case: str) -> None:
    """``solve`` refuses with the failing check named; ``check`` prints it as FAIL."""
    changes, needles = ASSUMPTIONS[case]
    err = check_error(capsys, tmp_path, changes, *needles, command="solve")
    assert "the data break the theory's assumptions" in err
    code, out, err = run(capsys, "check", str(write_config(tmp_path, changes)))
    assert code == 2 and "Traceback" not in err
    failed = [line for line in out.splitlines() if "FAIL" in line]
    assert any(line.startswith(needles[0]) for line in failed), out


@pytest.mark.parametrize(
    "surface",
    [
        {"kind": "expression", "theta": ["y1", "y2", "1/0"]},
        {"kind": "ellipsoid_cap", "semi_axes": [0.0, 1.0, 1.0], "offset": 0.2},
    ],
)
def test_infinite_surface_is_a_user_error(capsys, tmp_path, surface) -> None:
    path = write_config(tmp_path, {"surface": surface})
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err)


def test_huge_integer_is_a_user_error(capsys) -> None:
    code, _, err = run(capsys, "check", str(SMALL), "--set", "material.epsilon=1" + "0" * 400)
    assert_user_error(code, err, "material.epsilon")


# --------------------------------------------------------------------------- results, solver, bugs


def test_output_folder_with_results(capsys, tmp_path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    code, _, err = run(capsys, "solve", str(write_config(tmp_path)), "-o", str(out), "-q")
    assert_user_error(code, err, str(out), "already holds results", "--overwrite")
    assert (out / "summary.json").read_text() == "{}"


def test_solver_failure_exits_1_without_traceback(capsys, tmp_path) -> None:
    changes = {
        "penalty.continuation": False,
        "solver": {"max_iterations": 1},
        "output": {"paraview": False, "figures": False},
    }
    out = tmp_path / "out"
    code, _, err = run(capsys, "solve", str(write_config(tmp_path, changes)), "-o", str(out))
    assert code == 1
    assert "Traceback" not in err
    assert "FAILED: Newton did not converge" in err
    assert "no convergence in 1 Newton iterations" in err
    assert (out / "summary.json").is_file()


def test_internal_error_exits_1_with_traceback(capsys, monkeypatch) -> None:
    """A bug (any other exception) prints the traceback and asks for a report."""
    import shellobstacle.api

    def broken(_domain):
        raise RuntimeError("simulated bug in make_mesh")

    monkeypatch.setattr(shellobstacle.api, "make_mesh", broken)
    code, _, err = run(capsys, "check", str(SMALL))
    assert code == 1
    assert "Traceback (most recent call last)" in err
    assert "RuntimeError: simulated bug in make_mesh" in err
    assert "internal error (a bug): please report it" in err


# --------------------------------------------------------------------------- failed writes


def test_failed_figure_keeps_the_previous_png(tmp_path, monkeypatch) -> None:
    """A figure is written to a temporary file and renamed: a failure leaves the old file."""
    import matplotlib.pyplot as plt

    from shellobstacle.post.plotting import save_atomically

    path = tmp_path / "cross_section.png"
    path.write_bytes(b"previous figure")
    fig = plt.figure()

    def broken_savefig(fname, **kwargs):
        Path(fname).write_bytes(b"half a PNG")
        raise OSError("disk full")

    monkeypatch.setattr(fig, "savefig", broken_savefig)
    with pytest.raises(OSError, match="disk full"):
        save_atomically(fig, path, dpi=10)
    plt.close(fig)
    assert path.read_bytes() == b"previous figure"
    assert list(tmp_path.iterdir()) == [path]


class _FakeVTXWriter:
    """Stands in for dolfinx.io.VTXWriter: writes a folder, optionally fails half-way."""

    fail = False

    def __init__(self, comm, filename, functions, engine):
        self.folder = Path(filename)
        self.folder.mkdir()
        (self.folder / "md.idx").write_text("new")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def write(self, t):
        if self.fail:
            raise RuntimeError("ADIOS2 failed")
        (self.folder / "data.0").write_text("new")


@pytest.mark.parametrize("fail", [False, True])
def test_vtx_folder_is_replaced_atomically(tmp_path, monkeypatch, fail: bool) -> None:
    """A .bp folder appears complete or not at all; an old one survives a failed write."""
    import dolfinx.io

    from shellobstacle.io import paraview as output

    monkeypatch.setattr(_FakeVTXWriter, "fail", fail)
    monkeypatch.setattr(dolfinx.io, "VTXWriter", _FakeVTXWriter)
    path = tmp_path / "surface.bp"
    path.mkdir()
    (path / "md.idx").write_text("old")
    (path / "stale.0").write_text("old")
    if fail:
        with pytest.raises(RuntimeError, match="ADIOS2 failed"):
            output._write(MPI.COMM_WORLD, path, [])
        assert sorted(p.name for p in path.iterdir()) == ["md.idx", "stale.0"]
    else:
        assert output._write(MPI.COMM_WORLD, path, []) == path
        assert sorted(p.name for p in path.iterdir()) == ["data.0", "md.idx"]
        assert (path / "md.idx").read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["surface.bp"]


def test_zero_load_solves_to_zero(capsys, tmp_path) -> None:
    changes = {"load.p": ["0", "0", "0"], "output": {"paraview": False, "figures": False}}
    out = tmp_path / "out"
    code, _, err = run(capsys, "solve", str(write_config(tmp_path, changes)), "-o", str(out))
    assert code == 0, err
    assert "Traceback" not in err


@pytest.mark.parametrize("case", ["hyperbolic", "crosses the plane", "not defined"])
def test_checks_in_chunks_find_the_same_extremes(tmp_path, monkeypatch, case: str) -> None:
    """The checks evaluate the geometry a chunk of points at a time: chunks of 7 points give
    the table of one chunk for the whole mesh (values, points, verdicts), and the same
    point where θ is not defined."""
    from shellobstacle.api import make_mesh
    from shellobstacle.checks import assumptions as checks
    from shellobstacle.config.loader import load_config
    from shellobstacle.geometry.expressions import ExpressionError

    changes = NOT_DEFINED if case == "not defined" else ASSUMPTIONS[case][0]
    cfg = load_config(write_config(tmp_path, changes))
    mesh = make_mesh(cfg.domain)
    assert len(checks.sample_points(mesh)) > 50 * 7

    def table() -> list[tuple] | str:  # repr: NaN equals NaN
        try:
            return [(c.name, repr(c.value), repr(c.where), c.passed) for c in
                    checks.check_assumptions(cfg.shell, mesh)]  # fmt: skip
        except ExpressionError as err:
            return str(err)

    whole = table()
    monkeypatch.setattr(checks, "CHUNK", 7)
    assert table() == whole
    if case == "not defined":
        assert isinstance(whole, str) and "θ_3 = nan at y = (" in whole
    else:
        assert not all(passed for *_, passed in whole)
