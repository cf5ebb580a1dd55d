"""The adaptive loop (shellobstacle.adapt.loop) on the paper's problem, small meshes."""

from __future__ import annotations

import dataclasses
from pathlib import Path

# isort: split
import itertools

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest

from shellobstacle.adapt.loop import adaptive_solve
from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.config.loader import load_config
from shellobstacle.experiments.common import transfer
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.measures import mesh_size, mesh_size_min
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.kappa import kappa_on_mesh, local_kappa_scale
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post.norms import DifferenceNorms

ROOT = Path(__file__).parents[2]
PAPER = ROOT / "examples" / "paper.toml"
COMM = MPI.COMM_WORLD


@pytest.fixture(scope="module")
def cfg():
    return load_config(PAPER)


def _mesh(comm: MPI.Comm = COMM, h: float = 0.08) -> dolfinx.mesh.Mesh:
    return create_mesh(DomainSpec("disk", h=h, radius=0.5), comm, ghosted=True)


def _run(cfg, method: str, levels: int, mesh=None, **kw):
    kept = []

    def keep(level, problem):
        z = dolfinx.fem.Function(problem.V)
        z.x.array[:] = problem.zeta.x.array
        kept.append(z)

    options = AdaptOptions(max_levels=levels, **kw)
    penalty = None if method == "active-set" else cfg.penalty
    result = adaptive_solve(
        cfg.shell, mesh or _mesh(), cfg.discretization, penalty, options, cfg.solver, method,
        on_level=keep,
    )  # fmt: skip
    assert result.converged, result.error
    return result, kept


@pytest.mark.parametrize("method", ["active-set", "newton"])
def test_the_loop_reduces_the_error(cfg, method: str) -> None:
    """Five levels, errors against the solution two levels further (its mesh refines all):
    the V_M error and η fall at every level, and each level starts from the last one's
    solution (the exact solver settles from the warm start in a few steps)."""
    result, kept = _run(cfg, method, 6)
    reference = kept[-1]
    V = reference.function_space
    norms = DifferenceNorms(V, 4)
    errors = [norms(transfer(z, V), reference)["vm"] for z in kept[:5]]
    etas = [lv.eta for lv in result.levels[:5]]
    assert all(b < a for a, b in itertools.pairwise(errors)), errors
    assert all(b < a for a, b in itertools.pairwise(etas)), etas
    dofs = [lv.dofs for lv in result.levels]
    assert all(b > a for a, b in itertools.pairwise(dofs))
    assert result.reason == "max_levels = 6 reached"
    if method == "active-set":
        assert all(lv.iterations <= 4 for lv in result.levels[1:])


def test_targets_stop_the_loop(cfg) -> None:
    result, _ = _run(cfg, "active-set", 30, target_dofs=3000)
    assert result.levels[-1].dofs >= 3000 > result.levels[-2].dofs
    eta = result.levels[2].eta
    result, _ = _run(cfg, "active-set", 30, target_error=eta)
    assert len(result.levels) == 3 and "target_error" in result.reason


def test_kappa_follows_the_mesh(cfg) -> None:
    """'largest': κ = h_max^q; 'finest': h_min^q; 'local': h_T^q on each cell, as the DG0
    factor (h_T/h_max)^q of the Constant h_max^q."""
    q = cfg.penalty.exponent
    for mode in ("largest", "finest", "local"):
        result, _ = _run(cfg, "newton", 2, kappa=mode)
        last = result.levels[-1]
        if mode == "largest":
            assert last.kappa_min == last.kappa_max == pytest.approx(last.h_max**q)
        elif mode == "finest":
            assert last.kappa_min == last.kappa_max == pytest.approx(last.h_min**q)
        else:
            assert last.kappa_min == pytest.approx(last.h_min**q)
            assert last.kappa_max == pytest.approx(last.h_max**q)
            problem = result.problem
            rho = problem.kappa_scale.x.array
            assert rho.max() == pytest.approx(1.0) and rho.min() < 0.5
            mesh = problem.mesh
            cells = np.arange(mesh.topology.index_map(2).size_local, dtype=np.int32)
            h = mesh.h(2, cells)
            kappa_T = (
                problem.kappa.value * rho[problem.kappa_scale.function_space.dofmap.list[cells, 0]]
            )
            assert np.allclose(kappa_T, h**q, rtol=1e-12)


def test_kappa_on_a_mesh_by_mode() -> None:
    """One place for κ on a mesh: the ladder at h_max ('largest', 'local') or h_min
    ('finest'), ρ only for 'local', a fixed κ on every mesh, [0] without a penalty."""
    mesh = _mesh(h=0.1)
    h_max, h_min = mesh_size(mesh), mesh_size_min(mesh)
    assert h_min < h_max
    spec = PenaltySpec(exponent=1.5)
    largest = kappa_on_mesh(spec, mesh)
    assert (largest.h, largest.ladder, largest.scale) == (h_max, spec.ladder(h_max), None)
    assert largest.kappa_min == largest.kappa_max == h_max**1.5
    finest = kappa_on_mesh(spec, mesh, "finest")
    assert (finest.h, finest.ladder, finest.scale) == (h_min, spec.ladder(h_min), None)
    local = kappa_on_mesh(spec, mesh, "local")
    assert (local.h, local.ladder) == (h_max, spec.ladder(h_max))
    assert (local.kappa_min, local.kappa_max) == (h_min**1.5, h_max**1.5)
    assert local.scale is not None and local.scale.x.array.max() <= 1.0
    fixed = kappa_on_mesh(PenaltySpec(kappa=1e-4, continuation=False), mesh, "local")
    assert (fixed.ladder, fixed.scale, fixed.kappa_min) == ([1e-4], None, 1e-4)
    assert kappa_on_mesh(None, mesh, "finest").ladder == [0.0]
    with pytest.raises(ValueError, match="smallest"):
        kappa_on_mesh(spec, mesh, "smallest")


def test_a_unit_kappa_scale_changes_nothing(cfg) -> None:
    """The cellwise factor enters only the penalty: with ρ = 1 the residual is that of the
    Constant κ (the forms without a factor are those of every other solve)."""
    mesh = _mesh(h=0.1)
    h = dolfinx.fem.functionspace(mesh, ("DG", 0))
    ones = dolfinx.fem.Function(h)
    ones.x.array[:] = 1.0
    results = []
    for scale in (None, ones, local_kappa_scale(mesh, 1.5, 1.0)):
        problem = PenalizedProblem(cfg.shell, mesh, cfg.discretization, 1e-3, kappa_scale=scale)
        problem.zeta.x.array[2::3] = -0.2  # penetrates: the penalty acts
        vec = dolfinx.fem.assemble_vector(problem.forms["residual"])
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        results.append(vec.array.copy())
    assert np.array_equal(results[0], results[1])
    assert not np.allclose(results[0], results[2])


@pytest.mark.mpi
@pytest.mark.parametrize("method", ["active-set", "newton"])
def test_parallel_equals_serial(cfg, method: str) -> None:
    """On 2 ranks the marked sets, hence the meshes, are the serial ones: the same dofs per
    level, η and the solution's norm to solver tolerance."""
    out = []
    for comm in (COMM, MPI.COMM_SELF):
        result, kept = _run(cfg, method, 5, mesh=_mesh(comm))
        norm = DifferenceNorms(kept[-1].function_space)(kept[-1])["vm"]
        out.append(([lv.dofs for lv in result.levels], [lv.eta for lv in result.levels], norm))
    (dofs, etas, norm), (dofs_s, etas_s, norm_s) = out
    assert dofs == dofs_s
    assert np.allclose(etas, etas_s, rtol=1e-8)
    assert norm == pytest.approx(norm_s, rel=1e-8)


def test_solve_with_adapt_writes_the_levels(cfg, tmp_path) -> None:
    """``solve`` with [adapt] solves the last mesh and records every level."""
    import json

    from shellobstacle.cli.main import main

    out = tmp_path / "run"
    args = ["solve", str(PAPER), "-q", "-o", str(out), "--set", "domain.h=0.08"]
    args += ["--set", "adapt.max_levels=3", "--set", "output.paraview=false"]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    levels = summary["adapt"]["levels"]
    assert [lv["level"] for lv in levels] == [0, 1, 2, 3]
    assert summary["dofs"] == levels[-1]["dofs"] > levels[0]["dofs"]
    assert summary["converged"]
    assert "[adapt]" in (out / "config.toml").read_text()


def test_without_adapt_nothing_changes(cfg) -> None:
    """A config without [adapt] has none in its resolved form (the result folders and the
    compared configs of reproduce are those without the feature)."""
    assert cfg.adapt is None and "adapt" not in cfg.resolved
    with_section = load_config(PAPER, ["adapt.fraction=0.3"])
    assert with_section.adapt == AdaptOptions(fraction=0.3)
    assert dataclasses.replace(with_section, adapt=None).shell == cfg.shell
    assert PenaltySpec(exponent=1.5) == cfg.penalty
