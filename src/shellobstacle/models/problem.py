"""The discrete penalized problem P_{M,κ}^{ε,h} (docs/model.md §4–5) as compiled DOLFINx forms.

One :class:`PenalizedProblem` is compiled once per mesh; ``κ`` and the load
parameters are ``dolfinx.fem.Constant`` objects, so a sweep over them reuses it. So are a
ball's or a cylinder's parameters: a problem with another radius builds the same forms, which
the JIT compiler finds in its cache.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.fem.petsc
import numpy as np
import sympy as sp
import ufl

from shellobstacle.geometry.expressions import y1, y2
from shellobstacle.geometry.translation import to_ufl
from shellobstacle.models.edges import (
    boundary_parts,
    dirichlet_bcs,
    dirichlet_dofs,
    free_rotation_facets,
    rotation_measure,
)
from shellobstacle.models.hybrid_bending import (
    DEFAULT_HYBRID_PENALTY,
    CondensedStiffness,
    facet_midpoints,
    facet_normals,
    hybrid_bending_energy,
)
from shellobstacle.models.koiter import DEFAULT_INTERIOR_PENALTY, bending_energy
from shellobstacle.models.membrane import elastic_product, strain
from shellobstacle.models.singular import GradientCheck
from shellobstacle.obstacle import Obstacle, from_spec
from shellobstacle.penalty.rule import penalty_measure
from shellobstacle.progress import phase
from shellobstacle.spec import Discretization, Shell

__all__ = ["PenalizedProblem", "boundary_facets", "load_ufl", "require_koiter_discretization"]


class PenalizedProblem:
    """Compiled forms of the penalized shell problem on one mesh (docs/model.md §4–5, §8).

    The energy is :eq:`penalized-energy`,
    ``J_κ(η) = (ε/2) ∫ a^{αβστ} γ_στ(η) γ_αβ(η) √a dy − ∫ p^{i,ε} η_i √a dy
    + (ε/(2κ)) ∫ ({g(η)}^-)² / |c| dy``; its derivative is the penalized equation
    :eq:`penalized-equation` and its (generalized) Hessian the symmetric positive definite
    Jacobian :eq:`penalty-jacobian`. For Koiter's model (``shell.model == "koiter"``) the
    elastic part gains the bending energy of :eq:`koiter-energy`, in its hybrid form
    :eq:`koiter-hybrid` (the default, :mod:`~shellobstacle.models.hybrid_bending`: ``K`` is the
    Schur
    complement of a block matrix in ``(ζ, t)``) or its C⁰ interior-penalty form
    :eq:`koiter-c0ip` (:func:`~shellobstacle.models.koiter.bending_energy`); the rest is shared.

    Attributes:
        zeta: the unknown ``ζ_κ^h`` (covariant components), a vector Lagrange function.
        t: the hybrid bending form's facet multiplier (None for the other forms), set from
            ``ζ`` by :meth:`update_multiplier`.
        condensed: the hybrid stiffness' blocks (after :meth:`stiffness`), or None.
        kappa: the penalty parameter, a ``Constant``; None for the exact nodal problem (κ = 0:
            no penalty term and no penalty forms).
        kappa_scale: None, or the cellwise factor ``ρ`` of a penalty parameter ``κ ρ(x)``.
        obstacle: the :class:`~shellobstacle.obstacle.Obstacle` of ``shell.obstacle``.
        g: the gap ``g(ζ)`` (UFL); ``g_penalty``: the gap the constraint acts on,
            ``g0 + c·ζ`` (``g`` itself for a plane, else the linearization at
            :attr:`zeta_lin`); ``c``, ``c_norm``: its derivative ``c_j = ∂g/∂ζ_j`` and
            ``|c|`` (at ``ζ = 0``).
        zeta_lin: where a curved obstacle's gap is linearized (None for a plane).
        parameters: the load parameters, ``Constant`` objects by name.
    """

    def __init__(
        self,
        shell: Shell,
        mesh: dolfinx.mesh.Mesh,
        discretization: Discretization | None = None,
        kappa: float | None = 1.0,
        p: Sequence[Any] | None = None,
        kappa_scale: dolfinx.fem.Function | None = None,
    ) -> None:
        """Compile the forms; ``kappa``: the first κ (changed by :meth:`set_kappa`), or None
        for the methods of the exact nodal problem (κ = 0, the constraint imposed by the
        solver); ``p``: three UFL scalars replacing the shell's load expressions (e.g.
        Functions holding sampled or computed data); ``kappa_scale``: a positive cellwise
        (DG0) factor ``ρ`` making the penalty parameter ``κ ρ(x)`` (a κ that follows the local
        mesh size, :func:`~shellobstacle.penalty.kappa.local_kappa_scale`; None: ``κ`` alone)."""
        if kappa is None and kappa_scale is not None:
            raise ValueError("a cellwise κ factor needs a penalty parameter kappa, not None")
        self.shell = shell
        self.mesh = mesh
        self.disc = disc = discretization or Discretization()
        if shell.model == "koiter":
            require_koiter_discretization(disc, mesh)
        #: the facets of γ by condition (docs/model.md §8.1)
        self.parts = boundary_parts(shell, mesh, disc.transverse)
        self.obstacle: Obstacle = from_spec(shell.obstacle, shell.material.epsilon)
        self.q = np.asarray(shell.obstacle.q, dtype=float)
        mat = shell.material
        self.V = dolfinx.fem.functionspace(mesh, ("Lagrange", disc.degree, (3,)))
        self.zeta = dolfinx.fem.Function(self.V, name="zeta")
        self.kappa: dolfinx.fem.Constant | None = None
        if kappa is not None:
            self.kappa = dolfinx.fem.Constant(mesh, PETSc.ScalarType(kappa))
        self.kappa_scale = kappa_scale
        shell_load, self.parameters = load_ufl(shell, mesh)
        self.G = G = shell.surface.geometry_ufl(mesh)
        #: the load was given as UFL expressions (``p``), not the shell's own
        self.custom_load = p is not None
        self.p = shell_load if p is None else list(p)

        self.dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": disc.qdegree})
        self.dx_penalty = penalty_measure(mesh, disc, self.dx)

        eps, lam, mu = mat.epsilon, mat.lam, mat.mu
        zeta, v, du = self.zeta, ufl.TestFunction(self.V), ufl.TrialFunction(self.V)
        gam = self.strain_of(zeta)
        self._gap_forms(G)
        g_minus = ufl.conditional(ufl.lt(self.g_penalty, 0), self.g_penalty, 0)  # −{g}^-
        sqrt_a = G.sqrt_a

        elastic = 0.5 * eps * elastic_product(G, lam, mu, gam, gam) * sqrt_a * self.dx
        self.t: dolfinx.fem.Function | None = None  # the hybrid form's facet multiplier
        if shell.model == "koiter":
            hybrid = disc.bending == "hybrid"
            default = DEFAULT_HYBRID_PENALTY if hybrid else DEFAULT_INTERIOR_PENALTY
            # σ is a Constant: changing it reuses the compiled forms
            self.sigma = dolfinx.fem.Constant(
                mesh, PETSc.ScalarType(disc.interior_penalty or default)
            )
            # s multiplies the bending energy (set_bending_scale): a Constant, as σ
            self.bending_scale = dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))
            if hybrid:
                T = dolfinx.fem.functionspace(mesh, ("CR", 1))
                self.t = dolfinx.fem.Function(T, name="t")
                # ρ(ζ)·ρ(η) of P_k functions: degree 2k but for the geometry's coefficients
                dx_bending = ufl.Measure(
                    "dx", domain=mesh, metadata={"quadrature_degree": disc.bending_qdegree}
                )
                dropped = free_rotation_facets(mesh, self.parts) if self.parts.given else None
                bending = hybrid_bending_energy(
                    G, eps, lam, mu, zeta, self.t, facet_normals(mesh), dx_bending,
                    facet_midpoints(mesh, dropped), self.sigma,
                )  # fmt: skip
            else:
                ds = rotation_measure(mesh, self.parts, {"quadrature_degree": disc.qdegree})
                bending = bending_energy(G, eps, lam, mu, zeta, self.dx, self.sigma, ds)
            elastic += self.bending_scale * bending
        work = sum(self.p[i] * zeta[i] for i in range(3)) * sqrt_a * self.dx
        energy = elastic - work
        if self.kappa is not None:
            penalty = (eps / (2 * self.kappa_x)) * g_minus**2 / self.c_norm * self.dx_penalty
            energy = elastic - work + penalty
        residual = ufl.derivative(energy, zeta, v)
        load = sum(self.p[i] * v[i] for i in range(3)) * sqrt_a * self.dx
        with phase("compiling the forms"):
            self.forms = {
                "residual": dolfinx.fem.form(residual),
                "load": dolfinx.fem.form(load),
                "elastic_energy": dolfinx.fem.form(elastic),
                "work": dolfinx.fem.form(work),
            }
            if self.kappa is not None:
                self.forms["penalty_energy"] = dolfinx.fem.form(penalty)
                # (ε/κ) ∫ β(ζ)·v dy: the penalty part of the residual (= −κ ∂R/∂κ)
                self.forms["penalty_residual"] = dolfinx.fem.form(ufl.derivative(penalty, zeta, v))
            dz = ufl.derivative(elastic, zeta, v)
            if self.t is None:
                self.forms["jacobian"] = dolfinx.fem.form(ufl.derivative(residual, zeta, du))
                # K: the (constant) Hessian of the elastic energy; J_κ'' = K + penalty part
                self.forms["stiffness"] = dolfinx.fem.form(ufl.derivative(dz, zeta, du))
            else:
                # the hybrid stiffness' blocks in (ζ, t), K their Schur complement in ζ; the
                # forms above read t: they hold at ζ once update_multiplier() has run
                T = self.t.function_space
                s_, dt = ufl.TestFunction(T), ufl.TrialFunction(T)
                blocks = {
                    "a_zz": ufl.derivative(dz, zeta, du),
                    "a_zt": ufl.derivative(dz, self.t, dt),
                    "a_tt": ufl.derivative(ufl.derivative(elastic, self.t, s_), self.t, dt),
                }
                self.forms["stiffness_blocks"] = {k: dolfinx.fem.form(f) for k, f in blocks.items()}
        self.bcs = self._boundary_conditions()
        self._K: PETSc.Mat | None = None
        self.condensed: CondensedStiffness | None = None

    def _gap_forms(self, G: Any) -> None:
        """The gap ``g(ζ)``, the gap the constraint acts on and its derivative ``c``.

        For an affine obstacle (a plane) the two gaps are one. For a curved one the
        constraint acts on the linearization ``g(ζ̄) + c(ζ̄)·(ζ − ζ̄)`` at
        :attr:`zeta_lin` ``= ζ̄`` (:mod:`shellobstacle.solvers.linearization` moves ``ζ̄`` to
        ``ζ`` until they agree), and the penalty's weight ``1/|c|`` is taken at ``ζ = 0``, so
        that ``J_κ`` is one energy whatever ``ζ̄``. The obstacle's parameters enter as
        Constants (:meth:`~shellobstacle.obstacle.base.Obstacle.on_mesh`): another radius
        compiles no new forms.
        """
        obstacle = self.obstacle.on_mesh(self.mesh)
        zeta = [self.zeta[i] for i in range(3)]
        self.c_norm = obstacle.c_norm(G)
        self.g = obstacle.gap(G, zeta)  # g(ζ)
        self.zeta_lin: dolfinx.fem.Function | None = None
        self._gradient_check: GradientCheck | None = None
        if obstacle.affine:
            self.c = obstacle.c(G)  # c_j = ∂g/∂ζ_j
            self.g0 = obstacle.reference_gap(G)
            self.g_penalty = self.g
            return
        self.zeta_lin = dolfinx.fem.Function(self.V, name="zeta_lin")
        lin = [self.zeta_lin[i] for i in range(3)]
        self.c = obstacle.c(G, lin)
        self.g0 = obstacle.gap(G, lin) - sum(self.c[j] * lin[j] for j in range(3))
        self.g_penalty = self.g0 + sum(self.c[j] * zeta[j] for j in range(3))

    @property
    def linearized(self) -> bool:
        """Whether the constraint acts on a linearization of a curved obstacle's gap."""
        return self.zeta_lin is not None

    def linearize(self) -> None:
        """``ζ̄ ← ζ``: linearize a curved obstacle's gap at the current ``ζ`` (nothing for a
        plane).

        Raises:
            SingularGradientError: a constraint point lies where ``∇g`` is undefined
                (:mod:`shellobstacle.models.singular`).
        """
        if self.zeta_lin is not None:
            self.zeta_lin.x.array[:] = self.zeta.x.array
            if self._gradient_check is None:
                self._gradient_check = GradientCheck(self)
            self._gradient_check()

    @property
    def penalized(self) -> bool:
        """Whether the problem has a penalty (κ > 0); False for the exact nodal problem."""
        return self.kappa is not None

    @property
    def kappa_x(self) -> Any:
        """The penalty parameter ``κ`` or ``κ ρ(x)`` (UFL) of a penalized problem."""
        if self.kappa is None:
            raise ValueError("the exact nodal problem (kappa = None) has no penalty parameter")
        return self.kappa if self.kappa_scale is None else self.kappa * self.kappa_scale

    @property
    def model(self) -> str:
        """``"membrane"`` or ``"koiter"`` (the shell's model)."""
        return self.shell.model

    def strain_of(self, eta: Any) -> list[list[Any]]:
        """``γ_αβ(η)`` of a UFL vector (covariant components)."""
        grad = ufl.grad(eta)
        return strain(
            self.G, [eta[i] for i in range(3)], [[grad[i, a] for a in range(2)] for i in range(3)]
        )

    @property
    def dirichlet_components(self) -> list[int]:
        """The components of ζ fixed on a clamped part of γ: ζ_α, and ζ_3 if clamped."""
        return [0, 1] + ([2] if self.disc.transverse == "clamped" else [])

    def dirichlet_rows(self, V: dolfinx.fem.FunctionSpace) -> np.ndarray:
        """The owned scalar dofs (``bs · node + component``, local, sorted) that the Dirichlet
        conditions fix in ``V``, a space of ζ's element on this mesh or any other mesh of ω
        (the levels of a refinement hierarchy)."""
        parts = self.parts
        if V.mesh is not self.mesh:
            parts = boundary_parts(self.shell, V.mesh, self.disc.transverse, check=False)
        owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        rows = [dofs[dofs < owned] for dofs in dirichlet_dofs(V, parts).values()]
        return np.unique(np.concatenate(rows)) if rows else np.zeros(0, dtype=np.int32)

    def _boundary_conditions(self) -> list[dolfinx.fem.DirichletBC]:
        """Homogeneous Dirichlet conditions of the parts of γ (docs/model.md §8.1): ζ = 0 on
        the clamped (membrane: ζ_α, and ζ_3 if ``transverse = "clamped"``) and simply
        supported parts, ζ_α = 0 on a symmetry line y_α = c."""
        return dirichlet_bcs(self.V, self.parts)

    @property
    def num_dofs(self) -> int:
        """Global number of degrees of freedom (all three components)."""
        im = self.V.dofmap.index_map
        return im.size_global * self.V.dofmap.index_map_bs

    def set_kappa(self, kappa: float) -> None:
        """Change ``κ`` without recompiling."""
        if self.kappa is None:
            raise ValueError("the exact nodal problem (kappa = None) has no κ to change")
        if not kappa > 0:
            raise ValueError(f"the penalty parameter kappa must be > 0, got {kappa}")
        self.kappa.value = kappa

    def set_bending_scale(self, s: float) -> None:
        """Multiply Koiter's bending energy by ``s`` (1: the shell's own). When the load and
        the penalty are proportional to ε, as the paper's, J_κ/ε depends on ε only through
        the bending's ε²/3, so ``s = (ε'/ε)²`` gives Koiter's solution at thickness ε'
        without compiling the forms again. The stiffness is destroyed and assembled again at
        its next use: solvers built before the change hold the destroyed one, so build them
        again."""
        if self.model != "koiter":
            raise ValueError("only Koiter's model has a bending energy to scale")
        if not s > 0:
            raise ValueError(f"the bending scale must be > 0, got {s}")
        self.bending_scale.value = s
        if self.condensed is not None:
            self.condensed.destroy()
            self.condensed = None
        elif self._K is not None:
            self._K.destroy()
        self._K = None

    def set_parameter(self, name: str, value: float) -> None:
        """Change a load parameter without recompiling."""
        if name not in self.parameters:
            raise KeyError(f"no load parameter {name!r}; the load has {sorted(self.parameters)}")
        self.parameters[name].value = value

    def stiffness(self) -> PETSc.Mat:
        """The stiffness ``K`` (the constant Hessian of the elastic energy: membrane, plus
        bending for Koiter's model; Dirichlet rows and columns identity), assembled at the
        first call and shared by every solver of this problem: read it, never change it."""
        if self._K is None:
            if self.t is not None:
                self.condensed = CondensedStiffness(
                    self.forms["stiffness_blocks"], self.bcs, self._multiplier_bcs()
                )
                self._K = self.condensed.K
            else:
                self._K = dolfinx.fem.petsc.assemble_matrix(self.forms["stiffness"], bcs=self.bcs)
                self._K.assemble()
        return self._K

    def _multiplier_bcs(self) -> list[dolfinx.fem.DirichletBC]:
        """``t = 0`` on the boundary's facets (where no cell pair meets it)."""
        tdim = self.mesh.topology.dim
        T = self.t.function_space
        dofs = dolfinx.fem.locate_dofs_topological(T, tdim - 1, boundary_facets(self.mesh))
        return [dolfinx.fem.dirichletbc(PETSc.ScalarType(0), dofs, T)]

    def update_multiplier(self) -> None:
        """``t ← t(ζ)``, the hybrid form's multiplier that minimizes the energy at ``ζ``
        (nothing for the other forms): the forms that read ``t`` then hold at ``ζ``."""
        if self.t is None:
            return
        self.stiffness()
        self.condensed.multiplier(self.zeta.x.petsc_vec, self.t.x.petsc_vec)
        self.t.x.scatter_forward()

    def load_vector(self, b: PETSc.Vec | None = None) -> PETSc.Vec:
        """The load vector ``(p√a, v)`` with zero Dirichlet rows, assembled into ``b`` (its
        old values discarded) or into a new vector; returns it (collective)."""
        if b is None:
            b = dolfinx.fem.petsc.create_vector(self.V)
        with b.localForm() as loc:
            loc.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.forms["load"])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        dolfinx.fem.petsc.set_bc(b, self.bcs)
        return b

    def scalar(self, name: str) -> float:
        """Assemble one of the energy forms (global value, all ranks)."""
        local = dolfinx.fem.assemble_scalar(self.forms[name])
        return float(self.mesh.comm.allreduce(local))

    def energies(self) -> dict[str, float]:
        """``J(ζ)``, the penalty term and ``J_κ(ζ)`` at the current ``ζ`` (the penalty term 0
        for the exact nodal problem)."""
        self.update_multiplier()
        el, w = self.scalar("elastic_energy"), self.scalar("work")
        pen = self.scalar("penalty_energy") if self.penalized else 0.0
        return {"energy": el - w, "penalty_energy": pen, "penalized_energy": el - w + pen}


def load_ufl(
    shell: Shell, mesh: dolfinx.mesh.Mesh
) -> tuple[list[Any], dict[str, dolfinx.fem.Constant]]:
    """The shell's load ``p^{i,ε}`` as three UFL scalars on ``mesh``, and its parameters as
    ``Constant`` objects by name (changing one reuses the compiled forms)."""
    parameters = {
        k: dolfinx.fem.Constant(mesh, PETSc.ScalarType(v)) for k, v in shell.load.parameters.items()
    }
    x = ufl.SpatialCoordinate(mesh)
    symbols: dict[sp.Symbol, Any] = {y1: x[0], y2: x[1]}
    symbols |= {sp.Symbol(k, real=True): c for k, c in parameters.items()}
    # a component that is identically 0 stays a Constant so that UFL keeps the load forms
    zero = dolfinx.fem.Constant(mesh, PETSc.ScalarType(0))
    p = [zero if e == 0 else to_ufl(e, symbols) for e in shell.load_expressions()]
    return p, parameters


def require_koiter_discretization(disc: Discretization, mesh: dolfinx.mesh.Mesh) -> None:
    """Koiter's ζ_3 ∈ H² needs P2 with interior penalties, ``transverse = "clamped"`` (the
    edge conditions are the shell's :class:`~shellobstacle.spec.Edge`), and (in parallel) the
    ghost cells across process boundaries that the facet integrals read."""
    if disc.degree < 2:
        raise ValueError(
            "Koiter's model needs discretization.degree = 2 (ζ_3 ∈ H² by C⁰ interior penalty); "
            "got degree = 1"
        )
    if disc.transverse != "clamped":
        raise ValueError(
            "Koiter's model clamps ζ_3 and ∂_ν ζ_3 on γ: set discretization.transverse = 'clamped'"
        )
    if mesh.comm.size > 1:
        imap = mesh.topology.index_map(mesh.topology.dim)
        if mesh.comm.allreduce(imap.num_ghosts, op=MPI.SUM) == 0:
            raise ValueError(
                "Koiter's facet terms need ghost cells across process boundaries: build the "
                "mesh with shellobstacle.mesh.meshing.create_mesh(..., ghosted=True)"
            )


def boundary_facets(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    """The facets of ``mesh`` on γ (its exterior facets)."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    return dolfinx.mesh.exterior_facet_indices(mesh.topology)
