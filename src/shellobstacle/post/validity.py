"""Is a computed solution inside the validity of the linear shell model and the penalty method?

A solver can converge to a solution that means nothing physically: a load strong enough to push
the whole shell through the plane, or a load singular inside ω, gives a penalized solution that
penetrates the plane by a large part of the shell's height, or a deformed surface that turns
over itself. Scale-free measures, computed after every solve:

``penetration``
    ``max {g(ζ)}^- / max θ·q``: the largest penetration of the plane against the shell's
    initial height above it (the gap scale), the larger of the one where the constraint acts
    and the one at the nodes (``max_violation``, ``max_violation_nodal``). The penalized
    solution's penetration vanishes as κ → 0; one that is a sizeable part of the height means
    the constraint is not imposed.
``displacement``
    ``max |ζ_i a^i| / diam θ(ω)``: the linearized strain (docs/model.md §2) assumes displacements
    small against the shell; beyond a quarter of its size the linearization is not credible.
    Below :data:`TRIVIAL` under a load that is not zero the solution is *trivial*: the shell
    starts strictly inside the half-space, so ``ζ = 0`` solves only the unloaded problem, and
    a displacement under the round-off of θ's coordinates (``θ + U = θ`` in double precision)
    is no visible response to the load: a load far too small for the material constants (the
    paper's load times 1e-30), or a solver stopped at its start.
``orientation``
    ``min a_3 · (ã_1 ∧ ã_2) / √a`` with the deformed tangent vectors ``ã_α = a_α + ∂_α U``,
    ``U = ζ_i a^i``: 1 for no deformation, ``≤ 0`` where the deformed surface folds over.
``nonlinearity``
    ``E(N) / E(ζ)``: the elastic energy of the quadratic strain ``N_αβ = ½ ∂_αU·∂_βU`` that the
    linear strain ``γ_αβ`` leaves out of the Green–Lagrange strain ``½(ã_α·ã_β − a_αβ)``
    (``U = ζ_i a^i``, ``ã_α = a_α + ∂_αU``), weighed as the membrane energy
    ``½ ε ∫ a^{αβστ} N_στ N_αβ √a dy``, against the elastic energy of the solution. It grows
    like the load squared. Beyond :data:`NONLINEARITY` the linear kinematics are not credible:
    on the clamped plate of docs/model.md §11 (deflections of 0.3 thickness and more) the
    linear deflection is then more than 5 % too large against the Föppl–von Kármán plate's.
    A warning naming ``[model] kinematics = "nonlinear"``, not a violation (the exit status
    stays 0); 0, not computed, for a solution of the nonlinear kinematics.
``penalty_ratio``
    the penetration against ``κ max(√a |p|) / ε``, the penetration at which the penalty force
    ``(ε/κ) {g}^-`` balances the load at a point (docs/model.md §4): how many times the largest
    load the plane's reaction carries somewhere. Recorded, not judged: a membrane's contact
    pressure can be a measure concentrated on curves (the paper's problem: 4.5 at κ = h²,
    39 at κ = h³ on the same mesh), so the ratio grows as κ → 0 with nothing wrong.

A measure beyond its threshold in :data:`THRESHOLDS` makes the result *outside the validity*:
``solve`` warns on the terminal and in ``summary.json`` and exits with status 3
(:data:`~shellobstacle.cli.commands.EXIT_INVALID`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import numpy as np
import ufl

from shellobstacle.models.membrane import elastic_product

__all__ = ["NONLINEARITY", "THRESHOLDS", "Validity", "assess"]

#: Largest accepted value of each measure (``orientation``: smallest accepted value).
THRESHOLDS: dict[str, float] = {
    "penetration": 0.1,
    "displacement": 0.25,
    "orientation": 0.0,
}
#: Largest ``nonlinearity`` for which the linear kinematics are credible: on the clamped plate
#: of docs/model.md §11 (ν = 0.3) the linear centre deflection is 5 % above the Föppl–von
#: Kármán plate's where the measure is 0.035 (linear deflection 0.33 thickness).
NONLINEARITY = 0.035
#: Smallest displacement (of the shell's size) a loaded solution may have: a few hundred times
#: the double-precision round-off of θ's coordinates.
TRIVIAL = 1e-13

_EXPLAIN = {
    "penetration": "of the shell's height above the plane (max θ·q): the constraint is not "
    "imposed; decrease κ (a larger penalty exponent) or check that the load is not far beyond "
    "what the shell can carry",
    "displacement": "of the shell's size: outside the linear model's small displacements; "
    "reduce the load",
    "orientation": "the deformed surface folds over itself somewhere: the load is far beyond "
    "the linear model; reduce it",
    "trivial": "of the shell's size under a load that is not zero: the deformed shell is the "
    "undeformed one in double precision, no response to the load; the load ([load] p) is out "
    "of proportion to material.epsilon, material.lambda and material.mu: give them in units "
    "that make the displacement of ordinary size",
}


@dataclass
class Validity:
    """The measures of the module docstring, their thresholds and the warnings."""

    penetration: float
    displacement: float
    orientation: float
    penalty_ratio: float | None
    thresholds: dict[str, float] = field(default_factory=lambda: dict(THRESHOLDS))
    loaded: bool = True  # the load is not zero everywhere (else ζ = 0 is the solution)
    nonlinearity: float = 0.0
    model: str = "koiter"  # the shell's model, which the nonlinearity's remedy depends on

    @property
    def beyond_linear_kinematics(self) -> bool:
        """The neglected quadratic strain is not small (``nonlinearity > NONLINEARITY``)."""
        return self.nonlinearity > NONLINEARITY

    @property
    def violations(self) -> list[str]:
        """Names of the measures beyond their thresholds."""
        t = self.thresholds
        out = []
        if self.penetration > t["penetration"]:
            out.append("penetration")
        if self.displacement > t["displacement"]:
            out.append("displacement")
        if self.orientation <= t["orientation"]:
            out.append("orientation")
        if self.loaded and not self.displacement >= TRIVIAL:
            out.append("trivial")
        return out

    @property
    def valid(self) -> bool:
        """True when every measure is within its threshold."""
        return not self.violations

    def warnings(self) -> list[str]:
        """One line per violated measure: the value, the threshold and what to do."""
        t, lines = self.thresholds, []
        for name in self.violations:
            if name == "trivial":
                what = f"displacement {self.displacement:.3g} < {TRIVIAL:g} "
            elif name == "orientation":
                what = f"orientation {self.orientation:.3g} ≤ {t[name]:g}, "
            else:
                what = f"{name} {getattr(self, name):.3g} > {t[name]:g} "
            lines.append("outside the model's validity: " + what + _EXPLAIN[name])
        if self.beyond_linear_kinematics:
            scale = (NONLINEARITY / self.nonlinearity) ** 0.5
            lines.append(
                f"beyond linear kinematics: nonlinearity {self.nonlinearity:.3g} > "
                f"{NONLINEARITY:g} (the energy of the quadratic strain ½∂U·∂U the linear model "
                "neglects, against the solution's elastic energy; it grows like the load "
                f"squared): the displacement is credible for loads up to about {scale:.2g} "
                "times this one (docs/model.md §11); "
                + (
                    'set [model] kinematics = "nonlinear"'
                    if self.model == "koiter"
                    else "reduce the load (the membrane has linear kinematics only)"
                )
            )
        return lines

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly record (``summary.json``'s ``validity``)."""
        return {
            "valid": self.valid,
            "penetration": self.penetration,
            "displacement": self.displacement,
            "orientation": self.orientation,
            "penalty_ratio": self.penalty_ratio,
            "thresholds": dict(self.thresholds),
            "loaded": self.loaded,
            "violations": self.violations,
            "nonlinearity": self.nonlinearity,
            "nonlinearity_threshold": NONLINEARITY,
            "beyond_linear_kinematics": self.beyond_linear_kinematics,
        }


def assess(post: Any, kappa: float) -> Validity:
    """The validity measures of ``post.problem``'s current ``ζ`` (global, the same on every
    rank); ``post`` is its :class:`~shellobstacle.post.contact.Postprocessor`, ``kappa`` the
    penalty parameter of the solve (0 for the exact problem: no ``penalty_ratio``)."""
    problem = post.problem
    comm: MPI.Comm = post.comm
    contact = post.contact()
    violation = max(float(contact["max_violation"]), float(contact["max_violation_nodal"]))
    penetration = violation / post.gap_scale if post.gap_scale > 0 else float("inf")

    n_owned = post.P1.dofmap.index_map.size_local
    U = post.cartesian_displacement()
    bs = U.function_space.dofmap.index_map_bs
    Uo = U.x.array.reshape(-1, bs)[: U.function_space.dofmap.index_map.size_local]
    umax = comm.allreduce(float(np.max(np.linalg.norm(Uo, axis=1), initial=0.0)), op=MPI.MAX)
    points = post.P1.tabulate_dof_coordinates()[:n_owned]
    theta = np.asarray(problem.shell.surface.theta_numpy(points), dtype=float)
    lo, hi = theta.min(axis=1, initial=np.inf), theta.max(axis=1, initial=-np.inf)
    comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
    comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
    size = float(np.linalg.norm(hi - lo))

    G, zeta = problem.G, problem.zeta
    degree = max(problem.disc.degree - 1, 0)
    DG = dolfinx.fem.functionspace(problem.mesh, ("DG", degree))
    Ucart = ufl.as_vector(G.cartesian([zeta[i] for i in range(3)]))
    a = [ufl.as_vector(G.a_cov[al]) + Ucart.dx(al) for al in range(2)]
    orientation = ufl.dot(ufl.as_vector(G.a3), ufl.cross(a[0], a[1])) / G.sqrt_a
    load = ufl.sqrt(sum(p * p for p in problem.p)) * G.sqrt_a
    local_orientation, local_load = (
        _cell_values(expr, DG, problem.mesh) for expr in (orientation, load)
    )
    omin = comm.allreduce(float(np.min(local_orientation, initial=np.inf)), op=MPI.MIN)
    pmax = comm.allreduce(float(np.max(local_load, initial=0.0)), op=MPI.MAX)

    ratio = None
    if kappa > 0 and pmax > 0:
        eps = float(problem.shell.material.epsilon)
        ratio = violation / (kappa * pmax / eps)
    displacement = umax / size if size > 0 else float("inf")
    # the nonlinear kinematics neglect no quadratic strain
    linear = problem.shell.kinematics == "linear"
    return Validity(
        penetration, displacement, omin, ratio, loaded=pmax > 0,
        nonlinearity=nonlinearity(problem) if linear else 0.0, model=problem.shell.model,
    )  # fmt: skip


def nonlinearity(problem: Any) -> float:
    """The ``nonlinearity`` of the module docstring at ``problem``'s current ``ζ`` (0 where the
    solution has no elastic energy)."""
    G, zeta, material = problem.G, problem.zeta, problem.shell.material
    dU = [ufl.as_vector(G.cartesian([zeta[i] for i in range(3)])).dx(al) for al in range(2)]
    N = [[0.5 * ufl.dot(dU[al], dU[be]) for be in range(2)] for al in range(2)]
    density = elastic_product(G, material.lam, material.mu, N, N)
    form = dolfinx.fem.form(0.5 * material.epsilon * density * G.sqrt_a * problem.dx)
    neglected = problem.mesh.comm.allreduce(dolfinx.fem.assemble_scalar(form))
    problem.update_multiplier()  # the hybrid form's energy holds at ζ once t is t(ζ)
    elastic = problem.scalar("elastic_energy")
    return float(neglected / elastic) if elastic > 0 else 0.0


def _cell_values(expr: Any, space: dolfinx.fem.FunctionSpace, mesh: dolfinx.mesh.Mesh):
    """Values of ``expr`` at the interpolation points of the owned cells of ``space``."""
    f = dolfinx.fem.Function(space)
    f.interpolate(dolfinx.fem.Expression(expr, space.element.interpolation_points))
    return f.x.array[: space.dofmap.index_map.size_local * space.dofmap.index_map_bs]
