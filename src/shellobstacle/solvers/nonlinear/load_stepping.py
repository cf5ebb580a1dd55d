"""Load stepping with step control on a nonlinear energy, and the limit point (docs/model.md
§11.2).

The load factor ``s`` goes from 0 to 1. Each step starts from the last converged ``ζ_k``
moved along the path's tangent, ``ζ_k + Δs t_k`` with ``K(ζ_k) t_k = f`` (Euler's predictor),
and runs :class:`~.newton.EnergyNewton`. A step is accepted when Newton converged, the
tangent at the new ``ζ`` is positive definite (a stable equilibrium: no negative or null pivot)
and the step resolved the path: a step that went further than its predictor,
``‖ζ_{k+1} − ζ_k‖ > Δs ‖t_k‖`` (the path softens), has Newton's correction of the predictor at
most ``CORRECTOR`` = ½ of its change, ``‖ζ_{k+1} − ζ_pred‖ ≤ ½ ‖ζ_{k+1} − ζ_k‖`` (it is
``O(Δs)`` of it on a smooth path; a jump to another branch, a snap-through, is almost all
correction; on a path of square-root shape the ratio reaches ½ where the step reaches the
limit point). A stiffening step (the plate's) falls short of its predictor and is not tested.
A failed step is halved and retried from ``ζ_k``; below ``min_step`` the stepping stops. An
easy step (at most ``easy`` Newton steps) doubles the next, up to ``max_step``.

Bergan's current stiffness parameter ``S_k = f·t_0 / f·t_k`` (1 on the linear path, above 1
where the shell stiffens) falls to 0 at a limit point of the load, where ``K`` turns singular
along the path, and as ``S² ∝ s_c − s`` there, ``s_c`` is extrapolated from the last two
steps. A stepping stopped where ``S_k`` is below ``limit_stiffness``, or where the
extrapolated ``s_c`` lies within two failed steps, or where the only equilibria beyond
are unstable, raises :class:`LimitPointError` (snap-through is not followed); any other stop
raises :class:`~shellobstacle.solvers.result.ConvergenceError`.
"""

from __future__ import annotations

import dataclasses
import logging
import math

from mpi4py import MPI
from petsc4py import PETSc

from shellobstacle.solvers.nonlinear.newton import Energy, EnergyNewton
from shellobstacle.solvers.result import ConvergenceError

__all__ = ["LimitPointError", "LoadPath", "LoadStep", "LoadStepping"]

logger = logging.getLogger(__name__)

#: the largest accepted ``‖ζ_{k+1} − ζ_pred‖ / ‖ζ_{k+1} − ζ_k‖`` (the corrector's share) of a
#: step that went further than its predictor
CORRECTOR = 0.5


@dataclasses.dataclass(frozen=True)
class LoadStep:
    """An accepted load step: the load factor reached, its Newton steps, ``J`` there, the
    largest ``|ζ_3|``, the current stiffness parameter ``S`` and the step ``Δs`` taken after
    ``cuts`` halvings."""

    load_factor: float
    newton_iterations: int
    energy: float
    max_deflection: float
    stiffness: float
    step: float
    cuts: int


@dataclasses.dataclass
class LoadPath:
    """The accepted steps, in order (the first is ``s = 0``)."""

    steps: list[LoadStep] = dataclasses.field(default_factory=list)

    @property
    def cuts(self) -> int:
        """Halvings over the whole path."""
        return sum(step.cuts for step in self.steps)


class LimitPointError(ConvergenceError):
    """The load passes a limit (or bifurcation) point of the equilibrium path before ``s = 1``:
    ``load_factor`` the last stable ``s``, ``estimate`` the extrapolated limit (nan if none),
    ``deflection`` the largest ``|ζ_3|`` there; ``ζ`` holds that state."""

    def __init__(self, message: str, path: LoadPath, estimate: float) -> None:
        super().__init__(message)
        last = path.steps[-1]
        self.path, self.estimate = path, estimate
        self.load_factor, self.deflection = last.load_factor, last.max_deflection


class LoadStepping:
    """Load stepping on ``problem`` (its load factor driven from 0 to ``target``).

    Args:
        problem: the energy (:class:`~.newton.Energy`).
        first_step, min_step, max_step: ``Δs`` at the start, before giving up, at most.
        easy: Newton steps at or below which the next ``Δs`` doubles.
        limit_stiffness: the ``S`` below which a stop is a limit point.
        newton: the Newton solver (default: :class:`~.newton.EnergyNewton` with 15 steps).
    """

    def __init__(
        self,
        problem: Energy,
        first_step: float = 0.25,
        min_step: float = 1e-3,
        max_step: float = 0.5,
        easy: int = 4,
        limit_stiffness: float = 0.2,
        newton: EnergyNewton | None = None,
    ) -> None:
        self.problem = problem
        self.first_step, self.min_step, self.max_step = first_step, min_step, max_step
        self.easy, self.limit_stiffness = easy, limit_stiffness
        self.newton = newton or EnergyNewton(problem, max_it=15)
        self.t = self.newton.R.duplicate()  # the path's tangent t_k
        self._t_last = self.newton.R.duplicate()
        self._last = self.newton.R.duplicate()
        self.path: LoadPath | None = None
        self._ft0, self._step = math.nan, first_step

    @property
    def _zeta(self) -> PETSc.Vec:
        return self.problem.zeta.x.petsc_vec

    def deflection(self) -> float:
        """``max |ζ_3|`` over the mesh (collective)."""
        local = self.problem.zeta.x.array.reshape(-1, 3)[:, 2]
        comm = self.problem.zeta.function_space.mesh.comm
        return comm.allreduce(float(abs(local).max(initial=0.0)), op=MPI.MAX)

    def _tangent(self) -> tuple[int, float]:
        """Factorize ``K(ζ)`` and solve ``K t = f``; returns the non-positive pivots and
        ``f·t``."""
        self.newton.tangent.assemble()
        negative = self.newton.tangent.factor()
        self.newton.tangent.solve(self.newton.f, self.t)
        return negative, self.newton.f.dot(self.t)

    def start(self) -> None:
        """Back to ``s = 0``, ``ζ = 0`` (a new path)."""
        self._zeta.set(0.0)
        self.problem.zeta.x.scatter_forward()
        self.problem.load_factor.value = 0.0
        _, self._ft0 = self._tangent()
        self.path = LoadPath([LoadStep(0.0, 0, 0.0, 0.0, 1.0, 0.0, 0)])
        self._step = self.first_step

    def solve(self, target: float = 1.0) -> LoadPath:
        """Step the load factor to ``target``: from 0 on the first call (or after
        :meth:`start`), else on from the last state reached (a path through several loads).

        Raises:
            LimitPointError: a limit point before ``target`` (``ζ``: the last stable state).
            ConvergenceError: a step fails at ``min_step`` elsewhere (``ζ``: the last state).
        """
        if self.path is None:
            self.start()
        path, cuts = self.path, 0
        s = path.steps[-1].load_factor
        while s < target:
            step = min(self._step, target - s)
            self._zeta.copy(self._last)
            self.t.copy(self._t_last)
            self._zeta.axpy(step, self.t)  # Euler's predictor
            predicted = self._zeta.copy()
            self.problem.zeta.x.scatter_forward()
            self.problem.load_factor.value = s + step
            failure, record = None, None
            try:
                record = self.newton.solve()
            except ConvergenceError as error:
                failure = str(error)
            if failure is None:
                predicted.axpy(-1.0, self._zeta)
                moved = self._zeta.copy()
                moved.axpy(-1.0, self._last)
                negative, ft = self._tangent()
                if negative:
                    failure = (
                        f"the tangent at s = {s + step:.6g} has {negative} non-positive pivots"
                    )
                elif (
                    predicted.norm() > CORRECTOR * moved.norm()
                    and moved.norm() > step * self._t_last.norm()
                ):
                    failure = f"ζ ran ahead of the path's tangent at s = {s + step:.6g}"
            if failure is not None or record is None:
                self._last.copy(self._zeta)
                self.problem.zeta.x.scatter_forward()
                self.problem.load_factor.value = s
                self._t_last.copy(self.t)  # t_k again (the failed attempt overwrote it)
                logger.info("load step to s = %.6g failed (%s); halving", s + step, failure)
                if step / 2 < self.min_step:
                    raise self._stop(path, step, str(failure))
                self._step, cuts = step / 2, cuts + 1
                continue
            s += step
            path.steps.append(
                LoadStep(
                    s, record.iterations, record.energy, self.deflection(), self._ft0 / ft,
                    step, cuts,
                )
            )  # fmt: skip
            last = path.steps[-1]
            logger.info(
                "load factor %.6g: %d Newton steps, energy %.6e, max |ζ_3| %.6e, S = %.4f%s",
                s, last.newton_iterations, last.energy, last.max_deflection, last.stiffness,
                f" ({cuts} cuts)" if cuts else "",
            )  # fmt: skip
            if record.iterations <= self.easy:
                self._step = min(2 * self._step, self.max_step)
            cuts = 0
        return path

    def _stop(self, path: LoadPath, step: float, failure: str) -> ConvergenceError:
        """The error that ends a stepping stuck at its last step (``step``: the failed one)."""
        last = path.steps[-1]
        estimate = math.nan
        if len(path.steps) >= 2:
            before = path.steps[-2]
            drop = before.stiffness**2 - last.stiffness**2
            if drop > 0:
                estimate = (
                    last.load_factor
                    + last.stiffness**2 * (last.load_factor - before.load_factor) / drop
                )
        unstable = "non-positive pivots" in failure
        near = estimate < last.load_factor + 2 * step
        if last.stiffness < self.limit_stiffness or unstable or near:
            where = f"near s = {estimate:.6g}" if math.isfinite(estimate) else "ahead"
            return LimitPointError(
                f"limit point of the load {where}: the last stable state is s = "
                f"{last.load_factor:.6g} (max |ζ_3| = {last.max_deflection:.6g}, current "
                f"stiffness {last.stiffness:.3g}); the load beyond it snaps through: lower the "
                "load or follow the path past it by arc length",
                path,
                estimate,
            )
        return ConvergenceError(
            f"load stepping stopped at s = {last.load_factor:.6g} (max |ζ_3| = "
            f"{last.max_deflection:.6g}): {failure} with Δs = {step:.3g}; lower min_step or "
            "refine the mesh",
            steps=(),
        )
