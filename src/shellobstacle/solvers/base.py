"""What every solver shares: PETSc options prefixes, direct solvers, and the failure type
(:class:`~shellobstacle.solvers.result.ConvergenceError`, defined with the results).

Every sparse direct solve of the package (Newton's Jacobian, the contact zone's ``K_II`` and
Schur complement, the coarse seed, the active-set matrix, Brezis–Sibony's mass matrix and
start) is made by :func:`direct_solver` and factorized by :func:`factorize`, so options never
leak between solvers and a MUMPS failure reads the same everywhere.

Every PETSc object takes a prefix ``shellobstacle_<kind><n>_`` (:func:`unique_prefix`). The
user's options (``solver.petsc_options``, the ``petsc_options`` of each options class) reach
the objects of the kinds a solver names, as DOLFINx's ``NonlinearProblem`` puts its
``petsc_options`` under its prefix: :class:`UserOptions`.
"""

from __future__ import annotations

import functools
import itertools
import warnings
import weakref
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from mpi4py import MPI  # (before PETSc: the MPI runtime PETSc links to)
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers.result import ConvergenceError

__all__ = [
    "ConvergenceError",
    "UserOptions",
    "direct_solver",
    "factorization_pc",
    "factorize",
    "set_mumps_controls",
    "set_options",
    "unique_prefix",
    "with_user_options",
]


_NUMBERS = itertools.count()


def unique_prefix(kind: str) -> str:
    """``shellobstacle_<kind><n>_`` with ``n`` never used before in this process.

    A prefix made from ``id()`` can come back once its object is freed, and with it whatever
    options an earlier solver put in PETSc's global options database.
    """
    prefix = f"shellobstacle_{kind}{next(_NUMBERS)}_"
    for user in _APPLIED:
        user.apply(prefix, kind)
    return prefix


#: the user's options in force (:meth:`UserOptions.applied`)
_APPLIED: list[UserOptions] = []


class UserOptions:
    """The user's PETSc options for the objects a solver makes of the given ``kinds``.

    While :meth:`applied`, every prefix :func:`unique_prefix` makes for one of ``kinds`` gets
    ``values`` (option names without the leading ``-``: ``ksp_type``, ``pc_type``,
    ``mat_mumps_icntl_14``, ...); they stay in PETSc's options database until this object is
    freed (the solver keeps it), so that a factorization made later reads them too.

    Args:
        values: option name → value.
        kinds: the prefix kinds that take them (e.g. ``("newton", "zone")``).
        method: names the method in the warning about an option no object read.
        comm: the solver's communicator: an option counts as read when any of its ranks
            read it (PETSc's telescope, for one, makes its inner solver on some ranks only);
            None: this process alone.
    """

    def __init__(
        self,
        values: Mapping[str, Any],
        kinds: tuple[str, ...],
        method: str,
        comm: MPI.Comm | None = None,
    ) -> None:
        self.values, self.kinds, self.method, self.comm = dict(values), kinds, method, comm
        self.prefixes: list[str] = []
        self._names: list[str] = []
        self._reported: set[str] = set()
        weakref.finalize(self, _forget, self._names)

    def apply(self, prefix: str, kind: str) -> None:
        """Put the options under ``prefix`` if ``kind`` is one of this solver's."""
        if kind not in self.kinds or not self.values:
            return
        options = PETSc.Options()
        for key, value in self.values.items():
            options[prefix + key] = value
            self._names.append(prefix + key)
        self.prefixes.append(prefix)

    @contextmanager
    def applied(self) -> Iterator[None]:
        """The objects made in this block get the options; a PETSc error with options given
        is reported as theirs (naming them)."""
        if not self.values:
            yield
            return
        _APPLIED.append(self)
        try:
            yield
        except PETSc.Error as err:
            from shellobstacle.messages import ConfigError

            raise ConfigError(
                f"solver.petsc_options: PETSc failed (error {err.ierr}) with the options "
                f"{self.values} of {self.method}: check their names and values"
            ) from None
        finally:
            _APPLIED.remove(self)

    def report_unused(self) -> None:
        """Warn once about each option that no object of the solver has read, on any of its
        ranks (misspelled, or for an object the method does not make); collective over
        ``comm``."""
        options = PETSc.Options()
        keys = list(self.values)
        used = np.array(
            [any(options.used(p + key) for p in self.prefixes) for key in keys], dtype=np.int8
        )
        if self.comm is not None and self.comm.size > 1:
            self.comm.Allreduce(MPI.IN_PLACE, used, op=MPI.MAX)
        for key, read in zip(keys, used, strict=True):
            if key in self._reported or read:
                continue
            self._reported.add(key)
            warnings.warn(
                f"solver.petsc_options.{key}: no PETSc object of {self.method} read it "
                f"(prefixes shellobstacle_<{'|'.join(self.kinds)}><n>_): misspelled, or an "
                "option of an object the method does not make",
                RuntimeWarning,
                stacklevel=4,
            )


def with_user_options(solve: Callable[..., Any]) -> Callable[..., Any]:
    """Decorate a solver's ``solve`` to run with ``self.user_options`` applied and report its
    unused options afterwards: after a return or a :class:`ConvergenceError`, which every
    rank raises together (the report is collective); any other error propagates at once."""

    @functools.wraps(solve)
    def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
        user: UserOptions = self.user_options
        try:
            with user.applied():
                result = solve(self, *args, **kwargs)
        except ConvergenceError:
            user.report_unused()
            raise
        user.report_unused()
        return result

    return wrapper


def _forget(names: list[str]) -> None:
    options = PETSc.Options()
    for name in names:
        options.delValue(name)


def set_options(owner: object, prefix: str, values: dict[str, Any]) -> None:
    """Put ``values`` under ``prefix`` in the options database until ``owner`` is freed."""
    options = PETSc.Options()
    for key, value in values.items():
        options[prefix + key] = value
    weakref.finalize(owner, _forget, [prefix + key for key in values])


def set_mumps_controls(pc: PETSc.PC, icntl: dict[int, int] | None) -> None:
    """Set MUMPS controls (``ICNTL``) on the factor matrix ``pc`` is about to make."""
    if icntl:
        pc.setFactorSetUpSolverType()
        F = pc.getFactorMatrix()
        for key, value in icntl.items():
            F.setMumpsIcntl(key, value)


def direct_solver(
    A: PETSc.Mat,
    factorization: str = "lu",
    kind: str = "direct",
    package: str = "mumps",
    ordering: str | None = None,
    icntl: dict[int, int] | None = None,
) -> PETSc.KSP:
    """A KSP that solves with a factorization of ``A``, made at its first set-up or solve.

    Args:
        A: the matrix (parallel or sequential). With ``"cholesky"`` it is marked symmetric
            positive definite, which MUMPS' LDLᵀ then uses.
        factorization: ``"lu"`` or ``"cholesky"``.
        kind: names the options prefix (:func:`unique_prefix`).
        package: ``"mumps"``, or ``"petsc"`` (PETSc's own, serial only: cheaper calls for
            tiny matrices) in the given ``ordering`` (e.g. ``"nd"``).
        icntl: MUMPS controls, e.g. ``{7: 2}`` for its ordering.
    """
    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOptionsPrefix(unique_prefix(kind))
    ksp.setOperators(A)
    ksp.setType("preonly")
    if factorization == "cholesky":
        A.setOption(PETSc.Mat.Option.SPD, True)
    factorization_pc(ksp.getPC(), factorization, package, ordering, icntl)
    ksp.setFromOptions()
    return ksp


def factorization_pc(
    pc: PETSc.PC,
    factorization: str,
    package: str = "mumps",
    ordering: str | None = None,
    icntl: dict[int, int] | None = None,
) -> None:
    """Make ``pc`` a factorization (``"lu"`` or ``"cholesky"``) by ``package``: the
    preconditioner of :func:`direct_solver`, and of the CG that reuses a factorization."""
    pc.setType(factorization)
    pc.setFactorSolverType(package)
    if ordering is not None:
        pc.setFactorOrdering(ordering)
    set_mumps_controls(pc, icntl)


def factorize(
    ksp: PETSc.KSP,
    what: str,
    attempts: int = 3,
    prepare: Callable[[PETSc.PC], Any] | None = None,
) -> None:
    """``ksp.setUp()`` for a MUMPS factorization of ``what``, made to succeed or raise.

    MUMPS sizes its working space by the analysis' estimate plus ICNTL(14) percent, and the
    estimate can be short for a distributed dense front (the zone's Schur complement on 2
    ranks). On INFOG(1) = −8 or −9 the analysis and factorization are made again with
    ICNTL(14) doubled, up to ``attempts`` times (setting it on the existing factor does not
    take); any other failure raises. ``prepare(pc)`` runs before every attempt (e.g.
    :func:`~shellobstacle.solvers.zone.mumps.in_blocks`); what it returns is kept until the
    attempt is over.

    Raises:
        ConvergenceError: naming ``what`` and MUMPS' INFOG(1), INFOG(2).
    """
    pc = ksp.getPC()
    for attempt in range(attempts + 1):
        kept = prepare(pc) if prepare is not None else None
        ksp.setUp()
        del kept
        if pc.getFailedReason() == 0:
            return
        F = pc.getFactorMatrix()
        info, icntl = F.getMumpsInfog(1), {key: F.getMumpsIcntl(key) for key in (7, 14)}
        if info not in (-8, -9) or attempt == attempts:
            raise ConvergenceError(
                f"MUMPS could not factorize {what}: INFOG(1) = {info}, INFOG(2) = "
                f"{F.getMumpsInfog(2)} with ICNTL(14) = {icntl[14]} (MUMPS manual, section 8)"
            )
        icntl[14] = max(2 * icntl[14], 20)
        A, P = pc.getOperators()
        pc.reset()
        ksp.setOperators(A, P)
        set_mumps_controls(pc, icntl)
