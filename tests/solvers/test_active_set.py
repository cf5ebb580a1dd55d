"""Exact solver of the nodal obstacle problem (κ = 0): KKT, penalty limit, no contact, MPI."""

from __future__ import annotations

# isort: split
from mpi4py import MPI

import dolfinx
import numpy as np
import pytest
from conftest import KKT_TOL, VERTEX, square
from conftest import make_paper_shell as paper_shell

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.norms import l2_norm, vm_norm
from shellobstacle.solvers.base import ConvergenceError
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.solvers.vi.active_set import ActiveSetResult, ActiveSetSolver
from shellobstacle.solvers.vi.nodal import nodal_rotations
from shellobstacle.solvers.vi.options import ActiveSetOptions
from shellobstacle.spec import Discretization

PULL_UP = "Piecewise(((2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.06), (0, True))"


@pytest.fixture(scope="module")
def exact() -> tuple[PenalizedProblem, ActiveSetResult]:
    """The paper's problem on a 24 × 24 square, solved exactly from ζ = 0."""
    problem = PenalizedProblem(paper_shell(), square(), VERTEX)
    result = ActiveSetSolver(problem).solve()
    return problem, result


def test_kkt_conditions(exact) -> None:
    """Feasibility, sign, complementarity and stationarity hold to round-off; contact exists."""
    problem, result = exact
    rel = result.relative_kkt
    print(f"\nscales: {result.scales}")
    print(f"KKT (absolute): {result.kkt}")
    print(f"KKT (relative): {rel}")
    print(
        f"{result.iterations} solves ({result.newton_steps} Newton, {result.pdas_steps} PDAS), "
        f"gammas {result.gammas}, active nodes {result.active_nodes}, timings {result.timings}"
    )
    assert result.converged
    assert result.active_nodes > 0
    assert rel["primal_feasibility"] <= KKT_TOL
    assert rel["dual_feasibility"] <= KKT_TOL
    assert rel["complementarity"] <= KKT_TOL
    assert rel["stationarity"] <= KKT_TOL
    # the multiplier is supported on the contact vertices, and pushes (λ ≥ 0)
    post = Postprocessor(problem)
    contact = post.contact()
    assert contact["num_contact_nodes"] == result.active_nodes
    assert contact["max_violation"] <= KKT_TOL * result.scales["gap"]
    n1 = result.multiplier.function_space.dofmap.index_map.size_local
    lam = result.multiplier.x.array[:n1]
    gap = post.nodal_gap().x.array[:n1]
    assert np.all(lam >= 0.0)
    assert np.all(np.abs(gap[lam > 0]) <= KKT_TOL * result.scales["gap"])
    # the total contact force balances part of the downward load, the pressure is λ / mass
    total = problem.mesh.comm.allreduce(float(lam.sum()), op=MPI.SUM)
    assert total > 0
    p = result.contact_pressure.x.array[:n1]
    assert np.allclose(p * post.mass, lam, rtol=1e-12, atol=0)


def test_warm_start_from_penalized_solution(exact) -> None:
    """From a penalized solution the active set settles with active-set steps alone."""
    reference, result = exact
    problem = PenalizedProblem(paper_shell(), reference.mesh, VERTEX)
    continuation(problem, NewtonSolver(problem), [1e-1, 1e-2, 1e-3, 1e-4])
    warm = ActiveSetSolver(problem).solve()
    assert warm.newton_steps == 0 and warm.pdas_steps <= 3
    assert warm.active_nodes == result.active_nodes
    assert l2_norm(problem.zeta - reference.zeta) <= 1e-10 * l2_norm(reference.zeta)


def test_penalized_solutions_converge_to_the_exact_one(exact) -> None:
    """‖ζ_κ^h − ζ^h‖_{V_M} decreases with κ at a rate ≥ 0.45 (Theorem 7.1: √κ; here O(κ))."""
    reference, result = exact
    problem = PenalizedProblem(paper_shell(), reference.mesh, VERTEX)
    solver = NewtonSolver(problem)
    post = Postprocessor(problem)
    n1 = post.P1.dofmap.index_map.size_local
    points = post.P1.tabulate_dof_coordinates()[:n1]
    c_norm = problem.obstacle.c_norm(problem.shell.surface.geometry_numpy(points))
    lam = result.multiplier  # on the P1 space of the solver: compare by interpolation
    lam_exact = dolfinx.fem.Function(post.P1)
    lam_exact.interpolate(lam)
    lam_exact = lam_exact.x.array[:n1]
    eps = problem.shell.material.epsilon
    kappas = [10.0**-k for k in range(1, 9)]
    errors, lam_errors = [], []
    for kappa in kappas:
        continuation(problem, solver, [kappa])
        errors.append(vm_norm(problem.zeta - reference.zeta))
        # penalized multiplier (ε/κ) m⁰_i {g_i}^- / |c_i| → λ_i
        g_minus = np.maximum(-post.nodal_gap().x.array[:n1], 0.0)
        lam_kappa = eps / kappa * post.mass_projected * g_minus / c_norm
        local = float(np.max(np.abs(lam_kappa - lam_exact), initial=0.0))
        lam_errors.append(problem.mesh.comm.allreduce(local, op=MPI.MAX))
    errors = np.array(errors)
    print("\n  kappa      ‖ζ_κ − ζ‖_VM   ratio   max|λ_κ − λ| / max λ")
    for k, (kappa, e) in enumerate(zip(kappas, errors, strict=True)):
        ratio = errors[k - 1] / e if k else float("nan")
        print(
            f"  {kappa:8.1e}  {e:12.4e}  {ratio:6.2f}  {lam_errors[k] / result.scales['force']:.3e}"
        )
    # λ_κ → λ like κ until the round-off of g (amplified by ε/κ) takes over
    assert np.all(np.diff(lam_errors[:6]) < 0)
    assert min(lam_errors) <= 1e-6 * result.scales["force"]
    assert np.all(np.diff(errors) < 0), errors
    used = errors > 1e-10 * vm_norm(reference.zeta)  # above the round-off of the solves
    rate = np.polyfit(np.log(np.array(kappas)[used]), np.log(errors[used]), 1)[0]
    print(f"  fitted rate in kappa: {rate:.3f} over {used.sum()} values")
    assert used.sum() >= 4
    assert rate >= 0.45


def test_no_contact_gives_the_unconstrained_solution() -> None:
    """A load pulling the shell up: no active vertex, and the penalized (inactive) solution."""
    problem = PenalizedProblem(paper_shell(PULL_UP), square(), VERTEX)
    result = ActiveSetSolver(problem).solve()
    assert result.converged and result.active_nodes == 0
    assert np.all(result.multiplier.x.array == 0.0)
    newton = PenalizedProblem(paper_shell(PULL_UP), problem.mesh, VERTEX, kappa=1e-3)
    NewtonSolver(newton).solve()
    assert Postprocessor(newton).contact()["num_contact_nodes"] == 0
    diff = vm_norm(problem.zeta - newton.zeta)
    assert diff <= 1e-10 * vm_norm(newton.zeta), diff


def test_free_transverse_component_on_the_boundary() -> None:
    """With ζ_3 free on γ, boundary vertices carry a constraint on ζ_3 alone (rotation = id)."""
    disc = Discretization(penalty_quadrature="vertex", transverse="free")
    problem = PenalizedProblem(paper_shell("-1e-4"), square(n=12), disc)
    result = ActiveSetSolver(problem).solve()
    assert max(result.relative_kkt.values()) <= KKT_TOL
    assert result.active_nodes == 13 * 13  # the uniform pressure flattens the whole shell
    zeta = problem.zeta.x.array.reshape(-1, 3)
    assert np.abs(zeta[:, 2]).max() > 0


def test_zero_load_gives_zero() -> None:
    """No load: ζ = 0, no contact, λ = 0."""
    problem = PenalizedProblem(paper_shell("0"), square(n=8), VERTEX)
    result = ActiveSetSolver(problem).solve()
    assert result.active_nodes == 0
    assert np.all(problem.zeta.x.array == 0.0)
    assert np.all(result.multiplier.x.array == 0.0)


def test_rejects_other_discretizations() -> None:
    """P1 with a penalty at other points than the vertices is not the nodal problem's limit."""
    mesh = square(n=4)
    with pytest.raises(ValueError, match="penalty_quadrature='vertex'"):
        ActiveSetSolver(PenalizedProblem(paper_shell(), mesh, Discretization()))


def test_nonconvergence_raises_with_the_iterate() -> None:
    """Running out of linear solves raises ConvergenceError carrying the result."""
    problem = PenalizedProblem(paper_shell(), square(n=12), VERTEX)
    with pytest.raises(ConvergenceError, match="did not converge") as info:
        ActiveSetSolver(problem, ActiveSetOptions(max_iterations=1)).solve()
    result = info.value.result
    assert not result.converged and result.iterations == 1
    assert l2_norm(problem.zeta) > 0  # the last iterate is left in place


def test_nodal_rotations_are_orthogonal_and_respect_fixed_components() -> None:
    """Q_i is orthogonal, maps e_k to c^F/|c^F|, and leaves fixed components alone."""
    rng = np.random.default_rng(1)
    c = rng.normal(size=(50, 3))
    c[:5] = [0.0, 0.0, 1.0]  # already aligned with an axis
    c[5:10] = [0.0, 0.0, -2.0]
    free = np.ones((50, 3), dtype=bool)
    free[10:20, :2] = False  # only the transverse component free
    free[20:25] = False  # clamped vertex: no constraint
    Q, k, cn = nodal_rotations(c, free)
    assert np.allclose(np.einsum("nji,njk->nik", Q, Q), np.eye(3)[None], atol=1e-14)
    ok = k >= 0
    assert np.all(ok == np.any(free, axis=1))
    cf = np.where(free, c, 0.0)
    assert np.allclose(Q[ok, :, k[ok]], cf[ok] / cn[ok, None], atol=1e-14)
    for j in range(3):
        fixed = ~free[:, j]
        assert np.allclose(Q[fixed][:, :, j], np.eye(3)[j], atol=0)


@pytest.mark.mpi
def test_serial_and_parallel_agree() -> None:
    """The distributed exact solve equals a serial solve of the same mesh."""
    results = []
    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):
        problem = PenalizedProblem(paper_shell(), square(comm, n=20), VERTEX)
        r = ActiveSetSolver(problem).solve()
        post = Postprocessor(problem)
        lam = r.multiplier.x.array[: r.multiplier.function_space.dofmap.index_map.size_local]
        results.append(
            {
                "active": r.active_nodes,
                "iterations": r.iterations,
                "energy": problem.energies()["energy"],
                "area": post.contact()["contact_area"],
                "force": comm.allreduce(float(lam.sum()), op=MPI.SUM),
                "norm": l2_norm(problem.zeta),
                "zeta3_min": post.zeta3_range()[0],
            }
        )
        assert r.converged and max(r.relative_kkt.values()) <= KKT_TOL
    par, ser = results
    assert par["active"] == ser["active"] and par["active"] > 0
    assert par["iterations"] == ser["iterations"]
    for key in ("energy", "area", "force", "norm", "zeta3_min"):
        assert par[key] == pytest.approx(ser[key], rel=1e-9, abs=1e-15), key
