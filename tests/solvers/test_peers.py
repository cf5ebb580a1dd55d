"""The peers of the active-set solver on the nodal problem: PETSc's VI Newton (rsls, ssls) and
the latent-variable proximal point method (proximal Galerkin).

Each solves the same discrete problem (the constraint at the Lagrange nodes, rotated into
bounds) and must reach the active-set solution to its own tolerance, with the same KKT check;
both models (P1 membrane, P2 Koiter), the command line and its config errors, and 2 ranks
against 1.
"""

from __future__ import annotations

# isort: split
import dataclasses
import json
from pathlib import Path

from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
from cli_helpers import assert_user_error, run
from conftest import VERTEX, square
from conftest import make_paper_shell as paper_shell

from shellobstacle.api import nodal_solver
from shellobstacle.config.loader import ConfigError, load_config
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.norms import l2_norm
from shellobstacle.solvers.base import ConvergenceError
from shellobstacle.solvers.vi.options import ProximalGalerkinOptions, SnesVIOptions
from shellobstacle.spec import Discretization

SMALL = Path(__file__).parents[2] / "examples" / "small.toml"
serial = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="CLI tests run serially")

#: (method, options) of every peer variant the tests run
PEERS = [
    ("snes-vi", SnesVIOptions(vi_type="rsls", line_search="l2")),
    ("snes-vi", SnesVIOptions(vi_type="rsls", line_search="bt")),
    ("snes-vi", SnesVIOptions(vi_type="ssls", line_search="l2")),
    ("snes-vi", SnesVIOptions(vi_type="ssls", line_search="bt")),
    ("proximal-galerkin", ProximalGalerkinOptions()),
    ("proximal-galerkin", ProximalGalerkinOptions(linear_system="mixed")),
]


def _id(peer) -> str:
    method, opts = peer
    if method == "snes-vi":
        return f"{opts.vi_type}-{opts.line_search}"
    return f"pg-{opts.linear_system}"


def tolerance(method: str, opts) -> float:
    """The relative distance to the active-set solution each peer's stopping rule allows:
    SNES stops at ``rtol`` on its residual, whose matrix ``D^{-1/2} K' D^{-1/2}`` has a
    condition number of 5.6·10³ on this mesh (the bound on the amplification: 10⁴, with a
    factor 10 of margin); proximal Galerkin stops when the relative increment falls below
    ``tol``, the last steps contracting by 10⁻³ or more."""
    return 1e5 * opts.rtol if method == "snes-vi" else 10 * opts.tol


@pytest.fixture(scope="module")
def exact():
    """The paper's problem on a 24 × 24 square, solved exactly: (problem, ζ, λ, result)."""
    problem = PenalizedProblem(paper_shell(), square(), VERTEX)
    result = nodal_solver(problem, "active-set").solve()
    lam = result.multiplier.x.array.copy()
    return problem, problem.zeta.copy(), lam, result


@pytest.mark.parametrize("peer", PEERS, ids=_id)
def test_peer_reaches_the_active_set_solution(exact, peer) -> None:
    """ζ and λ equal the active-set solution's to the peer's tolerance; KKT to round-off."""
    problem, zeta, lam, reference = exact
    method, opts = peer
    problem.zeta.x.array[:] = 0.0
    result = nodal_solver(problem, method, opts).solve()
    distance = l2_norm(problem.zeta - zeta) / l2_norm(zeta)
    rel = result.relative_kkt
    print(f"\n{_id(peer)}: {result.iterations} solves, distance {distance:.2e}, KKT {rel}")
    assert result.converged
    assert distance <= tolerance(method, opts)
    assert max(rel.values()) <= opts.kkt_rtol
    assert result.active_nodes == reference.active_nodes > 0
    force = reference.scales["force"]
    n = result.multiplier.function_space.dofmap.index_map.size_local
    gap_lam = np.max(np.abs(result.multiplier.x.array[:n] - lam[:n]), initial=0.0)
    assert MPI.COMM_WORLD.allreduce(gap_lam, op=MPI.MAX) <= tolerance(method, opts) * force
    assert result.factor_mb > 0


def test_proximal_galerkin_linear_systems_agree(exact) -> None:
    """The condensed and the mixed Newton step give the same iterates (up to round-off)."""
    problem = exact[0]
    runs = []
    for system in ("condensed", "mixed"):
        problem.zeta.x.array[:] = 0.0
        opts = ProximalGalerkinOptions(linear_system=system)
        r = nodal_solver(problem, "proximal-galerkin", opts).solve()
        runs.append((r, problem.zeta.copy()))
    (a, za), (b, zb) = runs
    assert a.newton_per_step == b.newton_per_step
    assert a.alphas == b.alphas
    assert l2_norm(za - zb) <= 1e-10 * l2_norm(za)


def test_proximal_galerkin_schedule_and_rejection(exact) -> None:
    """The authors' double-exponential α̂, capped; a Newton failure retakes the step with
    α̂/10, after which α̂ grows by at most ``regrowth`` per step; the answer is still exact."""
    alphas = ProximalGalerkinOptions(max_iterations=30).alphas()
    assert alphas[:3] == [1.0, 1.0, pytest.approx(1.5**2.25 - 1)]
    assert alphas[9:] == [1e5] * 21 and np.all(np.diff(alphas[1:]) >= 0)
    problem, zeta, _, _ = exact
    problem.zeta.x.array[:] = 0.0
    opts = ProximalGalerkinOptions(max_newton_iterations=4)
    r = nodal_solver(problem, "proximal-galerkin", opts).solve()
    print(f"\nNewton steps {r.newton_per_step}, alphas {r.alphas}")
    assert r.rejected_steps == 1 and len(r.alphas) == r.proximal_steps + 1
    ratios = np.array(r.alphas[1:]) / np.array(r.alphas[:-1])
    retaken = int(np.flatnonzero(np.isclose(ratios, 0.1))[0])  # the failed attempt
    assert r.newton_per_step[retaken] == opts.max_newton_iterations
    assert np.all(ratios[retaken + 1 :] <= opts.regrowth * (1 + 1e-12))
    assert l2_norm(problem.zeta - zeta) <= 10 * opts.tol * l2_norm(zeta)


@pytest.mark.parametrize(
    ("method", "opts", "match", "moved"),
    [
        ("snes-vi", SnesVIOptions(max_iterations=1), "DIVERGED_MAX_IT", True),
        ("proximal-galerkin", ProximalGalerkinOptions(max_iterations=2), "2 proximal", True),
        (
            "proximal-galerkin",
            ProximalGalerkinOptions(max_newton_iterations=1, max_rejections=0),
            "Newton did not converge in proximal step 1 after 1 reductions",
            False,
        ),
    ],
)
def test_nonconvergence_raises_with_the_iterate(exact, method, opts, match, moved) -> None:
    """A peer that stops short raises ConvergenceError with its result, leaving its last
    (for proximal Galerkin: last accepted) iterate in ``problem.zeta``."""
    problem = exact[0]
    problem.zeta.x.array[:] = 0.0
    with pytest.raises(ConvergenceError, match=match) as info:
        nodal_solver(problem, method, opts).solve()
    result = info.value.result
    assert not result.converged and result.iterations >= 1
    assert (l2_norm(problem.zeta) > 0) == moved


def test_ssls_leaves_the_stiffness_alone(exact) -> None:
    """ssls modifies its Jacobian in place: two solves in a row take the same steps."""
    problem = exact[0]
    solver = nodal_solver(problem, "snes-vi", SnesVIOptions(vi_type="ssls", warm_start=False))
    norm = solver.qp.Kr.norm()
    first = solver.solve().residual_norms
    assert solver.solve().residual_norms == pytest.approx(first, rel=1e-12)
    assert solver.qp.Kr.norm() == norm


def test_peers_refuse_the_gauss_penalty_discretization() -> None:
    """P1 with the Gauss penalty quadrature is not the nodal problem."""
    problem = PenalizedProblem(paper_shell(), square(n=4), Discretization())
    for method in ("snes-vi", "proximal-galerkin"):
        with pytest.raises(ValueError, match="penalty_quadrature='vertex'"):
            nodal_solver(problem, method)


@pytest.mark.parametrize("method", ["snes-vi", "proximal-galerkin"])
def test_koiter_p2(method: str) -> None:
    """Koiter's model (P2: vertices and edge midpoints) falls out of the nodal machinery."""
    mesh = dolfinx.mesh.create_rectangle(
        MPI.COMM_WORLD, [[-0.25, -0.25], [0.25, 0.25]], [8, 8],
        ghost_mode=dolfinx.mesh.GhostMode.shared_facet,
    )  # fmt: skip
    shell = dataclasses.replace(paper_shell(), model="koiter")
    problem = PenalizedProblem(shell, mesh, Discretization(degree=2))
    reference = nodal_solver(problem, "active-set").solve()
    zeta = problem.zeta.copy()
    problem.zeta.x.array[:] = 0.0
    opts = SnesVIOptions() if method == "snes-vi" else ProximalGalerkinOptions()
    result = nodal_solver(problem, method, opts).solve()
    assert result.converged and result.active_nodes == reference.active_nodes > 0
    assert l2_norm(problem.zeta - zeta) <= tolerance(method, opts) * l2_norm(zeta)
    assert max(result.relative_kkt.values()) <= opts.kkt_rtol


# --------------------------------------------------------------------------- configuration


@pytest.mark.parametrize(
    ("sets", "needles"),
    [
        (["solver.method=snes-vi", "solver.vi_type=rs"], ("solver.vi_type", "'rsls'")),
        (["solver.vi_line_search=cubic"], ("solver.vi_line_search", "'bt', 'basic', 'l2'")),
        (["solver.proximal_tol=0"], ("solver.proximal_tol must be > 0", "1e-9")),
        (["solver.proximal_alpha_max=-1"], ("solver.proximal_alpha_max",)),
        (
            ["solver.method=proximal-galerkin", "solver.rtol=0"],
            ("solver.rtol must be > 0", "proximal-galerkin"),
        ),
        (["solver.method=snes-vi", "solver.factorization=qr"], ("solver.factorization",)),
    ],
)
@pytest.mark.filterwarnings("ignore:.*solves the nodal constraint exactly:UserWarning")
def test_config_errors_name_the_key(sets: list[str], needles: tuple[str, ...]) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(SMALL, sets)
    for needle in needles:
        assert needle in str(info.value), str(info.value)


def test_config_builds_the_peers_options() -> None:
    """The keys reach the options; P1 takes the nodal constraint, the penalty is ignored."""
    with pytest.warns(UserWarning, match="'snes-vi' solves the nodal constraint exactly"):
        cfg = load_config(
            SMALL,
            ["solver.method=snes-vi", "solver.vi_type=ssls", "solver.vi_line_search=bt",
             "penalty.exponent=1.5"],
        )  # fmt: skip
    assert cfg.penalty is None
    assert cfg.discretization.penalty_quadrature == "vertex"
    assert cfg.method_options == SnesVIOptions(vi_type="ssls", line_search="bt")
    with pytest.warns(UserWarning, match="penalty.exponent is ignored"):
        cfg = load_config(
            SMALL,
            ["solver.method=proximal-galerkin", "solver.proximal_tol=1e-7",
             "solver.proximal_alpha_max=1e3", "solver.max_iterations=40"],
        )  # fmt: skip
    opts = cfg.method_options
    assert (opts.tol, opts.alpha_max, opts.max_iterations) == (1e-7, 1e3, 40)


@serial
@pytest.mark.parametrize("method", ["snes-vi", "proximal-galerkin"])
def test_solve_command_writes_the_kkt_check(tmp_path: Path, capsys, method: str) -> None:
    """``solve --set solver.method=…`` writes the usual folder; κ = 0, the KKT measures."""
    out = tmp_path / method
    sets = [f"solver.method={method}", "output.paraview=false", "output.figures=false"]
    args = ["solve", str(SMALL), "-o", str(out), "-q"]
    code, _, err = run(capsys, *args, *(a for s in sets for a in ("--set", s)))
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    step = summary["continuation"][0]
    assert summary["method"] == method and summary["kappa"] == 0.0 and summary["converged"]
    assert summary["iterations"] == step["iterations"] > 0
    assert max(step["kkt_relative"].values()) <= 1e-6
    assert summary["max_violation"] <= 1e-12 and summary["contact_area"] > 0
    assert step["timings"]["total"] > 0 and step["factor_mb"] > 0


@serial
def test_solve_command_refuses_a_bad_vi_type(tmp_path: Path, capsys) -> None:
    args = ["solve", str(SMALL), "-o", str(tmp_path / "x"), "--set", "solver.method=snes-vi"]
    code, _, err = run(capsys, *args, "--set", "solver.vi_type=newton")
    assert_user_error(code, err, "solver.vi_type = 'newton'", "'rsls', 'ssls'")


# --------------------------------------------------------------------------- MPI


@pytest.mark.mpi
@pytest.mark.parametrize(
    ("method", "opts"),
    [("snes-vi", SnesVIOptions()), ("snes-vi", SnesVIOptions(vi_type="ssls")),
     ("proximal-galerkin", ProximalGalerkinOptions())],
)  # fmt: skip
def test_serial_and_parallel_agree(method: str, opts) -> None:
    """The distributed peer equals a serial solve of the same mesh to its tolerance."""
    results = []
    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):
        problem = PenalizedProblem(paper_shell(), square(comm, n=20), VERTEX)
        r = nodal_solver(problem, method, opts).solve()
        lam = r.multiplier.x.array[: r.multiplier.function_space.dofmap.index_map.size_local]
        results.append(
            {
                "active": r.active_nodes,
                "iterations": r.iterations,
                "energy": problem.energies()["energy"],
                "force": comm.allreduce(float(lam.sum()), op=MPI.SUM),
                "norm": l2_norm(problem.zeta),
            }
        )
        assert r.converged and max(r.relative_kkt.values()) <= opts.kkt_rtol
    par, ser = results
    assert par["active"] == ser["active"] > 0
    assert abs(par["iterations"] - ser["iterations"]) <= 1
    for key in ("energy", "force", "norm"):
        assert par[key] == pytest.approx(ser[key], rel=tolerance(method, opts)), key
