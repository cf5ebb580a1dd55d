"""What ``"auto"`` stands for in a solve: one decision from the problem, with its reasons.

``solver.linear_solver = "auto"`` and ``solver.nested_iteration = "auto"`` (the defaults) are
resolved once per solve by :func:`resolve`, from the problem alone: its model and degree, its
dofs, the mesh's coarser levels and the number of ranks. The machine's memory plays no part
(it only refuses what cannot fit, :mod:`~shellobstacle.mesh.resources`), so one config takes
the same numerical path on every machine.

* The linear solver (:func:`linear_solver_rule`): multigrid for the membrane P1 from
  :data:`MULTIGRID_FROM_DOFS` dofs on a mesh with coarser levels, the direct path else
  (Koiter's multigrid is taken when asked for).
* Nested iteration: on with multigrid on one rank, with P1, where :func:`check_nested`
  passes; off else (on several ranks the coarser levels' small solves gain nothing,
  docs/perf/multigrid.md).

Importing this module loads neither DOLFINx nor PETSc (the options' help quotes
:data:`MULTIGRID_FROM_DOFS`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from shellobstacle.mesh.domains import DomainSpec, coarsening_steps
from shellobstacle.mesh.resources import estimate

if TYPE_CHECKING:
    from shellobstacle.models.problem import PenalizedProblem

__all__ = [
    "AUTO",
    "MULTIGRID_FROM_DOFS",
    "Resolution",
    "check_nested",
    "estimated_linear_solver",
    "linear_solver_rule",
    "resolve",
    "takes_linear_solver",
]

#: From this many dofs "auto" takes multigrid for the membrane P1 on a mesh with coarser
#: levels: above it multigrid never lost to the direct path on the paper's problem, at
#: 0.33–0.66 M the two were on par (docs/perf/multigrid.md).
MULTIGRID_FROM_DOFS = 1.0e6
#: the options that may say "auto", in the order they are resolved
AUTO = ("linear_solver", "nested_iteration")


@dataclass(frozen=True)
class Resolution:
    """The options of a solve with every ``"auto"`` replaced, and why each has its value.

    Attributes:
        options: the options asked for, ``"auto"`` replaced by what it stands for.
        asked: option → the value asked for (``"auto"`` or a value).
        reasons: option → why it has its value (``"asked for"`` unless it was ``"auto"``).
    """

    options: Any
    asked: Mapping[str, str]
    reasons: Mapping[str, str]

    def record(self) -> dict[str, dict[str, str]]:
        """The summary's ``choices``: per option, the value asked for, the value chosen and
        why."""
        record = {}
        for name, asked in self.asked.items():
            chosen = getattr(self.options, name)
            record[name] = {"asked": asked, "chosen": chosen, "reason": self.reasons[name]}
        return record

    def said(self) -> str:
        """One progress line for what ``"auto"`` chose other than the direct path ("" for
        none)."""
        chosen = self.asked.get("linear_solver") == "auto" and self.options.linear_solver
        if not chosen or chosen == "direct":
            return ""
        return f'linear solver: {chosen} ("auto": {self.reasons["linear_solver"]})'


def takes_linear_solver(method: Any) -> bool:
    """Whether ``method`` (a :class:`~shellobstacle.solvers.registry.Method`) takes a linear
    solver: its options declare ``linear_solver``; the others factorize."""
    kind = method.options_type
    return kind is not None and any(f.name == "linear_solver" for f in dataclasses.fields(kind))


def linear_solver_rule(model: str, degree: int, dofs: float, levels: bool) -> tuple[str, str]:
    """What ``solver.linear_solver = "auto"`` stands for on a problem of ``model`` with
    Lagrange ``degree`` and ``dofs`` dofs on a mesh with (``levels``) or without coarser
    levels, and why."""
    if model == "koiter":
        return "direct", 'Koiter\'s model takes multigrid when asked for ("multigrid")'
    if (model, degree) != ("membrane", 1):
        return "direct", f"multigrid was not measured on the {model} model with degree {degree}"
    if not levels:
        return "direct", "the mesh has no coarser levels for multigrid"
    size = f"{MULTIGRID_FROM_DOFS / 1e6:g} M"
    if dofs < MULTIGRID_FROM_DOFS:
        return "direct", f"below {size} dofs the direct path is as fast"
    return "multigrid", f"from {size} dofs on a refined mesh it is the faster"


def estimated_linear_solver(
    method: Any, options: Any, spec: DomainSpec, model: str, degree: int
) -> str:
    """The linear solver whose memory the refusal before meshing estimates
    (:func:`~shellobstacle.mesh.resources.require_fits`): a factorization for a ``method``
    without a linear solver, the one ``options`` ask for (None: the method's defaults), and
    for ``"auto"`` :func:`linear_solver_rule` at the estimated dofs of ``spec``'s mesh (the
    solve resolves it from the problem made, :func:`resolve`)."""
    if not takes_linear_solver(method):
        return "direct"
    asked = (options if options is not None else method.options_type()).linear_solver
    if asked != "auto":
        return asked
    size = estimate(spec, model, degree)
    if size is None:
        return "direct"
    levels = coarsening_steps(spec) + spec.refinements > 0
    return linear_solver_rule(model, degree, size.dofs, levels)[0]


def check_nested(problem: PenalizedProblem) -> None:
    """Raise ValueError, naming the fix, when nested iteration
    (:mod:`~shellobstacle.solvers.newton.nested`) cannot solve ``problem``."""
    from shellobstacle.mesh.hierarchy import coarser_meshes
    from shellobstacle.solvers.newton.normal_relaxation import require_membrane

    key = "solver.nested_iteration"
    require_membrane(problem, key)
    if not coarser_meshes(problem.mesh):
        raise ValueError(
            f"{key} needs a mesh made by uniform refinement: set domain.refinements >= 1 "
            "(or solve a mesh large enough that gmsh_max_vertices refines it)"
        )
    if problem.kappa_scale is not None or problem.custom_load:
        raise ValueError(
            f"{key} rebuilds the shell on the coarser meshes from its config: a problem with "
            "a load or penalty scale given as functions on its mesh cannot use it"
        )


def _nested_rule(problem: PenalizedProblem, linear_solver: str) -> tuple[str, str]:
    """What ``solver.nested_iteration = "auto"`` stands for with ``linear_solver``, and why."""
    if problem.mesh.comm.size > 1:
        return "off", "on several ranks it is slower than the plain continuation"
    if linear_solver != "multigrid" or problem.disc.degree != 1:
        return "off", f"it pays with multigrid on P1 (here {linear_solver}, P{problem.disc.degree})"
    try:
        check_nested(problem)
    except ValueError as err:
        return "off", str(err)
    return "on", "multigrid on one rank"


def resolve(problem: PenalizedProblem, options: Any) -> Resolution:
    """Every ``"auto"`` of ``options`` (a method's options: their ``linear_solver`` and
    ``nested_iteration``, where they have them) resolved from ``problem``: its model, degree,
    dofs, the mesh's coarser levels and the number of ranks; never the machine's memory."""
    from shellobstacle.mesh.hierarchy import coarser_meshes

    asked = {name: getattr(options, name) for name in AUTO if hasattr(options, name)}
    chosen, reasons = dict(asked), dict.fromkeys(asked, "asked for")
    if asked.get("linear_solver") == "auto":
        levels = bool(coarser_meshes(problem.mesh))
        chosen["linear_solver"], reasons["linear_solver"] = linear_solver_rule(
            problem.model, problem.disc.degree, problem.num_dofs, levels
        )
    if asked.get("nested_iteration") == "auto":
        chosen["nested_iteration"], reasons["nested_iteration"] = _nested_rule(
            problem, chosen.get("linear_solver", "direct")
        )
    return Resolution(dataclasses.replace(options, **chosen), asked, reasons)
