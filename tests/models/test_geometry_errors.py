"""Surfaces the theory refuses: ``solve`` refuses with the failing check named and its fix,
``check`` prints it as FAIL (the assumptions of docs/model.md: elliptic, inside the
half-space, the normal towards the obstacle, thin), and θ not defined, not finite or not
smooth on ω̄ is one line with exit code 2 naming where (also on 2 ranks: one message, from
rank 0, exit 2 on every rank). The checks evaluate a chunk of points at a time alike.
"""

from __future__ import annotations

import re

from mpi4py import MPI

import numpy as np
import pytest
from cli_helpers import (
    EXAMPLES,
    assert_user_error,
    changed,
    check_error,
    check_row,
    run,
    serial,
    write_config,
)

from shellobstacle.config.loader import parse_config
from shellobstacle.geometry.expressions import ExpressionError, y1, y2
from shellobstacle.geometry.surface import Surface
from shellobstacle.geometry.translation import to_ufl

COMM = MPI.COMM_WORLD

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


@serial
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


def test_a_membrane_on_a_surface_that_is_not_elliptic_names_koiters_model(capsys) -> None:
    sets = ["--set", "domain.h=0.1", "--set", 'model.kind="membrane"']
    code, out, err = run(capsys, "check", str(EXAMPLES / "cylinder_koiter.toml"), *sets)
    assert code == 2 and "FAIL" in check_row(out, "elliptic"), err
    assert "elliptic: the membrane model needs an elliptic surface" in out
    assert 'set model.kind = "koiter"' in out, out


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


# --------------------------------------------------------------------------- θ not smooth on ω̄


#: θ_3 = √(0.1 − |y|²) on the disk |y| < 0.5: a square root of a negative number
UNDEFINED = {"kind": "expression", "theta": ["y1", "y2", "sqrt(0.1 - r**2)"]}


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
    path = write_config(tmp_path, {"surface": surface})
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
    _, _, err = run(capsys, "check", str(write_config(tmp_path, {"surface": UNDEFINED})))
    y = [float(v) for v in re.search(r"at y = \(([^,]+), ([^)]+)\)", err).groups()]
    assert 0.1 < y[0] ** 2 + y[1] ** 2 < 0.5**2
    assert y[0] ** 2 + y[1] ** 2 < 0.1 + 4 * 0.1 * 0.1  # within a cell or two of |y|² = 0.1


@pytest.mark.mpi
def test_theta_undefined_on_two_ranks(capsys, tmp_path) -> None:
    """On every rank the exit code is 2; only rank 0 prints, one line."""
    folder = COMM.bcast(tmp_path if COMM.rank == 0 else None, root=0)
    path = folder / "undefined.toml"
    if COMM.rank == 0:
        write_config(folder, {"surface": UNDEFINED}, path.name)
    COMM.barrier()
    code, _, err = run(capsys, "check", str(path))
    codes = COMM.allgather(code)
    errs = COMM.allgather(err)
    assert codes == [2] * COMM.size
    assert_user_error(codes[0], errs[0], "surface.theta: θ is not smooth on ω̄: θ_3 = nan")
    assert all(e == "" for e in errs[1:]), errs


@serial
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


#: θ_3 with a kink: its second derivative holds DiracDelta(y1), which NumPy's printer names
#: but NumPy has not (a NameError in SymPy's generated code, "internal error (a bug)" before)
KINKED = ["y1", "y2", "0.3 - y1**2/2 - y2**2/2 + 0.01*Abs(y1)"]


@serial
def test_theta_with_a_kink_is_a_user_error(capsys, tmp_path) -> None:
    path = write_config(tmp_path, {"surface": {"kind": "expression", "theta": KINKED}})
    code, _, err = run(capsys, "check", str(path))
    assert_user_error(code, err, "surface.theta", "DiracDelta(y1)", "smooth")


@serial
@pytest.mark.parametrize(
    "theta3",
    [
        "0.3 - Abs(y1)",  # DiracDelta in ∂²θ
        "0.3 - Max(y1, y2)**2",  # Heaviside, then DiracDelta
        "(Abs((y1)**0.5))**2",  # an unevaluated Derivative (NumPy's printer refuses it)
    ],
)
def test_derivatives_without_a_value_raise_expression_error(theta3: str) -> None:
    surface = Surface.from_strings(["y1", "y2", theta3])
    pts = np.array([[0.1, 0.2], [-0.3, 0.1]])
    with pytest.raises(ExpressionError, match=r"surface\.theta"):
        surface.geometry_numpy(pts)
    with pytest.raises(ExpressionError, match=r"surface\.theta"):
        to_ufl(surface.d2[0][0][2], {y1: 0.0, y2: 0.0})


# --------------------------------------------------------------------------- chunks


@serial
@pytest.mark.parametrize("case", ["hyperbolic", "crosses the plane", "not defined"])
def test_checks_in_chunks_find_the_same_extremes(tmp_path, monkeypatch, case: str) -> None:
    """The checks evaluate the geometry a chunk of points at a time: chunks of 7 points give
    the table of one chunk for the whole mesh (values, points, verdicts), and the same
    point where θ is not defined."""
    from shellobstacle.api import make_mesh
    from shellobstacle.checks import assumptions as checks
    from shellobstacle.config.loader import load_config
    from shellobstacle.geometry.expressions import ExpressionError

    changes = {"surface": UNDEFINED} if case == "not defined" else ASSUMPTIONS[case][0]
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
