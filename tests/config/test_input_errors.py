"""Input the loader and the checks refuse in one line, and the API refusing it alike.

Each case runs the command line (``shellobstacle.cli.main``) on ``examples/small.toml`` with a
coarse mesh (h = 0.1) and one change, and asserts exit code 2 and one
``shellobstacle: error:`` line without a traceback that names the key and the problem: a
config file that is not text or is a directory, expressions that overflow or are not finite
on ω̄, θ undefined on part of ω (also on 2 ranks: one message, from rank 0, exit 2 on every
rank), ``--set`` replacing κ's form, reaching into tables and naming itself. The Python API's
dataclasses raise the config's messages. The remaining cases check what the user reads:
the load experiment's report on a user's shell, Brezis–Sibony's count of κ, the exact solver
with the defaults, and the examples and README against the files they describe.
"""

from __future__ import annotations

import copy
import json
import re
import tomllib
from pathlib import Path
from typing import Any

from mpi4py import MPI

import pytest
from cli_helpers import assert_user_error, run

from shellobstacle.cli.main import main
from shellobstacle.config.loader import ConfigError, load_config, parse_config, to_toml
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.spec import Discretization, Shell

COMM = MPI.COMM_WORLD
serial = pytest.mark.skipif(COMM.size > 1, reason="CLI tests run serially")
ROOT = Path(__file__).parents[2]
EXAMPLES = ROOT / "examples"
SMALL = EXAMPLES / "small.toml"
BASE: dict[str, Any] = tomllib.loads(SMALL.read_text())
BASE["domain"]["h"] = 0.1
#: θ_3 = √(0.1 − |y|²) on the disk |y| < 0.5: a square root of a negative number
UNDEFINED = {"kind": "expression", "theta": ["y1", "y2", "sqrt(0.1 - r**2)"]}


def changed(changes: dict[str, Any]) -> dict[str, Any]:
    """``BASE`` with ``{"section.key": value}`` or ``{"section": table}`` applied."""
    data = copy.deepcopy(BASE)
    for dotted, value in changes.items():
        section, _, key = dotted.partition(".")
        if key:
            data.setdefault(section, {})[key] = value
        else:
            data[section] = value
    return data


def write(folder: Path, changes: dict[str, Any] | None = None, name: str = "c.toml") -> Path:
    path = folder / name
    path.write_text(to_toml(changed(changes or {})))
    return path


# --------------------------------------------------------------------------- 1. the file


@serial
def test_binary_config_file(capsys, tmp_path) -> None:
    path = tmp_path / "bin.toml"
    path.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(128, 256)))
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err, "bin.toml", "not a text file", "not UTF-8")


@serial
def test_directory_as_config_file(capsys, tmp_path) -> None:
    folder = tmp_path / "configs.toml"
    folder.mkdir()
    code, _, err = run(capsys, "check", str(folder))
    assert_user_error(code, err, "configs.toml", "is a directory")
    assert "does not exist" not in err


# --------------------------------------------------------------------------- 2. overflow


@serial
@pytest.mark.parametrize(
    ("changes", "needles"),
    [
        ({"load.p": ["0", "0", "exp(1000)"]}, ("load.p[3]", "exp(1000)", "overflows")),
        ({"load.p": ["0", "0", "1e400*y1"]}, ("load.p[3]", "overflows double precision")),
        (
            {"surface": {"kind": "expression", "theta": ["y1", "y2", "exp(1000) - r**2"]}},
            ("surface.theta[3]", "exp(1000)", "overflows"),
        ),
        ({"load.p": ["0", "0", "exp(2000*y1)"]}, ("load.p[3]: p^3 = inf at y = (",)),
    ],
)
@pytest.mark.parametrize("command", ["check", "solve"])
def test_expression_that_overflows(capsys, tmp_path, changes, needles, command) -> None:
    extra = ["-o", str(tmp_path / "out"), "-q"] if command == "solve" else []
    code, _, err = run(capsys, command, str(write(tmp_path, changes)), *extra)
    assert_user_error(code, err, *needles)


# --------------------------------------------------------------------------- 3. --set


@serial
def test_set_kappa_replaces_the_files_exponent(capsys) -> None:
    paper = EXAMPLES / "paper.toml"
    assert "exponent" in tomllib.loads(paper.read_text())["penalty"]
    cfg = load_config(paper, ["penalty.kappa=1e-3"])
    assert (cfg.penalty.kappa, cfg.penalty.exponent) == (1e-3, None)
    assert cfg.resolved["penalty"].get("exponent") is None


@serial
def test_set_exponent_replaces_the_files_kappa(tmp_path) -> None:
    path = write(tmp_path, {"penalty": {"kappa": 1e-6}})
    cfg = load_config(path, ["penalty.exponent=1.5"])
    assert (cfg.penalty.kappa, cfg.penalty.exponent) == (None, 1.5)


@serial
def test_set_both_kappa_and_exponent_names_both(capsys) -> None:
    args = ("--set", "penalty.kappa=1e-3", "--set", "penalty.exponent=1.5")
    code, _, err = run(capsys, "check", str(SMALL), *args)
    assert_user_error(
        code,
        err,
        "--set penalty.kappa=1e-3, --set penalty.exponent=1.5: give either penalty.kappa or "
        "penalty.exponent, not both",
    )


@serial
def test_set_reaches_into_a_table() -> None:
    cfg = load_config(EXAMPLES / "paraboloid.toml", ["load.parameters.ell=3"])
    assert cfg.shell.load.parameters["ell"] == 3.0
    cfg = load_config(SMALL, ["load.parameters.ell=3"])  # a table the file does not have
    assert cfg.shell.load.parameters == {"ell": 3.0}


@serial
@pytest.mark.parametrize(
    ("item", "needles"),
    [
        ("load.foo=1", ("--set load.foo=1: unknown key 'foo' in [load]",)),
        ("material.mu=abc", ("--set material.mu=abc: material.mu must be a number",)),
        ("penalty.exponent=0", ("--set penalty.exponent=0: penalty.exponent must be in (0, 20]",)),
        ("load.parameters.ell=big", ("--set load.parameters.ell=big: load.parameters.ell",)),
        ("load.p.x=1", ("--set load.p.x=1: load.p is not a table",)),
        ("materail.mu=1", ("--set materail.mu=1: unknown section [materail]",)),
    ],
)
def test_set_errors_name_the_set(capsys, item: str, needles: tuple[str, ...]) -> None:
    code, _, err = run(capsys, "check", str(SMALL), "--set", item)
    assert_user_error(code, err, *needles)
    assert "small.toml" not in err


# --------------------------------------------------------------------------- 4. the API


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


# --------------------------------------------------------------------------- 5. θ undefined


@serial
@pytest.mark.parametrize(
    ("surface", "needles"),
    [
        (UNDEFINED, ("surface.theta: θ is not smooth on ω̄: θ_3 = nan at y = (", "shrink")),
        (
            {"kind": "spherical_cap", "radius": 0.3, "offset": 0.1},
            ("surface.radius:", "= nan at y = (", "raise surface.radius or shrink [domain]"),
        ),
        (
            {"kind": "ellipsoid_cap", "semi_axes": [0.4, 0.6, 1.0], "offset": 0.2},
            ("surface.semi_axes:", "= nan at y = (", "must contain ω̄"),
        ),
    ],
)
def test_theta_undefined_on_part_of_omega(capsys, tmp_path, surface, needles) -> None:
    """``check`` and ``solve`` (also with --force) name where θ is undefined, no table."""
    path = write(tmp_path, {"surface": surface})
    code, out, err = run(capsys, "check", str(path))
    assert_user_error(code, err, *needles)
    assert "nan" not in out and "FAIL" not in out
    for force in ([], ["--force"]):
        out_dir = str(tmp_path / f"out{len(force)}")
        code, _, err = run(capsys, "solve", str(path), "-o", out_dir, "-q", *force)
        assert_user_error(code, err, *needles)


@serial
def test_theta_undefined_point_is_in_the_undefined_region(capsys, tmp_path) -> None:
    """The point named is a point of ω where 0.1 − |y|² < 0, the one nearest the origin."""
    _, _, err = run(capsys, "check", str(write(tmp_path, {"surface": UNDEFINED})))
    y = [float(v) for v in re.search(r"at y = \(([^,]+), ([^)]+)\)", err).groups()]
    assert 0.1 < y[0] ** 2 + y[1] ** 2 < 0.5**2
    assert y[0] ** 2 + y[1] ** 2 < 0.1 + 4 * 0.1 * 0.1  # within a cell or two of |y|² = 0.1


@pytest.mark.mpi
def test_theta_undefined_on_two_ranks(capsys, tmp_path) -> None:
    """On every rank the exit code is 2; only rank 0 prints, one line."""
    folder = COMM.bcast(tmp_path if COMM.rank == 0 else None, root=0)
    path = folder / "undefined.toml"
    if COMM.rank == 0:
        write(folder, {"surface": UNDEFINED}, path.name)
    COMM.barrier()
    code, _, err = run(capsys, "check", str(path))
    codes = COMM.allgather(code)
    errs = COMM.allgather(err)
    assert codes == [2] * COMM.size
    assert_user_error(codes[0], errs[0], "surface.theta: θ is not smooth on ω̄: θ_3 = nan")
    assert all(e == "" for e in errs[1:]), errs


# --------------------------------------------------------------------------- 6. experiment load


def _horizontal_line_labels(monkeypatch) -> list[str]:
    """The labels of every horizontal line matplotlib draws from now on."""
    import matplotlib.axes

    labels: list[str] = []
    draw = matplotlib.axes.Axes.axhline

    def axhline(self, *args, **kwargs):
        labels.append(str(kwargs.get("label", "")))
        return draw(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "axhline", axhline)
    return labels


@serial
def test_load_experiment_describes_the_users_problem(capsys, tmp_path, monkeypatch) -> None:
    """On a user's shell: the user's load, no central refinement, no loaded-disk line."""
    labels = _horizontal_line_labels(monkeypatch)
    out = tmp_path / "load"
    args = ["--set", "domain.h=0.1", "--values", "0,20", "-o", str(out), "-q"]
    args += ["--set", "output.pictures=false"]
    code, _, err = run(capsys, "experiment", "load", str(EXAMPLES / "paraboloid.toml"), *args)
    assert code == 0, err
    report = (out / "report.md").read_text()
    assert "g_ℓ" not in report and "0.295" not in report and "0.06" not in report
    assert "refined near the centre" not in report
    assert "p = (`0`, `0`, `Piecewise((-ell*1e-6" in report
    assert "grow monotonically with ell" in report or "grows with ell" in report
    assert labels and not any("loaded disk" in label for label in labels), labels


def test_load_experiment_keeps_the_papers_wording() -> None:
    from shellobstacle.experiments import load
    from shellobstacle.experiments.reproduce import PAPER_CONFIG

    cfg = load.batch3_config(load_config(PAPER_CONFIG))
    assert load.is_paper_load(cfg.shell.load)
    assert not load.is_paper_load(load_config(EXAMPLES / "paraboloid.toml").shell.load)
    assert load._load_text(cfg.shell.load, True).startswith("g_ℓ = −(2ε/25)")
    spec = DomainSpec("disk", h=0.05, radius=0.5, central_h=0.01, central_radius=0.1)
    assert "refined near the centre" in load._refined_text(spec)
    assert load._refined_text(DomainSpec("disk", h=0.05)) == ""


def test_only_the_papers_load_draws_its_loaded_disk(tmp_path, monkeypatch) -> None:
    from shellobstacle.experiments import load

    labels = _horizontal_line_labels(monkeypatch)
    study = load.LoadStudy("ell", 0.1, 1e-3, 100)
    study.rows = [
        {"ell": v, "contact_area_nodal": a, "contact_area_nodal_projected": a}
        for v, a in [(0.0, 0.01), (10.0, 0.02)]
    ]
    load.plot_contact_area(study, tmp_path / "paper.png", paper_load=True)
    assert any("loaded disk" in label for label in labels)
    labels.clear()
    load.plot_contact_area(study, tmp_path / "user.png", paper_load=False)
    assert not any("loaded disk" in label for label in labels)


# --------------------------------------------------------------------------- 7, 8. solvers


@serial
def test_brezis_sibony_log_states_one_kappa(tmp_path) -> None:
    out = tmp_path / "bs"
    sets = ["solver.method=brezis-sibony", "output.paraview=false", "output.figures=false"]
    args = ["solve", str(write(tmp_path)), "-o", str(out), "-q"]
    assert main(args + [a for s in sets for a in ("--set", s)]) == 0
    log = (out / "log.txt").read_text()
    assert "solving for 1 value of κ" in log and "by Brezis–Sibony" in log
    assert "value(s) of κ" not in log
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["continuation"]) == 1


@serial
def test_active_set_with_the_defaults(tmp_path) -> None:
    """No discretization.penalty_quadrature needed: the exact solver's constraint is nodal."""
    out = tmp_path / "exact"
    sets = ["solver.method=active-set", "output.paraview=false", "output.figures=false"]
    args = ["solve", str(write(tmp_path)), "-o", str(out), "-q"]
    assert main(args + [a for s in sets for a in ("--set", s)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "active-set" and summary["kappa"] == 0.0
    assert max(summary["continuation"][0]["kkt_relative"].values()) < 1e-10
    resolved = tomllib.loads((out / "config.toml").read_text())
    assert resolved["discretization"]["penalty_quadrature"] == "vertex"


def test_written_config_reads_back_to_the_resolved_config(tmp_path) -> None:
    """A result folder's config.toml (``to_toml`` of the resolved config) reads back to it,
    a multi-line expression and a table of parameters included."""
    p = ["0", "0", "Piecewise((-P*(1 - r**2),\n           r < 0.06), (0, True))"]
    cfg = load_config(write(tmp_path, {"load.p": p, "load.parameters": {"P": 0.003}}))
    assert "\n" in cfg.resolved["load"]["p"][2]
    saved = tmp_path / "config.toml"
    saved.write_text(to_toml(cfg.resolved))
    assert load_config(saved).resolved == cfg.resolved


# --------------------------------------------------------------------------- 9. docs, examples


def test_examples_are_files_and_paper_toml_is_the_packaged_one() -> None:
    from shellobstacle.experiments.reproduce import PAPER_CONFIG

    assert [p.name for p in EXAMPLES.iterdir() if p.is_symlink()] == []
    assert (EXAMPLES / "paper.toml").read_bytes() == PAPER_CONFIG.read_bytes()


def test_readme_config_matches_examples_paper_toml() -> None:
    """Every key of the README's config block has the value of ``examples/paper.toml``."""
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"```toml\n(.*?)```", readme, re.S).group(1)
    shown = tomllib.loads(block)
    paper = tomllib.loads((EXAMPLES / "paper.toml").read_text())
    for section, keys in shown.items():
        for key, value in keys.items():
            assert paper[section][key] == value, f"README [{section}] {key} = {value!r}"


def test_readme_paraview_field_names_are_the_written_ones() -> None:
    readme = (ROOT / "README.md").read_text()
    paragraph = readme[readme.index("**ParaView**") :].split("\n\n")[0]
    source = (ROOT / "src" / "shellobstacle" / "post" / "contact.py").read_text()
    for name in ("gap", "contact", "U"):
        assert f"`{name}`" in paragraph
        assert f'name="{name}"' in source


@serial
@pytest.mark.parametrize(("q3", "way"), [(1.0, "lower"), (-1.0, "raise")])
def test_offset_hint_points_the_way_that_fixes_it(tmp_path, q3: float, way: str) -> None:
    """θ_3 = √(R² − |y|²) − offset: θ·q falls by q_3 per unit of offset. Following the hint
    (by 0.2) turns the failing half-space check into a passing one."""
    from shellobstacle.api import make_mesh
    from shellobstacle.checks.assumptions import check_assumptions

    offset = 0.95 if q3 > 0 else 0.9  # 0.866 − offset ≤ θ_3 ≤ 1 − offset: partly outside

    def half_space(offset: float):
        cfg = parse_config(changed({"surface.offset": offset, "obstacle": {"q": [0.0, 0.0, q3]}}))
        row = {c.name: c for c in check_assumptions(cfg.shell, make_mesh(cfg.domain))}
        return row["inside half-space"]

    before = half_space(offset)
    assert not before.passed and f"{way} surface.offset" in before.hint
    after = half_space(offset - 0.2 if way == "lower" else offset + 0.2)
    assert after.passed
