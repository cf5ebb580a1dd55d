"""Newton's method made to decrease a non-convex energy ``J`` (docs/model.md §11.1).

Each step solves ``(K + τ D) δ = −R`` with ``R = J'(ζ)``, ``K = J''(ζ)`` (:mod:`.tangent`):
``τ = 0`` where ``K`` is positive definite, else the smallest of ``τ₀, 10 τ₀, …`` that makes
the factorization's inertia positive (Nocedal & Wright, *Numerical Optimization*, §3.4), so
``δ`` is a descent direction, ``R·δ < 0``. The step ``α δ`` backtracks from ``α = 1`` (halving)
until Armijo's condition ``J(ζ + α δ) ≤ J(ζ) + c α R·δ`` holds on ``J`` itself, assembled;
where the predicted decrease ``|R·δ|`` is below the energy's round-off the full step is taken
and the residual decides. Newton stops when ``‖R‖ ≤ rtol ‖s f‖`` (``f`` the load vector, ``s``
the load factor), or when the step is below ``stol ‖ζ‖`` (the residual's round-off floor).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Protocol

from mpi4py import MPI  # noqa: F401  (before PETSc: the MPI runtime PETSc links to)
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import ufl

from shellobstacle.solvers.nonlinear.tangent import Tangent
from shellobstacle.solvers.result import ConvergenceError

__all__ = ["Energy", "EnergyNewton", "NewtonRecord"]

#: Armijo's sufficient-decrease constant
ARMIJO = 1e-4
#: the energy's relative round-off: a predicted decrease below it is not tested
ENERGY_ROUNDOFF = 1e-12


class Energy(Protocol):
    """What the solvers ask of a problem
    (:class:`~shellobstacle.models.nonlinear_koiter.NonlinearKoiterProblem` is one)."""

    zeta: dolfinx.fem.Function
    load_factor: dolfinx.fem.Constant
    energy: ufl.Form  #: ``J``
    residual: ufl.Form  #: ``J'``
    jacobian: ufl.Form  #: ``J''``
    load: ufl.Form  #: ``f``: the load's linear form at load factor 1
    bcs: list[dolfinx.fem.DirichletBC]
    jit_options: dict[str, Any] | None


@dataclasses.dataclass
class NewtonRecord:
    """One solve: its ``iterations``, the largest ``shift`` ``τ`` it used (0: none), the
    line search's smallest ``step`` ``α``, the residual ``norms`` and the final ``energy``."""

    iterations: int = 0
    shift: float = 0.0
    step: float = 1.0
    norms: list[float] = dataclasses.field(default_factory=list)
    energy: float = math.nan


class EnergyNewton:
    """The energy-decreasing Newton method on ``problem`` (its forms compiled once).

    Args:
        problem: the energy, its variations, ``ζ`` and the load factor.
        rtol: the residual's reduction relative to ``‖s f‖``; stol: the smallest step
            relative to ``‖ζ‖``; max_it: Newton steps before a :class:`ConvergenceError`.
        shift: ``τ₀``, the first shift tried on an indefinite tangent.
    """

    def __init__(
        self,
        problem: Energy,
        rtol: float = 1e-9,
        stol: float = 1e-12,
        max_it: int = 25,
        shift: float = 1e-4,
    ) -> None:
        self.problem, self.rtol, self.stol, self.max_it, self.shift = (
            problem, rtol, stol, max_it, shift,
        )  # fmt: skip
        jit = problem.jit_options
        self.comm = problem.zeta.function_space.mesh.comm
        self._energy = dolfinx.fem.form(problem.energy, jit_options=jit)
        self._residual = dolfinx.fem.form(problem.residual, jit_options=jit)
        self._load = dolfinx.fem.form(problem.load, jit_options=jit)
        self.tangent = Tangent(dolfinx.fem.form(problem.jacobian, jit_options=jit), problem.bcs)
        self.R = dolfinx.fem.petsc.create_vector(problem.zeta.function_space)
        self.f = self.R.duplicate()
        self._assemble(self.f, self._load)
        self.delta = self.R.duplicate()
        self._start = self.R.duplicate()

    def _assemble(self, b: PETSc.Vec, form: dolfinx.fem.Form) -> None:
        """``b`` ← the vector of ``form``, its Dirichlet rows zero."""
        with b.localForm() as local:
            local.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, form)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        dolfinx.fem.petsc.set_bc(b, self.problem.bcs)

    def energy(self) -> float:
        """``J(ζ)`` (collective)."""
        return self.comm.allreduce(dolfinx.fem.assemble_scalar(self._energy))

    def residual(self) -> float:
        """Assemble ``R = J'(ζ)`` into ``self.R``; returns ``‖R‖``."""
        self._assemble(self.R, self._residual)
        return self.R.norm()

    def direction(self, record: NewtonRecord) -> float:
        """``δ ← −(K + τ D)⁻¹ R`` with the smallest ``τ`` of the module docstring that gives a
        descent direction; returns the slope ``R·δ`` (negative)."""
        self.tangent.assemble()
        shift = 0.0
        while True:
            negative = self.tangent.factor(shift)
            if negative == 0:
                self.tangent.solve(self.R, self.delta)
                self.delta.scale(-1.0)
                slope = self.R.dot(self.delta)
                if slope < 0 or self.R.norm() == 0:
                    record.shift = max(record.shift, shift)
                    return slope
            shift = self.shift if shift == 0 else 10 * shift
            if shift > 1e8:
                raise ConvergenceError(
                    "no shift of the nonlinear tangent gave a descent direction (the energy "
                    "or its tangent is not finite): check the load and the material"
                )

    def line_search(self, slope: float, energy: float, record: NewtonRecord) -> tuple[float, float]:
        """``ζ ← ζ + α δ`` with Armijo's ``α``; returns ``J`` there and ``α``."""
        x = self.problem.zeta.x.petsc_vec
        x.copy(self._start)
        alpha, noise = 1.0, ENERGY_ROUNDOFF * max(abs(energy), 1e-300)
        while True:
            self._start.copy(x)
            x.axpy(alpha, self.delta)
            self.problem.zeta.x.scatter_forward()
            trial = self.energy()
            if -slope <= noise or trial <= energy + ARMIJO * alpha * slope + noise:
                record.step = min(record.step, alpha)
                return trial, alpha
            alpha /= 2
            if alpha < 1e-10:
                self._start.copy(x)
                self.problem.zeta.x.scatter_forward()
                raise ConvergenceError(
                    "the line search on the nonlinear energy found no decrease along the "
                    "Newton direction: apply the load in smaller steps"
                )

    def solve(self) -> NewtonRecord:
        """Newton's method from the current ``ζ`` to a stationary point of ``J``.

        Raises:
            ConvergenceError: after ``max_it`` steps, or when no step decreases ``J``; ``ζ``
                is left at the last iterate.
        """
        record = NewtonRecord()
        for bc in self.problem.bcs:
            bc.set(self.problem.zeta.x.array)
        self.problem.zeta.x.scatter_forward()
        scale = abs(float(self.problem.load_factor.value)) * self.f.norm()
        energy = self.energy()
        for it in range(self.max_it + 1):
            rnorm = self.residual()
            record.norms.append(rnorm)
            if rnorm <= self.rtol * scale or rnorm == 0:
                break
            if it == self.max_it:
                raise ConvergenceError(
                    f"Newton's method on the nonlinear energy did not converge in {it} steps "
                    f"(residual {rnorm:.3e}, target {self.rtol * scale:.3e}): apply the load in "
                    "smaller steps",
                    result=record,
                )
            slope = self.direction(record)
            energy, alpha = self.line_search(slope, energy, record)
            record.iterations += 1
            if alpha * self.delta.norm() <= self.stol * self.problem.zeta.x.petsc_vec.norm():
                record.norms.append(self.residual())
                break
        record.energy = energy
        return record
