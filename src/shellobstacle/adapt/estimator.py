"""A posteriori error indicators of the membrane obstacle problem (the model page's
:eq:`estimator`; docs/model.md §9).

For a discrete solution ``ζ_h`` and a contact force density ``Λ ≥ 0`` (per unit ``dy``) that
pushes along ``c = (a^i·q)``, the residual of the equilibrium equations is the functional
``Res(η) = ∫ p^i η_i √a dy + ∫ Λ c_i η_i dy − ε ∫ a^{αβστ} γ_στ(ζ_h) γ_αβ(η) √a dy``.
Integrating by parts on each cell ``T`` (``n^{αβ} = ε a^{αβστ} γ_στ(ζ_h)``) splits it into

- the element residuals ``r_σ = √a (p^σ + n^{σβ}|_β) + Λ c_σ`` (``σ = 1, 2``; the covariant
  divergence of :func:`~shellobstacle.models.membrane.stress_divergence`) and
  ``r_3 = √a (p^3 + b_αβ n^{αβ}) + Λ c_3``: the strong form :eq:`strong-form`;
- the jumps ``J_σ = [√a n^{σβ} ν_β]`` of the membrane traction across interior edges.

``η_α ∈ H¹₀`` and ``η_3 ∈ L²`` (the space ``V_M``), so the dual norm weighs ``r_σ`` and ``J_σ``
by ``h`` and ``r_3`` by 1. With the complementarity term of Braess (2005) and Veeser (2001),
``∫ Λ |g(ζ_h)| dy`` (the contact force where the shell is off the plane, or inside it), the
indicator of a cell is

``η_T² = (h_T² ‖(r_1, r_2)‖²_T + ‖r_3‖²_T + ½ Σ_{E⊂∂T} h_E ‖J‖²_E) / (4με)²``
``+ ∫_T Λ |g(ζ_h)| dy / (4με)``

(``4μ`` the smallest eigenvalue of ``a^{αβστ}``: the scale that makes ``η`` comparable with
the ``V_M`` norm of the error). ``Λ`` is the penalty's ``(ε/κ) {g(ζ_h)}^- / |c|`` for a
penalized solution (``Res`` then vanishes on the discrete space: the penalized equation), or
the exact solver's contact pressure times ``√a`` for the discrete variational inequality.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import numpy as np
import ufl

from shellobstacle.models.membrane import membrane_stress, stress_divergence
from shellobstacle.models.problem import PenalizedProblem

__all__ = ["ErrorEstimator", "Indicators", "penalty_force"]

#: the parts of the indicator, each a cellwise vector of squares
PARTS = ("tangential", "normal", "jump", "contact")


@dataclass
class Indicators:
    """The squared indicators of the owned cells and their parts.

    Attributes:
        eta2: ``η_T²`` of the owned cells (local order).
        parts: the same per part (:data:`PARTS`), summing to ``eta2``.
        comm: the mesh's communicator.
    """

    eta2: np.ndarray
    parts: dict[str, np.ndarray]
    comm: MPI.Comm

    @property
    def total(self) -> float:
        """``η = (Σ_T η_T²)^{1/2}`` over the whole mesh."""
        return float(np.sqrt(self.comm.allreduce(float(self.eta2.sum()), op=MPI.SUM)))

    def part_totals(self) -> dict[str, float]:
        """``(Σ_T part_T)^{1/2}`` of each part over the whole mesh."""
        return {
            k: float(np.sqrt(self.comm.allreduce(float(v.sum()), op=MPI.SUM)))
            for k, v in self.parts.items()
        }


def penalty_force(problem: PenalizedProblem) -> Any:
    """``Λ = (ε/κ(x)) {g(ζ)}^- / |c|``: the penalty's contact force per unit ``dy`` (UFL),
    the pointwise expression that the penalty's Gauss rule samples."""
    eps = problem.shell.material.epsilon
    g_plus = ufl.conditional(ufl.lt(problem.g, 0), -problem.g, 0)  # {g}^-
    return eps / problem.kappa_x * g_plus / problem.c_norm


class ErrorEstimator:
    """The cellwise indicators :math:`η_T` of one problem, compiled once (per mesh).

    Args:
        problem: the compiled problem; its ``zeta`` is read at each :meth:`__call__`.
        force: ``Λ``, the contact force per unit ``dy`` as a UFL expression or Function
            (default: the penalty's, :func:`penalty_force`, or for the vertex rule its
            vertex values interpolated in P1). For the exact discrete VI pass
            ``√a`` times the active-set solver's contact pressure
            (:meth:`for_exact_solution`).
    """

    def __init__(self, problem: PenalizedProblem, force: Any = None) -> None:
        if problem.model != "membrane":
            raise ValueError("the error indicators are those of the membrane model")
        self.problem = problem
        mesh = problem.mesh
        G = problem.G
        mat = problem.shell.material
        eps, lam, mu = mat.epsilon, mat.lam, mat.mu
        self._nodal: tuple[dolfinx.fem.Function, dolfinx.fem.Expression] | None = None
        if force is None:
            force = penalty_force(problem)
            if problem.disc.penalty_quadrature == "vertex":
                # the vertex rule's force: its values at the vertices, interpolated in P1
                P1 = dolfinx.fem.functionspace(mesh, ("Lagrange", 1))
                nodal = dolfinx.fem.Function(P1, name="penalty_force")
                self._nodal = (
                    nodal,
                    dolfinx.fem.Expression(force, P1.element.interpolation_points),
                )
                force = nodal
        self.force = Lam = force
        zeta = problem.zeta
        gamma = problem.strain_of(zeta)
        n = membrane_stress(G, eps, lam, mu, gamma)
        dn = [[[ufl.grad(n[al][be])[s] for s in range(2)] for be in range(2)] for al in range(2)]
        div = stress_divergence(G, n, dn)
        sqrt_a = G.sqrt_a
        c = problem.c
        p = problem.p
        r_t = [sqrt_a * (p[s] + div[s]) + Lam * c[s] for s in range(2)]
        normal = sum(G.b_lower[al][be] * n[al][be] for al in range(2) for be in range(2))
        r_3 = sqrt_a * (p[2] + normal) + Lam * c[2]
        nu = ufl.FacetNormal(mesh)
        jumps = [
            ufl.jump(ufl.as_vector([sqrt_a * n[s][0], sqrt_a * n[s][1]]), nu) for s in range(2)
        ]
        self.W = W = dolfinx.fem.functionspace(mesh, ("DG", 0))
        w = ufl.TestFunction(W)
        scale = 4.0 * mu * eps
        q = problem.disc.qdegree
        dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": q})
        dS = ufl.Measure("dS", domain=mesh, metadata={"quadrature_degree": q})
        h = ufl.CellDiameter(mesh)
        h_E = ufl.FacetArea(mesh)
        gap_abs = abs(problem.g)
        integrands = {
            "tangential": h**2 * (r_t[0] ** 2 + r_t[1] ** 2) / scale**2 * w * dx,
            "normal": r_3**2 / scale**2 * w * dx,
            "jump": h_E("+") * (jumps[0] ** 2 + jumps[1] ** 2) / scale**2 * ufl.avg(w) * dS,
            "contact": Lam * gap_abs / scale * w * dx,
        }
        self.forms = {k: dolfinx.fem.form(v) for k, v in integrands.items()}

    @classmethod
    def for_exact_solution(
        cls, problem: PenalizedProblem, contact_pressure: dolfinx.fem.Function
    ) -> ErrorEstimator:
        """The indicators of the exact discrete VI: ``Λ = √a λ/m``, the active-set solver's
        contact pressure (per unit surface ``√a dy``) turned into a force per unit ``dy``."""
        return cls(problem, problem.G.sqrt_a * contact_pressure)

    def __call__(self) -> Indicators:
        """The indicators of the current ``problem.zeta`` (collective)."""
        if self._nodal is not None:
            nodal, expression = self._nodal
            nodal.interpolate(expression)
            nodal.x.scatter_forward()
        n_owned = self.W.dofmap.index_map.size_local
        parts = {}
        for name, form in self.forms.items():
            vec = dolfinx.fem.assemble_vector(form)
            vec.scatter_reverse(dolfinx.la.InsertMode.add)
            parts[name] = np.array(vec.array[:n_owned])
        eta2 = sum(parts.values())
        return Indicators(eta2, parts, self.problem.mesh.comm)
