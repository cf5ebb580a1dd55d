"""Koiter's geometrically nonlinear shell model and its C⁰ interior-penalty discretization
(docs/model.md §11, :eq:`nonlinear-koiter-energy`; Ciarlet 2005, §4.1).

The deformed middle surface is ``φ = θ + ζ_i a^i``; its covariant basis ``ã_α = ∂_α φ`` and
unit normal ``ã_3 = ã_1 ∧ ã_2 / |ã_1 ∧ ã_2|`` give the membrane strain
``E_αβ = ½(ã_α·ã_β − a_αβ)`` and the bending strain ``K_αβ = ∂_αβ φ·ã_3 − b_αβ``, whose
linear parts at ``ζ = 0`` are ``γ_αβ`` and ``ρ_αβ`` of the linear model. The energy weighs
them with the linear model's elasticity tensor
(:func:`~shellobstacle.models.membrane.elastic_product`) and its ``ε``, ``ε³/3``.

A P2 ``ζ`` is continuous but its derivatives are not: ``∂_αβ φ`` is taken cell by cell (the
broken Hessian) and the kink of the deformed surface across a facet enters through the facet
terms of the linear C⁰ interior penalty (:func:`~shellobstacle.models.koiter.bending_energy`),
``ρ`` replaced by ``K(ζ)`` and the jump ``[∂_n η_3]`` by (:eq:`nonlinear-jump`)::

    j_F(ζ) = ½ (ã_3⁺·∂_{n⁻}φ⁻ + ã_3⁻·∂_{n⁺}φ⁺)   (interior facets),
    j_F(ζ) = a_3·∂_n φ                           (the clamped boundary),

``n^±`` the outward normals in ω of the facet's two cells. ``j_F`` is frame-indifferent,
vanishes where the deformed surface is C¹ across the facet (and where the clamped edge keeps
its normal), and its derivative there is ``ã_3·[∂_n v]``, the term that integrating the
bending moment by parts on each cell leaves: the method is consistent. At ``ζ = 0`` that
derivative is ``[∂_n v_3]``, so the second variation at ``ζ = 0`` is the linear C⁰ interior
penalty's form.
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI  # noqa: F401  (before PETSc: the MPI runtime PETSc links to)
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np
import ufl

from shellobstacle.geometry.surface import Geometry
from shellobstacle.models.edges import boundary_parts, dirichlet_bcs, rotation_measure
from shellobstacle.models.koiter import (
    DEFAULT_INTERIOR_PENALTY,
    bending_moment,
    facet_stiffness,
    normal_normal,
)
from shellobstacle.models.membrane import elastic_product
from shellobstacle.models.problem import load_ufl, require_koiter_discretization
from shellobstacle.obstacle import Obstacle, from_spec
from shellobstacle.penalty.rule import penalty_measure
from shellobstacle.spec import Discretization, Shell

__all__ = [
    "FAST_COMPILE",
    "NonlinearKoiterProblem",
    "basis_derivatives",
    "bending_strain",
    "deformed_normal",
    "displacement_derivatives",
    "membrane_strain",
    "nonlinear_bending_energy",
    "normal_jump",
]

Tensor2 = list[list[Any]]

#: DOLFINx's JIT options for the nonlinear forms: their kernels are large, and ``-O0``
#: compiles them many times faster than the default ``-O2`` (for a slower assembly)
FAST_COMPILE: dict[str, Any] = {"cffi_extra_compile_args": ["-O0", "-g0"], "timeout": 600}


def basis_derivatives(G: Geometry) -> tuple[list[list[Any]], list[list[list[Any]]]]:
    """``(∂_α a^i, ∂_αβ a^i)`` as UFL vectors, ``[α][i]`` and ``[α][β][i]``, from the Gauss and
    Weingarten formulas ``∂_α a^σ = −Γ^σ_ατ a^τ + b^σ_α a_3``, ``∂_α a_3 = −b^τ_α a_τ`` and
    their derivatives; ``∂_β Γ^σ_ατ = ∂_β ∂_α a_τ·a^σ + ∂_α a_τ·∂_β a^σ`` differentiates only
    the entries of ``∂_αβ θ`` in UFL (``∂_β b^σ_α`` is ``b^σ_{α|β}`` less its Christoffel
    terms)."""
    r = range(2)
    vec = ufl.as_vector
    C, bm, bd = G.christoffel, G.b_mixed, G.b_covariant_derivative  # bm[α][σ] = b^σ_α
    up, cov, a3 = [vec(v) for v in G.a_contra[:2]], [vec(v) for v in G.a_cov], vec(G.a3)
    d2 = [[vec(G.d2[al][be]) for be in r] for al in r]
    d_up = [
        [-sum(C[s][al][t] * up[t] for t in r) + bm[al][s] * a3 for s in r]
        + [-sum(bm[al][t] * cov[t] for t in r)]
        for al in r
    ]
    # d3[β][α][τ] = ∂_β ∂_α a_τ (a constant entry of ∂_αβ θ has no UFL gradient)
    d3 = [
        [
            [vec([ufl.grad(c)[be] if _varies(c) else 0.0 for c in G.d2[al][t]]) for t in r]
            for al in r
        ]
        for be in r
    ]

    def d_christoffel(be: int, s: int, al: int, t: int) -> Any:  # ∂_β Γ^σ_ατ
        return ufl.dot(d3[be][al][t], up[s]) + ufl.dot(d2[al][t], d_up[be][s])

    def d_curvature(be: int, s: int, al: int) -> Any:  # ∂_β b^σ_α
        return (
            bd[be][s][al]
            - sum(C[s][be][t] * bm[al][t] for t in r)
            + sum(C[t][be][al] * bm[t][s] for t in r)
        )

    dd_up = [
        [
            [
                -sum(d_christoffel(be, s, al, t) * up[t] + C[s][al][t] * d_up[be][t] for t in r)
                + d_curvature(be, s, al) * a3
                + bm[al][s] * d_up[be][2]
                for s in r
            ]
            + [-sum(d_curvature(be, t, al) * cov[t] + bm[al][t] * d2[be][t] for t in r)]
            for be in r
        ]
        for al in r
    ]
    return d_up, dd_up


def _varies(c: Any) -> bool:
    """Whether the scalar ``c`` is a UFL expression of the spatial coordinate."""
    return isinstance(c, ufl.core.expr.Expr) and ufl.domain.extract_unique_domain(c) is not None


def displacement_derivatives(G: Geometry, zeta: Any) -> tuple[list[Any], list[list[Any]]]:
    """``(∂_α u, ∂_αβ u)`` of ``u = ζ_i a^i`` (UFL vectors; the Hessian cell by cell)."""
    r = range(2)
    d_up, dd_up = basis_derivatives(G)
    up = [ufl.as_vector(v) for v in G.a_contra]
    grad, hess = ufl.grad(zeta), ufl.grad(ufl.grad(zeta))
    du = [sum(grad[i, al] * up[i] + zeta[i] * d_up[al][i] for i in range(3)) for al in r]
    ddu = [
        [
            sum(
                hess[i, al, be] * up[i]
                + grad[i, al] * d_up[be][i]
                + grad[i, be] * d_up[al][i]
                + zeta[i] * dd_up[al][be][i]
                for i in range(3)
            )
            for be in r
        ]
        for al in r
    ]
    return du, ddu


def deformed_normal(G: Geometry, du: list[Any]) -> Any:
    """``ã_3 = ã_1 ∧ ã_2 / |ã_1 ∧ ã_2|`` with ``ã_α = a_α + ∂_α u``."""
    normal = ufl.cross(ufl.as_vector(G.a_cov[0]) + du[0], ufl.as_vector(G.a_cov[1]) + du[1])
    return normal / ufl.sqrt(ufl.dot(normal, normal))


def membrane_strain(G: Geometry, du: list[Any]) -> Tensor2:
    """``E_αβ = ½(ã_α·ã_β − a_αβ)``, written ``½(a_α·∂_β u + a_β·∂_α u + ∂_α u·∂_β u)`` (no
    cancellation of ``a_αβ``)."""
    a = [ufl.as_vector(v) for v in G.a_cov]
    return [
        [
            0.5 * (ufl.dot(a[al], du[be]) + ufl.dot(a[be], du[al]) + ufl.dot(du[al], du[be]))
            for be in range(2)
        ]
        for al in range(2)
    ]


def bending_strain(G: Geometry, du: list[Any], ddu: list[list[Any]]) -> Tensor2:
    """``K_αβ = ∂_αβ φ·ã_3 − b_αβ``, written ``∂_αβ θ·(ã_3 − a_3) + ∂_αβ u·ã_3``."""
    normal = deformed_normal(G, du)
    change = normal - ufl.as_vector(G.a3)
    return [
        [
            ufl.dot(ufl.as_vector(G.d2[al][be]), change) + ufl.dot(ddu[al][be], normal)
            for be in range(2)
        ]
        for al in range(2)
    ]


def normal_jump(G: Geometry, du: list[Any], n: Any, interior: bool) -> Any:
    """``j_F`` of the module docstring on the interior facets (``interior``: restricted to
    ``+`` and ``−``) or on the clamped boundary; ``du``: ``∂_α u``
    (:func:`displacement_derivatives`), ``n``: the facet normal."""
    if not interior:  # a_3·∂_n φ = a_3·∂_n u
        return ufl.dot(ufl.as_vector(G.a3), sum(n[al] * du[al] for al in range(2)))
    a = [ufl.as_vector(G.a_cov[al]) + du[al] for al in range(2)]
    d_n = sum(n[al] * a[al] for al in range(2))  # ∂_n φ
    normal = deformed_normal(G, du)
    return 0.5 * (ufl.dot(normal("+"), d_n("-")) + ufl.dot(normal("-"), d_n("+")))


def nonlinear_bending_energy(
    G: Geometry,
    epsilon: Any,
    lam: Any,
    mu: Any,
    zeta: Any,
    dx: ufl.Measure,
    sigma: Any,
    ds_clamped: ufl.Measure | None,
) -> ufl.Form:
    """The bending energy of :eq:`nonlinear-koiter-c0ip`: the linear C⁰ interior penalty's
    (:func:`~shellobstacle.models.koiter.bending_energy`) with ``ρ`` → ``K(ζ)`` and
    ``[∂_n η_3]`` → ``j_F(ζ)``; its arguments are that function's."""
    mesh = zeta.function_space.mesh
    degree = dx.metadata().get("quadrature_degree")
    meta = {"quadrature_degree": degree} if degree else {}
    dS = ufl.Measure("dS", domain=mesh, metadata=meta)
    du, ddu = displacement_derivatives(G, zeta)
    K = bending_strain(G, du, ddu)
    cells = 0.5 * (epsilon**3 / 3) * elastic_product(G, lam, mu, K, K) * G.sqrt_a * dx

    n = ufl.FacetNormal(mesh)
    h = ufl.CellDiameter(mesh)
    M_nn = G.sqrt_a * normal_normal(bending_moment(G, epsilon, lam, mu, K), n)
    C_F = facet_stiffness(G, epsilon, lam, mu, n)
    jump = normal_jump(G, du, n, interior=True)
    h_avg = (h("+") + h("-")) / 2
    interior = (-ufl.avg(M_nn) * jump + 0.5 * (sigma / h_avg) * ufl.avg(C_F) * jump * jump) * dS
    energy = cells + interior
    if ds_clamped is not None:
        j = normal_jump(G, du, n, interior=False)
        energy += (-M_nn * j + 0.5 * (sigma / h) * C_F * j * j) * ds_clamped
    return energy


class NonlinearKoiterProblem:
    """The nonlinear Koiter shell on one mesh (docs/model.md §11): ``J(ζ) = E_m(ζ) + E_b(ζ)
    − s ∫ p^i ζ_i √a dy``, plus, with a penalty parameter ``κ``, the obstacle's penalty
    ``(ε/(2κ)) ∫ ({g(ζ)}⁻)² / |c| dy`` of :eq:`penalized-energy` (the obstacle's own gap
    ``g(ζ)``, exact for a curved obstacle too: the energy is not convex anyway); its first and
    second variations as UFL forms, ``s`` a load factor (a ``Constant``).

    Attributes:
        zeta: the displacement (covariant components), a P2 vector Lagrange function.
        load_factor: ``s``; parameters: the load's parameters, ``Constant`` objects by name.
        membrane, bending, work: the energy's parts (UFL forms); energy: ``J`` (with the
            penalty); residual and jacobian: its first and second variations (UFL forms);
            load: ``f``, the load's linear form at ``s = 1``.
        parts, bcs: the parts of γ by condition (:mod:`~shellobstacle.models.edges`) and
            their Dirichlet conditions (the rotation's, weakly, are the bending energy's).
        kappa: ``κ`` (a ``Constant``), or None without obstacle; obstacle, g, c_norm: the
            obstacle and its gap, as :class:`~shellobstacle.models.problem.PenalizedProblem`'s
            (which the post-processing reads).
        dx, ds, dx_penalty, sigma: the measures (the linear model's quadrature degree and
            penalty rule) and the penalty ``σ`` (a ``Constant``).
    """

    #: the hybrid form's multiplier (none here), the curved obstacle's linearization (none)
    t = None
    zeta_lin = None
    kappa_scale = None
    custom_load = False

    def __init__(
        self,
        shell: Shell,
        mesh: dolfinx.mesh.Mesh,
        discretization: Discretization | None = None,
        load_factor: float = 1.0,
        jit_options: dict[str, Any] | None = None,
        kappa: float | None = None,
    ) -> None:
        """``jit_options``: DOLFINx's, for the forms (their kernels are large: ``-O0`` compiles
        them many times faster than the default ``-O2``, for a slower assembly); ``kappa``: the
        obstacle's penalty parameter (None: no obstacle)."""
        disc = discretization or Discretization(degree=2, bending="c0ip")
        require_koiter_discretization(disc, mesh)
        if disc.bending != "c0ip":
            raise ValueError(
                "the nonlinear Koiter energy has the C⁰ interior-penalty bending form only: "
                "set discretization.bending = 'c0ip'"
            )
        self.shell, self.mesh, self.disc = shell, mesh, disc
        self.parts = boundary_parts(shell, mesh, disc.transverse)
        self.V = dolfinx.fem.functionspace(mesh, ("Lagrange", disc.degree, (3,)))
        self.zeta = zeta = dolfinx.fem.Function(self.V, name="zeta")
        self.load_factor = dolfinx.fem.Constant(mesh, PETSc.ScalarType(load_factor))
        self.p, self.parameters = load_ufl(shell, mesh)
        p = self.p
        self.sigma = dolfinx.fem.Constant(
            mesh, PETSc.ScalarType(disc.interior_penalty or DEFAULT_INTERIOR_PENALTY)
        )
        self.G = G = shell.surface.geometry_ufl(mesh)
        mat = shell.material
        eps, lam, mu = mat.epsilon, mat.lam, mat.mu
        meta = {"quadrature_degree": disc.qdegree}
        self.dx = dx = ufl.Measure("dx", domain=mesh, metadata=meta)
        self.ds = rotation_measure(mesh, self.parts, meta)
        E = membrane_strain(G, displacement_derivatives(G, zeta)[0])
        self.membrane = 0.5 * eps * elastic_product(G, lam, mu, E, E) * G.sqrt_a * dx
        self.bending = nonlinear_bending_energy(G, eps, lam, mu, zeta, dx, self.sigma, self.ds)
        work = sum(p[i] * zeta[i] for i in range(3)) * G.sqrt_a * dx
        self.work = self.load_factor * work
        self.load = ufl.derivative(work, zeta, ufl.TestFunction(self.V))
        self.energy = self.membrane + self.bending - self.work
        self.obstacle: Obstacle = from_spec(shell.obstacle, eps)
        self.q = np.asarray(shell.obstacle.q, dtype=float)
        self.kappa: dolfinx.fem.Constant | None = None
        self.penalty: ufl.Form | None = None
        if kappa is not None:
            self._penalty(kappa)
            self.energy = self.energy + self.penalty
        self.residual = ufl.derivative(self.energy, zeta, ufl.TestFunction(self.V))
        self.jacobian = ufl.derivative(self.residual, zeta, ufl.TrialFunction(self.V))
        self.bcs = dirichlet_bcs(self.V, self.parts)
        self.jit_options = jit_options
        self._newton: dolfinx.fem.petsc.NonlinearProblem | None = None
        self._scalars: dict[str, dolfinx.fem.Form] = {}

    def _penalty(self, kappa: float) -> None:
        """``(ε/(2κ)) ∫ ({g(ζ)}⁻)² / |c| dy`` with the obstacle owner's gap, weight and measure
        (:eq:`penalized-energy`)."""
        obstacle = self.obstacle.on_mesh(self.mesh)
        self.kappa = dolfinx.fem.Constant(self.mesh, PETSc.ScalarType(kappa))
        self.g = self.g_penalty = obstacle.gap(self.G, [self.zeta[i] for i in range(3)])
        self.c_norm = obstacle.c_norm(self.G)
        self.dx_penalty = penalty_measure(self.mesh, self.disc, self.dx)
        g_minus = ufl.conditional(ufl.lt(self.g, 0), self.g, 0)
        eps = self.shell.material.epsilon
        self.penalty = (eps / (2 * self.kappa)) * g_minus**2 / self.c_norm * self.dx_penalty

    # what the post-processing and the result read of a penalized problem

    model = "koiter"
    linearized = False

    @property
    def penalized(self) -> bool:
        """Whether the obstacle's penalty is in the energy."""
        return self.kappa is not None

    @property
    def num_dofs(self) -> int:
        """Global number of degrees of freedom (all three components)."""
        im = self.V.dofmap.index_map
        return im.size_global * self.V.dofmap.index_map_bs

    def set_kappa(self, kappa: float) -> None:
        """Change ``κ`` without recompiling."""
        if self.kappa is None or not kappa > 0:
            raise ValueError(f"set_kappa needs a penalized problem and kappa > 0, got {kappa}")
        self.kappa.value = kappa

    def linearize(self) -> None:
        """Nothing: the penalty reads the obstacle's exact gap."""

    def update_multiplier(self) -> None:
        """Nothing: the C⁰ interior-penalty form has no multiplier."""

    def scalar(self, name: str) -> float:
        """``"elastic_energy"`` (``E_m + E_b``), ``"work"`` (at the load factor),
        ``"penalty_energy"`` or ``"energy"`` (``J``) at the current ``ζ`` (collective)."""
        if name not in self._scalars:
            forms = {"elastic_energy": self.membrane + self.bending, "work": self.work,
                     "energy": self.energy, "penalty_energy": self.penalty}  # fmt: skip
            self._scalars[name] = dolfinx.fem.form(forms[name], jit_options=self.jit_options)
        local = dolfinx.fem.assemble_scalar(self._scalars[name])
        return float(self.mesh.comm.allreduce(local))

    def energies(self) -> dict[str, float]:
        """``J(ζ)`` without and with the penalty term, and the term (0 without obstacle)."""
        el, w = self.scalar("elastic_energy"), self.scalar("work")
        pen = self.scalar("penalty_energy") if self.penalized else 0.0
        return {"energy": el - w, "penalty_energy": pen, "penalized_energy": el - w + pen}

    def solve(self, rtol: float = 1e-10, max_it: int = 30) -> int:
        """Newton's method with full steps from the current ``ζ`` (SNES ``newtonls`` with the
        basic line search, LU), stopped when the residual has fallen by ``rtol`` or the step is
        below ``rtol ‖ζ‖`` (the residual's round-off can stay above the first); returns its
        iterations. Raises RuntimeError when it fails to converge."""
        if self._newton is None:
            options = {
                "snes_type": "newtonls",
                "snes_linesearch_type": "basic",
                "snes_atol": 0.0,
                "ksp_type": "preonly",
                "pc_type": "lu",
                "pc_factor_mat_solver_type": "mumps",
            }
            self._newton = dolfinx.fem.petsc.NonlinearProblem(
                self.residual, self.zeta, bcs=self.bcs, J=self.jacobian,
                petsc_options_prefix="nonlinear_koiter_", petsc_options=options,
                jit_options=self.jit_options,
            )  # fmt: skip
        snes = self._newton.solver
        snes.setTolerances(rtol=rtol, stol=rtol, max_it=max_it)
        self._newton.solve()
        if snes.getConvergedReason() <= 0:
            raise RuntimeError(
                f"Newton's method on the nonlinear Koiter energy failed (SNES reason "
                f"{snes.getConvergedReason()}): apply the load in smaller steps"
            )
        return snes.getIterationNumber()
