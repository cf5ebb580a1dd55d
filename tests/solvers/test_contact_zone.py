"""Condensation onto the contact zone (solvers/contact_zone.py): exact, kept, grown, restored."""

from __future__ import annotations

from petsc4py import PETSc

import numpy as np
import pytest
from conftest import lu_solve, square, without_petsc_function
from conftest import make_paper_shell as paper_shell

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.linear.direct import DirectStrategy
from shellobstacle.solvers.linear.zone import ZoneStrategy
from shellobstacle.solvers.newton.continuation import continuation, predict
from shellobstacle.solvers.newton.solver import NewtonOptions, NewtonSolver
from shellobstacle.solvers.zone.reduced import ZoneModel

KAPPAS = [1e-2, 1e-3, 1e-4]


def solved(
    options: NewtonOptions, n: int = 32, linear: object = None
) -> tuple[PenalizedProblem, NewtonSolver, list]:
    problem = PenalizedProblem(paper_shell(), square(n=n))
    solver = NewtonSolver(problem, options, linear)
    steps = continuation(problem, solver, KAPPAS, predictor=False)
    assert all(s.converged for s in steps)
    return problem, solver, steps


@pytest.mark.mpi
def test_the_condensed_solve_is_the_jacobian_solve() -> None:
    """With the active points inside the zone, the condensed solve is J⁻¹ (to round-off)."""
    problem, solver, _ = solved(NewtonOptions())
    zone = solver.zone
    assert zone is not None and not zone.whole
    sizes = zone.sizes
    assert 0 < sizes["interface_dofs"] < sizes["zone_dofs"] < problem.num_dofs
    system = solver.system
    system.residual()
    A = system.jacobian()
    assert zone.covers(system.g < 0)
    zone.set_up(A)
    b = system.R.duplicate()
    rng = np.random.default_rng(problem.mesh.comm.rank)
    b.array[:] = rng.standard_normal(b.getLocalSize())
    x = b.duplicate()
    zone.cond.apply(b, x)
    exact = lu_solve(A, b)
    r = b.duplicate()
    A.mult(x, r)
    r.axpy(-1.0, b)
    assert r.norm() <= 1e-10 * b.norm()
    x.axpy(-1.0, exact)
    assert x.norm() <= 1e-9 * exact.norm()


@pytest.mark.mpi
def test_zone_continuation_equals_factorizing_every_step() -> None:
    """Same solution as a fresh factorization per step, far fewer factorizations.

    The zone is built before the first step (seeded by the coarse-grid first step) or, without
    the seed, once the contact appears; it is kept over the smaller κ. Unseeded, the Newton
    steps are those of the fresh factorizations; seeded, the first step from ζ = 0 goes to
    the minimizer of the model whose active set is the seed's penetrated points, which saves
    Newton steps at the first κ (the later κ start from the same solution).
    """
    p_fresh, _, fresh = solved(
        NewtonOptions(contact_zone=False), linear=DirectStrategy(reuse=False)
    )
    assert [s.newton.factorizations for s in fresh] == [s.iterations for s in fresh]
    z_fresh = p_fresh.zeta.x.petsc_vec
    # seeded: K_II only; unseeded: K at the first Newton step (no contact yet), then K_II
    for seed, first in ((True, 1), (False, 2)):
        p_zone, solver, zoned = solved(NewtonOptions(), linear=ZoneStrategy(seed=seed))
        if seed:
            assert zoned[0].iterations < fresh[0].iterations
            assert [s.iterations for s in zoned[1:]] == [s.iterations for s in fresh[1:]]
        else:
            assert [s.iterations for s in zoned] == [s.iterations for s in fresh]
        factorizations = [s.newton.factorizations for s in zoned]
        assert factorizations == [first, 0, 0]
        assert solver.zone.builds == first
        d = p_zone.zeta.x.petsc_vec.copy()
        d.axpy(-1.0, z_fresh)
        assert d.norm() <= 1e-10 * z_fresh.norm()


@pytest.mark.mpi
def test_a_seed_step_that_does_not_descend_is_replaced_by_a_newton_step(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """If the step towards the seed's model minimizer is not a descent direction (forced here
    by reversing it), the usual Newton step is taken: the steps of an unseeded zone."""
    _, _, plain = solved(NewtonOptions(), linear=ZoneStrategy(seed=False))
    p_ref, _, _ = solved(NewtonOptions())
    seed_step = ZoneModel._seed_step
    calls = []

    def reversed_step(self: ZoneModel, seed: np.ndarray) -> int:
        cg = seed_step(self, seed)
        assert self.r.dot(self.d) < 0.0  # the true step descends ...
        self.d.scale(-1.0)  # ... its reverse does not
        calls.append(cg)
        return cg

    monkeypatch.setattr(ZoneModel, "_seed_step", reversed_step)
    p_rev, _, rev = solved(NewtonOptions())
    assert len(calls) == 1
    assert [s.iterations for s in rev] == [s.iterations for s in plain]
    d = p_rev.zeta.x.petsc_vec.copy()
    d.axpy(-1.0, p_ref.zeta.x.petsc_vec)
    assert d.norm() <= 1e-10 * p_ref.zeta.x.petsc_vec.norm()


@pytest.mark.mpi
def test_the_zone_grows_when_an_active_point_leaves_it() -> None:
    """A zone that misses active points is rebuilt around them; the answer is unchanged."""
    problem, solver, _ = solved(NewtonOptions())
    reference = problem.zeta.x.petsc_vec.copy()
    zone = solver.zone
    small = zone.Z[:: max(1, zone.Z.size // 6)][:6]  # a few dofs: misses the contact region
    zone.set_zone(small)
    assert not zone.covers(solver.system.penalty.gap(problem.zeta.x.petsc_vec) < 0)
    builds = zone.builds
    problem.zeta.x.array[:] = 0.0
    steps = continuation(problem, solver, KAPPAS, predictor=False)
    assert all(s.converged for s in steps)
    assert zone.builds > builds and zone.Z.size > small.size
    d = problem.zeta.x.petsc_vec.copy()
    d.axpy(-1.0, reference)
    assert d.norm() <= 1e-10 * reference.norm()


@pytest.mark.mpi
def test_a_restored_zone_continues_to_the_last_bit() -> None:
    """A solver given another's zone (a resumed run) repeats its iterates exactly.

    Exactly serially. MUMPS' parallel factorization is not bitwise reproducible (its dynamic
    scheduling picks the processes of a front at run time): on three or more ranks two
    factorizations of this K already solve to different last bits
    (benchmarks/mumps_reproducibility.py), and on two ranks a bitwise check fails about once
    in a dozen runs. Under MPI the restored run agrees to round-off in the same Newton steps
    (measured: 1e-15 relative).
    """
    p1, s1, _ = solved(NewtonOptions())
    p2 = PenalizedProblem(paper_shell(), square(n=32))
    s2 = NewtonSolver(p2, NewtonOptions())
    s2.set_zone_indicator(s1.zone_indicator())
    assert np.array_equal(s2.zone.Z, s1.zone.Z)
    p2.zeta.x.array[:] = p1.zeta.x.array
    steps = []
    for problem, solver in ((p1, s1), (p2, s2)):
        problem.set_kappa(1e-5)
        steps.append(solver.solve().iterations)
    assert steps[0] == steps[1]
    if p1.mesh.comm.size == 1:
        assert np.array_equal(p1.zeta.x.array, p2.zeta.x.array)
    else:
        d = p2.zeta.x.petsc_vec.copy()
        d.axpy(-1.0, p1.zeta.x.petsc_vec)
        assert d.norm() <= 1e-13 * p1.zeta.x.petsc_vec.norm()


@pytest.mark.mpi
def test_a_zone_too_large_factorizes_the_whole_jacobian() -> None:
    """Above the zone's largest fraction of the dofs the Jacobian is factorized at every
    step; same answer (and the same steps as an unseeded zone, whose Newton steps are those
    of J_κ)."""
    p_small, _, small = solved(NewtonOptions(), n=24, linear=ZoneStrategy(seed=False))
    p_whole, solver, whole = solved(NewtonOptions(), n=24, linear=ZoneStrategy(max_fraction=1e-6))
    assert solver.zone.whole
    assert [s.iterations for s in whole] == [s.iterations for s in small]
    # the first step factorizes K (no contact yet, an empty zone), every later one J
    assert [s.newton.factorizations for s in whole] == [s.iterations for s in whole]
    d = p_whole.zeta.x.petsc_vec.copy()
    d.axpy(-1.0, p_small.zeta.x.petsc_vec)
    assert d.norm() <= 1e-10 * p_small.zeta.x.petsc_vec.norm()


def test_zone_max_fraction_is_checked() -> None:
    with pytest.raises(ValueError, match="zone_max_fraction"):
        ZoneStrategy(max_fraction=0.0)


def test_petscs_mumps_functions_are_found_through_petsc4py() -> None:
    """Every function of ``SIGNATURES`` is reached in the libpetsc petsc4py runs on; a name
    PETSc lacks is reported missing and gives no function (the real lookup, nothing patched)."""
    from shellobstacle.solvers import libpetsc
    from shellobstacle.solvers.zone import mumps

    for name in libpetsc.SIGNATURES:
        assert libpetsc.missing(name) is None
        assert libpetsc.function(name) is not None
    assert mumps.selected_inverse_available() is None
    reason = libpetsc.missing("MatMumpsNoSuchFunction")
    assert reason is not None and "MatMumpsNoSuchFunction" in reason
    assert libpetsc.function("MatMumpsNoSuchFunction") is None


def test_without_mumps_selected_inverses_the_solver_warns_and_falls_back(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """No MatMumpsGetInverse in PETSc: a warning, the factorization-reuse solver, the zone's
    answer."""
    zone_problem = PenalizedProblem(paper_shell(), square(n=8))
    zone_solver = NewtonSolver(zone_problem, NewtonOptions())
    assert zone_solver.zone is not None
    continuation(zone_problem, zone_solver, [1e-2], predictor=False)
    without_petsc_function(monkeypatch, "MatMumpsGetInverse")
    problem = PenalizedProblem(paper_shell(), square(n=8))
    with pytest.warns(RuntimeWarning, match="selected inverse entries are not reachable"):
        solver = NewtonSolver(problem, NewtonOptions())
    assert solver.zone is None and isinstance(solver.linear, DirectStrategy)
    assert solver.linear.reuse
    steps = continuation(problem, solver, [1e-2], predictor=False)
    assert steps[0].converged
    d = problem.zeta.x.petsc_vec.copy()
    d.axpy(-1.0, zone_problem.zeta.x.petsc_vec)
    assert d.norm() <= 1e-10 * zone_problem.zeta.x.petsc_vec.norm()


@pytest.mark.mpi
def test_newton_on_the_zone_problem_solves_the_whole_problem() -> None:
    """Steps on the zone's problem (ζ_I eliminated) reach the solution of J_κ itself.

    With a seeded zone every step is taken on the zone (without the seed, all but the cold
    first step); the answer agrees with full Newton steps through the same zone and with a
    fresh factorization of every Jacobian, and the completed iterate's residual R(ζ) is the
    one the history reports.
    """
    p_red, s_red, reduced = solved(NewtonOptions())
    p_cold, _, cold = solved(NewtonOptions(), linear=ZoneStrategy(seed=False))
    p_full, _, full = solved(NewtonOptions(), linear=ZoneStrategy(reduced=False))
    p_fresh, _, _ = solved(NewtonOptions(contact_zone=False), linear=DirectStrategy(reuse=False))
    assert [s.newton.zone_steps for s in reduced] == [s.iterations for s in reduced]
    assert [s.newton.zone_steps for s in cold] == [
        cold[0].iterations - 1,
        *[s.iterations for s in cold[1:]],
    ]
    assert all(s.newton.zone_steps == 0 for s in full)
    ref = p_fresh.zeta.x.petsc_vec
    for problem in (p_red, p_cold, p_full):
        d = problem.zeta.x.petsc_vec.copy()
        d.axpy(-1.0, ref)
        assert d.norm() <= 1e-10 * ref.norm()
    s_red.system.residual()
    assert s_red.system.R.norm() == pytest.approx(reduced[-1].newton.residual_norms[-1], rel=1e-12)
    assert reduced[-1].newton.relative_residual <= 1e-10


def test_only_the_direct_strategy_predicts() -> None:
    """The Euler predictor needs a kept factorization of the whole Jacobian: the zone's and
    the iterative strategy leave ζ as it is, the direct strategy predicts."""
    for options in (NewtonOptions(), NewtonOptions(linear_solver="iterative")):
        problem, solver, _ = solved(options)
        zeta0 = problem.zeta.x.array.copy()
        assert not solver.linear.predicts
        assert not predict(solver, solver.kappa / 10)
        assert np.array_equal(problem.zeta.x.array, zeta0)
    problem, solver, _ = solved(NewtonOptions(contact_zone=False))
    zeta0 = problem.zeta.x.array.copy()
    assert solver.linear.predicts and predict(solver, solver.kappa / 10)
    assert not np.array_equal(problem.zeta.x.array, zeta0)


@pytest.mark.mpi
def test_the_predictor_is_the_euler_step() -> None:
    """predict(): ζ + Δκ J⁻¹(−∂R/∂κ), J the Jacobian at the solution."""
    problem, solver, _ = solved(NewtonOptions(contact_zone=False))
    system = solver.system
    kappa = solver.kappa
    zeta0 = problem.zeta.x.petsc_vec.copy()
    g = system.penalty.gap(zeta0)
    b = system.R.duplicate()
    b.set(0.0)
    system.penalty.add_residual(np.minimum(g, 0.0) / kappa, kappa, b)  # −∂R/∂κ: (1/κ²) Mᵀ g⁻
    system.g = g
    expected = lu_solve(system.jacobian(), b)
    assert predict(solver, kappa / 10)
    step = problem.zeta.x.petsc_vec.copy()
    step.axpy(-1.0, zeta0)
    step.scale(1.0 / (kappa / 10 - kappa))
    step.axpy(-1.0, expected)
    assert step.norm() <= 1e-8 * expected.norm()


def _laplacian_with_dense_block(n: int, dense: np.ndarray) -> PETSc.Mat:
    """A sequential SPD matrix like the zone's ``S``: the 5-point grid Laplacian on n × n
    points plus a dense positive semidefinite block (all entries 1/|dense|) on ``dense``."""
    m = n * n
    block = np.zeros(m, dtype=bool)
    block[dense] = True
    rows = []
    for i in range(m):
        cols = {i} | {j for j, ok in ((i - 1, i % n), (i + 1, (i + 1) % n), (i - n, i >= n),
                                      (i + n, i < m - n)) if ok}  # fmt: skip
        if block[i]:
            cols |= set(dense.tolist())
        rows.append(sorted(cols))
    indptr = np.concatenate([[0], np.cumsum([len(r) for r in rows])]).astype(PETSc.IntType)
    indices = np.concatenate(rows).astype(PETSc.IntType)
    i_of = np.repeat(np.arange(m), np.diff(indptr))
    values = np.where(i_of == indices, 4.0, 0.0) - np.where(
        (np.abs(i_of - indices) == 1) | (np.abs(i_of - indices) == n), 1.0, 0.0
    )
    values += np.where(block[i_of] & block[indices], 1.0 / dense.size, 0.0)
    return PETSc.Mat().createAIJ((m, m), csr=(indptr, indices, values), comm=PETSc.COMM_SELF)


@pytest.mark.mpi
@pytest.mark.parametrize("factorization", ["cholesky", "lu"])
def test_the_replicated_schur_factor_solves_on_all_ranks_together(factorization: str) -> None:
    """S (held whole by every rank) factorized by all ranks together: the solution of S x = b
    is the sequential one to round-off and bitwise the same on every rank."""
    from mpi4py import MPI

    from shellobstacle.solvers.zone.mumps import ReplicatedFactor

    comm = MPI.COMM_WORLD
    S = _laplacian_with_dense_block(30, np.arange(0, 900, 7))
    factor = ReplicatedFactor(comm, S, factorization, {7: 2})
    assert factor.parallel == (comm.size > 1)
    b = S.createVecLeft()
    b.array[:] = np.sin(np.arange(b.getSize()))
    x = b.duplicate()
    for scale in (1.0, 2.0):  # a second factorization of new values, same pattern
        S.scale(scale)
        factor.factorize(S)
        factor.solve(b, x)
        reference = lu_solve(S, b)
        assert np.abs(x.array - reference.array).max() < 1e-12 * np.abs(reference.array).max()
        everywhere = comm.allgather(x.array.copy())
        assert all(np.array_equal(everywhere[0], xr) for xr in everywhere)
    factor.destroy()


def test_a_failed_factorization_raises_a_clear_error() -> None:
    """MUMPS' failure (here: a singular matrix) raises, naming the matrix and INFOG(1)."""
    from shellobstacle.solvers.base import direct_solver, factorize

    A = _laplacian_with_dense_block(6, np.arange(3))
    A.zeroEntries()
    A.assemble()
    ksp = direct_solver(A, "lu")
    with pytest.raises(
        RuntimeError, match=r"could not factorize the test matrix: INFOG\(1\) = -10"
    ):
        factorize(ksp, "the test matrix")
    ksp.destroy()


@pytest.mark.mpi
def test_a_zone_too_large_is_built_again_once_the_contact_shrinks(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The cylindrical panel's zone seeded where its first step penetrates holds 45 % of the
    dofs; its contact at the first κ holds half those points: the whole Jacobian is factorized
    only until a zone built from the active points fits, then the steps are the zone's, with
    the answer of the path without a zone."""
    from pathlib import Path

    from shellobstacle.api import solve
    from shellobstacle.config.loader import load_config
    from shellobstacle.post.contact import Postprocessor
    from shellobstacle.solvers.zone.contact_zone import ContactZone

    states: list[bool] = []
    set_zone = ContactZone.set_zone

    def spy(self: ContactZone, Z: np.ndarray, pattern: object = None) -> None:
        set_zone(self, Z, pattern)
        states.append(self.whole)

    monkeypatch.setattr(ContactZone, "set_zone", spy)
    config = str(Path(__file__).parents[2] / "examples" / "cylinder_koiter.toml")
    runs = []
    for zone in ("true", "false"):
        cfg = load_config(config, ["domain.h=0.05", f"solver.contact_zone={zone}"])
        result = solve(cfg)
        assert result.converged
        area = Postprocessor(result.problem).contact()["contact_area"]
        runs.append((result.problem.zeta.x.petsc_vec.copy(), area))
    assert states == [True, False]  # whole at the seed, then one zone for the continuation
    (zeta, area), (reference, area_reference) = runs
    assert area == pytest.approx(area_reference, rel=1e-12)
    zeta.axpy(-1.0, reference)
    assert zeta.norm() <= 1e-9 * reference.norm()
