"""The paper's batches on small meshes: the qualitative results of section 10 (docs/model.md §7)."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest

from shellobstacle.cli.main import main
from shellobstacle.config.loader import load_config
from shellobstacle.experiments.common import transfer
from shellobstacle.experiments.load import PAPER_BATCH3_LOAD, load_study
from shellobstacle.experiments.mesh import mesh_levels, mesh_study
from shellobstacle.experiments.penalty import PenaltyStudyOptions, penalty_study
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.mesh.refinement import refine_uniformly
from shellobstacle.mesh.transfer import Interpolation
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post.norms import DifferenceNorms
from shellobstacle.spec import Discretization, Load

ROOT = Path(__file__).parents[2]
PAPER = ROOT / "examples" / "paper.toml"


@pytest.fixture(scope="module")
def cfg():
    """The paper's configuration."""
    return load_config(PAPER)


@pytest.mark.parametrize("quadrature", ["gauss", "vertex"])
def test_batch1_differences_decrease_to_the_tolerance(cfg, quadrature: str) -> None:
    """Cauchy differences in κ = h^q decrease monotonically and fall below 2e-6."""
    mesh = create_mesh(DomainSpec("disk", h=0.04, radius=0.5))
    disc = Discretization(penalty_quadrature=quadrature)
    study = penalty_study(cfg.shell, mesh, disc, PenaltyStudyOptions(tol=2e-6))
    errors = [r["error_VM"] for r in study.rows]
    assert study.reached_tol and errors[-1] < 2e-6
    assert all(b < a for a, b in itertools.pairwise(errors)), errors
    # at least as fast as Theorem 7.1's √κ
    assert study.decay_rate() >= 0.45


def test_transfer_between_nested_meshes_is_exact() -> None:
    """A coarse P1 function is reproduced exactly on the refined mesh."""
    coarse_mesh = create_mesh(DomainSpec("disk", h=0.15, radius=0.5))
    fine_mesh = refine_uniformly(coarse_mesh)
    V0 = dolfinx.fem.functionspace(coarse_mesh, ("Lagrange", 1, (3,)))
    V1 = dolfinx.fem.functionspace(fine_mesh, ("Lagrange", 1, (3,)))
    u = dolfinx.fem.Function(V0)
    rng = np.random.default_rng(MPI.COMM_WORLD.rank)
    u.x.array[:] = rng.standard_normal(u.x.array.size)
    u.x.scatter_forward()
    w = transfer(u, V1)
    norms = DifferenceNorms(V1)
    # the L² norm of a P1 function is mesh independent when it is the same function
    l2_coarse = DifferenceNorms(V0)(u)["l2"]
    assert norms(w)["l2"] == pytest.approx(l2_coarse, rel=1e-12)
    assert norms(w)["h1"] == pytest.approx(DifferenceNorms(V0)(u)["h1"], rel=1e-12)


@pytest.mark.mpi
def test_interpolation_locates_the_points_once_per_source_space() -> None:
    """:class:`Interpolation` keeps each source space's point location: interpolating again,
    or another function of the same space, locates nothing new and gives what a fresh
    interpolation gives; a new source space is located once; after ``forget`` it is again."""
    coarse_mesh = create_mesh(DomainSpec("disk", h=0.15, radius=0.5))
    fine_mesh = refine_uniformly(coarse_mesh)
    V0 = dolfinx.fem.functionspace(coarse_mesh, ("Lagrange", 1, (3,)))
    V0b = dolfinx.fem.functionspace(coarse_mesh, ("Lagrange", 1, (3,)))
    V1 = dolfinx.fem.functionspace(fine_mesh, ("Lagrange", 1, (3,)))
    rng = np.random.default_rng(MPI.COMM_WORLD.rank)
    functions = []
    for V in (V0, V0, V0b):
        u = dolfinx.fem.Function(V)
        u.x.array[:] = rng.standard_normal(u.x.array.size)
        u.x.scatter_forward()
        functions.append(u)
    into = Interpolation(V1)
    for expected_searches, u in zip((1, 1, 2), functions, strict=True):
        w = into(u)
        assert into.searches == expected_searches
        np.testing.assert_array_equal(w.x.array, transfer(u, V1).x.array)
    into(functions[0])
    assert into.searches == 2
    into.forget()
    into(functions[0])
    assert into.searches == 3


def test_batch2_differences_shrink_with_h(cfg) -> None:
    """On nested meshes with κ = h^q the differences of consecutive solutions decrease."""
    base = create_mesh(DomainSpec("disk", h=0.15, radius=0.5))
    levels = mesh_levels(cfg.shell, base, 2, cfg.discretization)
    study = mesh_study(levels, 1.0)
    errors = [r["error_VM"] for r in study.rows]
    assert len(errors) == 2 and errors[1] < errors[0]
    # another q on the same levels locates no point again
    mesh_study(levels, 0.9)
    assert [level.interpolation.searches for level in levels] == [0, 1, 1]


def test_batch3_contact_area_grows_with_the_load(cfg) -> None:
    """The contact area of the paper's g_ℓ grows with ℓ (measured on the nodes)."""
    shell = dataclasses.replace(cfg.shell, load=Load(("0", "0", PAPER_BATCH3_LOAD), {"ell": 0}))
    mesh = create_mesh(DomainSpec("disk", h=0.08, radius=0.5, central_h=0.006, central_radius=0.1))
    study = load_study(shell, mesh, Discretization(), PenaltySpec(exponent=1.5), [0, 20, 40, 80])
    areas = [r["contact_area_nodal"] for r in study.rows]
    assert study.area_increases(), areas
    # the contact zone is close to the loaded disk |y| < 0.06
    assert 0.7 * np.pi * 0.06**2 < areas[0] < 1.5 * np.pi * 0.06**2


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI test runs serially")
def test_experiment_penalty_cli(tmp_path: Path) -> None:
    """``experiment penalty`` writes the CSVs, the figure and a report."""
    out = tmp_path / "b1"
    args = [
        "experiment",
        "penalty",
        str(PAPER),
        "-o",
        str(out),
        "-q",
        "--set",
        "domain.h=0.06",
        "--quadratures",
        "vertex",
    ]
    assert main(args) == 0
    csv = next(out.glob("batch1_h*_vertex.csv")).read_text().splitlines()
    assert csv[0] == "iteration,q_n,q_m,error_VM,error_H1,reference"
    assert len(csv) >= 3
    assert next(out.glob("batch1_h*.png")).stat().st_size > 10_000
    report = (out / "report.md").read_text()
    assert "Batch 1" in report
    # the last κ's solution in 3D, referenced in the report
    assert (out / "batch1_shell_3d.png").stat().st_size > 20_000
    assert "(batch1_shell_3d.png)" in report


@pytest.mark.mpi
def test_batch1_parallel(cfg) -> None:
    """Batch 1 under MPI gives the serial differences (structured mesh, each rank alone)."""
    out = []
    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):
        mesh = dolfinx.mesh.create_rectangle(comm, [[-0.25, -0.25], [0.25, 0.25]], [16, 16])
        study = penalty_study(
            cfg.shell,
            mesh,
            Discretization(penalty_quadrature="vertex"),
            PenaltyStudyOptions(q_max=2.0),
        )
        out.append([r["error_VM"] for r in study.rows])
    assert np.allclose(out[0], out[1], rtol=1e-8, atol=1e-14)
