"""Options and sizes checked before any work: every experiment option
(shellobstacle.experiments.options)
and the estimated size of every mesh against the machine (shellobstacle.mesh.resources).

Each mistake ends with exit 2, one line on stderr naming the option, and no result folder.
"""

from __future__ import annotations

from pathlib import Path

from mpi4py import MPI

import gmsh
import pytest

from shellobstacle.cli.main import main
from shellobstacle.config.loader import ConfigError
from shellobstacle.experiments.options import MAX_STEPS, numbers
from shellobstacle.mesh import memory, resources
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.mesh.resources import estimate, mesh_vertices
from shellobstacle.solvers import auto
from shellobstacle.solvers.auto import estimated_linear_solver
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.registry import METHODS

EXAMPLES = Path(__file__).parents[2] / "examples"
PAPER, KOITER = str(EXAMPLES / "paper.toml"), str(EXAMPLES / "cylinder_koiter.toml")
COARSE = ["--set", "domain.h=0.1"]
pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")

BAD_OPTIONS = [
    (["penalty", PAPER, *COARSE, "--step", "0"], "--step must be a positive number"),
    (["penalty", PAPER, *COARSE, "--start", "-1"], "--start must be a positive number"),
    (["penalty", PAPER, *COARSE, "--tol", "nan"], "--tol must be a positive number"),
    (["penalty", PAPER, *COARSE, "--q-max", "0.2"], "--q-max (0.2) must be at least --start"),
    (["penalty", PAPER, *COARSE, "--step", "1e-5"], f"more than {MAX_STEPS} exponents"),
    (["penalty", PAPER, *COARSE, "--quadratures", "gaus"], "'gaus' is not one of"),
    (["penalty", PAPER, *COARSE, "--quadratures", ","], "expected one or more of"),
    (["penalty", PAPER, *COARSE, "--quadratures", "gauss,gauss"], "names a quadrature twice"),
    (["penalty", KOITER, *COARSE, "--quadratures", "vertex"], "use --quadratures gauss"),
    (["mesh", PAPER, *COARSE, "--q", ""], "--q: expected at least one number"),
    (["mesh", PAPER, *COARSE, "--q", "1,-1"], "--q: expected positive numbers, got -1"),
    (["mesh", PAPER, *COARSE, "--q", "inf"], "--q: expected positive numbers, got inf"),
    (["mesh", PAPER, *COARSE, "--q", "a,b"], "--q: expected comma-separated numbers"),
    (["mesh", PAPER, *COARSE, "--refinements", "-1"], "--refinements must be between 0"),
    (["load", KOITER, *COARSE, "--parameter", "foo"], "--parameter 'foo': the load has no"),
    (["load", KOITER, *COARSE, "--parameter", "P", "--values", ""], "--values: expected at"),
    (["solvers", PAPER, "--sizes", "5"], "--sizes: mesh size h=5.0 exceeds"),
    (["solvers", PAPER, "--sizes", "0"], "--sizes: expected positive numbers"),
    (["solvers", PAPER, *COARSE, "--exponent", "0"], "--exponent must be a positive"),
    (["koiter-limit", PAPER, *COARSE, "--epsilons", "0"], "--epsilons: expected positive"),
    (["koiter-limit", PAPER, *COARSE, "--edge-h", "-1"], "--edge-h must be a positive"),
    (["solvers", PAPER, "--sizes", "0.0003"], "--sizes: h = 0.0003 gives about"),
    (["koiter-limit", PAPER, "--edge-h", "1e-5"], "edge_h = 1e-05 gives about"),
    (["mesh", PAPER, "--refinements", "8"], "8 refinement(s) gives about"),
]


@pytest.mark.parametrize(("args", "message"), BAD_OPTIONS, ids=lambda v: str(v)[:40])
def test_bad_experiment_options_are_refused_before_any_work(
    args: list[str], message: str, tmp_path: Path, monkeypatch, capsys
) -> None:
    """Exit 2, one stderr line naming the option and what is wrong, no folder made."""
    monkeypatch.chdir(tmp_path)
    assert main(["experiment", *args, "-q"]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_numbers() -> None:
    assert numbers("1, 2,3 ,", "--x") == [1.0, 2.0, 3.0]
    with pytest.raises(ConfigError, match="at most"):
        numbers(",".join(["1"] * (MAX_STEPS + 1)), "--x")
    with pytest.raises(ConfigError, match="expected finite numbers, got nan"):
        numbers("1,nan", "--x")


@pytest.mark.parametrize(
    "spec",
    [
        DomainSpec("disk", 0.05),
        DomainSpec("disk", 0.05, central_h=0.01, central_radius=0.1),
        DomainSpec("ellipse", 0.04, semi_axes=(0.6, 0.3), edge_h=0.01, edge_width=0.05),
        DomainSpec("polygon", 0.05, vertices=((0, 0), (1, 0), (1, 1), (0.5, 0.4), (0, 1))),
        DomainSpec("rectangle", 0.07, corners=((0, 0), (1, 0.5)), refinements=2),
        DomainSpec("disk", 0.1, refinements=3),
    ],
    ids=["disk", "central", "edge", "polygon", "rectangle", "refined"],
)
def test_estimated_vertices_within_a_factor_of_the_mesh(spec: DomainSpec) -> None:
    """The estimate that guards the memory is within a factor 1.5 of the real count."""
    mesh = create_mesh(spec)
    real = mesh.topology.index_map(0).size_global
    assert real / 1.5 < mesh_vertices(spec) < 1.5 * real, (mesh_vertices(spec), real)


def test_msh_file_node_count(tmp_path: Path) -> None:
    """A file domain's vertices are read from its $Nodes header (4 per refinement)."""
    path = str(tmp_path / "plate.msh")
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.1)
        gmsh.model.add("plate")
        surface = gmsh.model.occ.addRectangle(0, 0, 0, 2, 1)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [surface], 1)
        gmsh.model.mesh.generate(2)
        nodes = len(gmsh.model.mesh.getNodes()[0])
        gmsh.write(path)
    finally:
        gmsh.finalize()
    assert mesh_vertices(DomainSpec("file", path=path)) == nodes
    assert mesh_vertices(DomainSpec("file", path=path, refinements=2)) == 16 * nodes
    assert mesh_vertices(DomainSpec("file", path=str(tmp_path / "none.msh"))) is None


def test_estimates_by_model() -> None:
    """P1: 3 dofs per vertex; P2: 3 per vertex and edge (about 4 nodes per vertex)."""
    spec = DomainSpec("disk", 0.05)
    p1, p2 = estimate(spec, "membrane", 1), estimate(spec, "koiter", 2)
    assert p1.dofs == 3 * p1.vertices and p2.dofs == 12 * p2.vertices
    assert p2.bytes_solve / p2.dofs > p1.bytes_solve / p1.dofs


@pytest.mark.parametrize("command", ["solve", "check", "experiment"])
def test_too_large_for_this_machine_unless_force(
    command: str, tmp_path: Path, monkeypatch, capsys
) -> None:
    """On a machine with 0.25 GiB the paper's coarse mesh is refused (exit 2, one line with the
    estimate and the machine's memory, no folder); --force proceeds."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(memory, "machine_memory", lambda: 0.25 * 2.0**30)
    args = [*([command] if command != "experiment" else ["experiment", "solvers"]), PAPER]
    args += ["-q", "--set", "domain.h=0.1", "--set", "output.paraview=false"]
    args += ["--set", "output.pictures=false"]
    if command == "experiment":
        args += ["--sizes", "0.15"]
    if command == "check":
        monkeypatch.setattr(resources, "BYTES_PER_VERTEX_MESH", 1e6)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "GiB on this machine, more than 80% of its 0.25 GiB" in err and "--force" in err
    assert " GB" not in err
    assert len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []
    assert main([*args, "--force"]) == 0
    if command != "check":
        assert len(list(tmp_path.iterdir())) == 1  # the result folder


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")
def test_a_mesh_too_large_for_the_direct_solver_names_multigrid(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    """The paper's h = 0.0006 (7.7 M dofs) on a 24 GiB machine: refused for the direct solver
    (3.5 kB per dof), with multigrid named as fitting (2.2 kB per dof, measured 2.0–2.1); with
    multigrid the estimate passes, ``"auto"`` (the default) is estimated as the multigrid it
    stands for there (a refined mesh from 1 M dofs), and a method that factorizes as direct.
    Koiter's model likewise (13 and 5 kB per dof), its multigrid named with the refinement it
    needs; its ``"auto"`` is the direct path, refused with multigrid named."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(memory, "machine_memory", lambda: 24 * 2.0**30)
    big = DomainSpec("disk", 0.0006)
    est = resources.estimate(big)
    assert est is not None and 7.0e6 < est.dofs < 8.5e6
    assert NewtonOptions().linear_solver == "auto"
    newton, active_set = METHODS["newton"], METHODS["active-set"]
    assert estimated_linear_solver(newton, None, big, "membrane", 1) == "multigrid"
    assert estimated_linear_solver(newton, None, big, "membrane", 2) == "direct"
    chosen = resources.require_fits(big, linear_solver="multigrid")
    assert chosen == resources.estimate(big, linear_solver="multigrid")
    args = ["solve", PAPER, "-q", "--set", "domain.h=0.0006"]
    args += ["--set", 'solver.linear_solver="direct"']
    assert main(args) == 2
    err = capsys.readouterr().err
    assert 'solver.linear_solver = "multigrid" (about 1' in err, err
    assert len(err.strip().splitlines()) == 1 and list(tmp_path.iterdir()) == []
    options = NewtonOptions(linear_solver="multigrid")
    assert estimated_linear_solver(newton, options, big, "membrane", 1) == "multigrid"
    assert estimated_linear_solver(METHODS["brezis-sibony"], None, big, "membrane", 1) == "direct"
    linear = estimated_linear_solver(active_set, None, big, "membrane", 1)
    with pytest.raises(resources.ResourceError, match="multigrid"):
        resources.require_fits(big, linear_solver=linear)
    # Koiter's model: multigrid fits in its 5 kB per dof, on a refined mesh only (named)
    panel = DomainSpec("rectangle", 1 / 450, corners=((0.0, 0.0), (1.0, 1.0)))
    with pytest.raises(resources.ResourceError, match=r"with domain\.refinements >= 1 \(about"):
        resources.require_fits(panel, "koiter", 2)
    refined = DomainSpec("rectangle", 1 / 225, corners=((0.0, 0.0), (1.0, 1.0)), refinements=1)
    assert estimated_linear_solver(newton, None, refined, "koiter", 2) == "direct"
    with pytest.raises(resources.ResourceError, match=r'"multigrid" \(about'):
        resources.require_fits(refined, "koiter", 2)
    assert resources.require_fits(refined, "koiter", 2, linear_solver="multigrid") is not None


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")
@pytest.mark.parametrize(
    ("from_dofs", "refinements", "expected", "reason"),
    [
        (1.5e6, 1, "direct", "below 1.5 M dofs the direct path is as fast"),
        (1e4, 1, "multigrid", "from 0.01 M dofs on a refined mesh it is the faster"),
        (1e4, 0, "direct", "the mesh has no coarser levels for multigrid"),
    ],
)
def test_auto_takes_multigrid_where_it_is_faster(
    from_dofs: float,
    refinements: int,
    expected: str,
    reason: str,
    tmp_path: Path,
    monkeypatch,
    capsys,
) -> None:
    """``solver.linear_solver = "auto"`` (the default) solves the paper's problem at about 21k
    dofs by the direct path below ``MULTIGRID_FROM_DOFS`` dofs, by multigrid from them
    (lowered here) on a mesh with coarser levels (gmsh's mesh refined once), not on one without;
    summary.json says which and why, and the progress says why when it is multigrid."""
    import json

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(auto, "MULTIGRID_FROM_DOFS", from_dofs)
    h = 0.0115 * 2**refinements
    est = resources.estimate(DomainSpec("disk", h, radius=0.5, refinements=refinements))
    assert est is not None and 2.0e4 < est.dofs < 3.5e4, est
    out = tmp_path / "out"
    args = ["solve", PAPER, "-o", str(out), "--set", f"domain.h={h}"]
    args += ["--set", f"domain.refinements={refinements}"]
    args += ["--set", "output.paraview=false", "--set", "output.pictures=false"]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] and summary["linear_solver"] == expected
    choice = {"asked": "auto", "chosen": expected, "reason": reason}
    assert summary["choices"]["linear_solver"] == choice
    printed = capsys.readouterr()
    said = f'linear solver: multigrid ("auto": {reason}'
    assert (said in printed.out + printed.err) == (expected == "multigrid")
