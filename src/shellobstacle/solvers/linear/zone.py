"""Exact Newton directions condensed onto a contact zone, and steps on the zone's problem.

The default direct strategy (:mod:`~shellobstacle.solvers.zone`): ``K`` outside the zone is
factorized once per zone and kept across κ. While the active points stay inside the zone,
Newton's steps are taken on the zone's own condensed problem
(:class:`~shellobstacle.solvers.zone.reduced.ZoneModel`), which needs only the zone's Schur
complement; a full step (no zone yet, a zone too large, or an active point outside it) is
solved exactly through the zone, and its penetration helps place the next zone. A solve that
starts without contact builds its first zone where a coarse-grid step penetrates
(:mod:`~shellobstacle.solvers.newton.seeds`), before any factorization of ``K``.
"""

from __future__ import annotations

import time
import warnings

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import numpy as np

from shellobstacle.solvers.linear.direct import REUSE_MAX_ITERATIONS
from shellobstacle.solvers.newton.seeds import coarse_penetration
from shellobstacle.solvers.newton.system import PenalizedSystem
from shellobstacle.solvers.zone.contact_zone import ContactZone
from shellobstacle.solvers.zone.mumps import selected_inverse_available
from shellobstacle.solvers.zone.reduced import ZoneModel

__all__ = ["ZONE_MAX_FRACTION", "ZoneStrategy", "zone_available"]

#: a zone with more dofs than this fraction is not condensed
ZONE_MAX_FRACTION = 0.3


def zone_available(comm: MPI.Comm) -> bool:
    """Whether MUMPS' selected inverse entries can be reached on every rank (else: warn)."""
    reason = selected_inverse_available()
    if not comm.allreduce(reason is None, op=MPI.LAND):
        warnings.warn(
            "solver.contact_zone: MUMPS' selected inverse entries are not reachable "
            f"({reason or 'on another rank'}); using one factorization per κ reused by CG "
            "instead",
            RuntimeWarning,
            stacklevel=3,
        )
        return False
    return True


class ZoneStrategy:
    """Newton directions through a :class:`~shellobstacle.solvers.zone.contact_zone.ContactZone`.

    Args:
        factorization: MUMPS ``"cholesky"`` or ``"lu"`` of ``K_II`` and the Schur complement.
        rtol: of the CG that reuses a factorization of the Schur complement.
        max_fraction: zones above this fraction of the dofs factorize the whole Jacobian.
        reduced: take steps on the zone's problem (``False``: every step a full one through
            the zone, a reference in tests).
        seed: build the first zone from the coarse-grid step of a solve without contact.
    """

    predicts = False

    def __init__(
        self,
        factorization: str = "cholesky",
        rtol: float = 1e-12,
        max_fraction: float = ZONE_MAX_FRACTION,
        reduced: bool = True,
        seed: bool = True,
    ) -> None:
        if not 0.0 < max_fraction <= 1.0:
            raise ValueError(f"zone_max_fraction must be in (0, 1], got {max_fraction}")
        self.factorization, self.rtol, self.max_fraction = factorization, rtol, max_fraction
        self.reduced_steps, self.seed = reduced, seed
        self.factorizations = 0
        self.hint: np.ndarray | None = None  # points the last full step penetrates

    def attach(self, system: PenalizedSystem, timings: dict[str, float]) -> None:
        """The zone of ``system`` (empty until the first step)."""
        self.system, self.timings = system, timings
        self.zone = ContactZone(
            system.K, system.penalty, self.max_fraction, self.factorization, timings
        )

    def begin(self) -> None:
        """A new solve: no kept factorization of ``S`` (the zone itself is kept)."""
        self.factorizations = 0
        self.hint = None
        self.zone.forget_factorization()
        self.zone.set_load(self.system.f)

    def refresh(self) -> None:
        """The zone's own problem takes the penalty's new point operators; the zone, its
        condensation of ``K`` and its factorizations' analyses are kept."""
        self.zone.refresh()

    def tangent(self, b: PETSc.Vec) -> bool:
        """No prediction: from the previous solution the zone's steps are as few."""
        return False

    def _prepare(self, active: np.ndarray) -> None:
        builds = self.zone.builds
        self.zone.prepare(active, self.hint)
        self.factorizations += self.zone.builds - builds  # (each build factorizes K_II)

    def direction(self, history: list[float], target: float) -> int:
        """A full step: ``δ ← J⁻¹(−R)`` exactly through the zone (grown to hold the active
        points first)."""
        system, zone = self.system, self.zone
        ta = time.perf_counter()
        system.jacobian()
        self.timings["assemble"] += time.perf_counter() - ta
        system.negate_residual()
        self._prepare(system.g < 0)
        zone.set_up(system.A)
        if zone.whole:
            self.factorizations += 1
        ts = time.perf_counter()
        zone.newton_step(system.R, system.zeta, system.dz)
        system.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        self.timings["solve"] += time.perf_counter() - ts
        self.hint = system.penetrated_by_full_step()
        return 1

    def reduced(self, floor_factor: float) -> ZoneModel | None:
        """The zone's problem to take the next steps on, or None for a full step (no contact
        and none expected, or a zone too large). Builds the zone for the active points first
        (before any contact: where the coarse-grid step penetrates)."""
        zone, system = self.zone, self.system
        if not self.reduced_steps:
            return None
        comm = system.comm
        active = system.g < 0
        if not zone.usable:
            if zone.whole:
                return None
            if not comm.allreduce(bool(active.any()), op=MPI.LOR):
                if zone.Z is not None or not self.seed:
                    return None  # no contact: a full step
                self.hint = coarse_penetration(system, self.timings)
                if not comm.allreduce(bool(self.hint.any()), op=MPI.LOR):
                    return None  # no contact expected either
        self._prepare(active)
        if not zone.usable:
            return None
        seed = None
        if self.hint is not None:  # the seed: the hint at the zone's points, on every rank
            seed = np.concatenate(comm.allgather(self.hint[np.flatnonzero(zone.points)]))
        self.hint = None
        return ZoneModel(zone.problem, system, seed, REUSE_MAX_ITERATIONS, self.rtol)

    # -- the zone as state (checkpoints) ------------------------------------------------------
    def zone_indicator(self) -> dolfinx.fem.Function | None:
        """The kept zone as a 0/1 function on the displacement space (or None).

        A resumed sweep restores it (:meth:`set_zone_indicator`) so that its iterates are
        those of the uninterrupted run: to the last bit serially; under MPI to round-off, as
        MUMPS' parallel factorization does not repeat its last bits from run to run.
        """
        if self.zone.Z is None:
            return None
        u = dolfinx.fem.Function(self.system.problem.V)
        u.x.petsc_vec.array[self.zone.owned_zone()] = 1.0
        u.x.scatter_forward()
        return u

    def set_zone_indicator(self, u: dolfinx.fem.Function) -> None:
        """Make the dofs where ``u`` is 1 the contact zone (collective)."""
        self.zone.set_owned_zone(np.flatnonzero(u.x.petsc_vec.array_r > 0.5))
