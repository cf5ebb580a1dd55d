"""Derived quantities of a solved penalized problem: gap, contact set, norms, cross-sections.

The contact set of a penalized solution is ``{y : g(ζ)(y) ≤ 0}`` with the gap
``g(ζ) = (θ + ζ_i a^i)·q`` (MODEL.md §3–4). It is measured on the mesh vertices
(MODEL.md §7, batch 3): the sign of ``g`` at quadrature points is noise of order
``h²`` for P1. Its area is the sum of the lumped (vertex-rule) masses of the
contact vertices, with the surface element ``√a dy`` and projected (``dy``).

Everything returned is global: each rank contributes its owned degrees of
freedom and the results are reduced over the communicator, so every function
here gives the same answer on every rank of an ``mpiexec -n N`` run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from shellobstacle import compat  # noqa: F401  (must precede dolfinx / petsc4py)

# isort: split
import dolfinx
import dolfinx.fem
import dolfinx.geometry
import dolfinx.la
import numpy as np
import ufl
from mpi4py import MPI

from shellobstacle.problem import PenalizedProblem

__all__ = [
    "AXES",
    "CrossSection",
    "Postprocessor",
    "cross_section",
    "h1_norm",
    "horizontal_direction",
    "l2_norm",
    "norms",
    "vm_norm",
]

AXES = ("y1", "y2")


# -- norms (MODEL.md §2: the space V_M and its norm) ------------------------------------------
def _measure(e: Any, mesh: dolfinx.mesh.Mesh | None, quadrature_degree: int | None) -> ufl.Measure:
    """``dx`` on the mesh of ``e`` (or ``mesh``), with a fixed quadrature degree if given."""
    domain = mesh if mesh is not None else ufl.domain.extract_unique_domain(e)
    if domain is None:
        raise ValueError("cannot find the mesh of the expression: pass mesh=...")
    metadata = {} if quadrature_degree is None else {"quadrature_degree": quadrature_degree}
    return ufl.Measure("dx", domain=domain, metadata=metadata)


def _integrate(integrand: Any, dx: ufl.Measure) -> float:
    """``∫ integrand dx`` over the whole distributed mesh (assemble_scalar + allreduce)."""
    form = dolfinx.fem.form(integrand * dx)
    local = dolfinx.fem.assemble_scalar(form)
    return float(form.mesh.comm.allreduce(local, op=MPI.SUM))


def _squares(e: Any) -> tuple[list[Any], list[Any]]:
    """``e_i²`` and ``|∇e_i|²`` for every component of a scalar or vector UFL expression."""
    comps = [e[i] for i in range(ufl.shape(e)[0])] if ufl.shape(e) else [e]
    return [c * c for c in comps], [ufl.inner(ufl.grad(c), ufl.grad(c)) for c in comps]


def l2_norm(
    e: Any, *, mesh: dolfinx.mesh.Mesh | None = None, quadrature_degree: int | None = None
) -> float:
    """``‖e‖_{L²(ω)} = (∫_ω Σ_i e_i² dy)^{1/2}`` of a scalar or vector Function / UFL expression.

    Args:
        e: Function or UFL expression on a mesh (e.g. ``u - v`` or ``u - exact``).
        mesh: The mesh, needed only if ``e`` does not reveal it (constants).
        quadrature_degree: Fixed quadrature degree; ``None`` lets UFL estimate it (exact for
            polynomial integrands, ``+2`` per non-polynomial function otherwise).

    Returns:
        The global norm (the same on every rank).
    """
    values, _ = _squares(e)
    return float(np.sqrt(_integrate(sum(values), _measure(e, mesh, quadrature_degree))))


def h1_norm(
    e: Any, *, mesh: dolfinx.mesh.Mesh | None = None, quadrature_degree: int | None = None
) -> float:
    """Full ``‖e‖_{H¹(ω)} = (∫_ω Σ_i (e_i² + |∇e_i|²) dy)^{1/2}`` (value plus gradient).

    Args:
        e: Function or UFL expression on a mesh.
        mesh: The mesh, needed only if ``e`` does not reveal it.
        quadrature_degree: Fixed quadrature degree (``None``: UFL's estimate).

    Returns:
        The global norm.
    """
    values, grads = _squares(e)
    total = _integrate(sum(values) + sum(grads), _measure(e, mesh, quadrature_degree))
    return float(np.sqrt(total))


def vm_norm(
    e: Any, *, mesh: dolfinx.mesh.Mesh | None = None, quadrature_degree: int | None = None
) -> float:
    """``‖e‖_{V_M} = (Σ_α ‖e_α‖²_{H¹(ω)} + ‖e_3‖²_{L²(ω)})^{1/2}`` (MODEL.md §2).

    Args:
        e: Vector Function or UFL expression with three covariant components.
        mesh: The mesh, needed only if ``e`` does not reveal it.
        quadrature_degree: Fixed quadrature degree (``None``: UFL's estimate).

    Returns:
        The global norm.

    Raises:
        ValueError: If ``e`` does not have three components.
    """
    if ufl.shape(e) != (3,):
        raise ValueError(f"vm_norm needs a 3-vector (η_1, η_2, η_3), got shape {ufl.shape(e)}")
    values, grads = _squares(e)
    total = _integrate(sum(values) + grads[0] + grads[1], _measure(e, mesh, quadrature_degree))
    return float(np.sqrt(total))


def norms(
    u: Any,
    v: Any | None = None,
    *,
    mesh: dolfinx.mesh.Mesh | None = None,
    quadrature_degree: int | None = None,
) -> dict[str, float]:
    """The L², H¹ and V_M norms of ``u − v`` (of ``u`` if ``v`` is None).

    ``u`` and ``v`` must live on the same mesh (interpolate a coarse solution into the fine
    space first: nested meshes make that exact, MODEL.md §7 batch 2).

    Args:
        u: Vector Function or UFL expression (three covariant components).
        v: Optional second one.
        mesh: The mesh, needed only if the expression does not reveal it.
        quadrature_degree: Fixed quadrature degree (``None``: UFL's estimate).

    Returns:
        ``{"l2": ..., "h1": ..., "vm": ...}``.
    """
    e = u if v is None else u - v
    kw: dict[str, Any] = {"mesh": mesh, "quadrature_degree": quadrature_degree}
    return {"l2": l2_norm(e, **kw), "h1": h1_norm(e, **kw), "vm": vm_norm(e, **kw)}


# -- nodal quantities ---------------------------------------------------------------------------
def _owned(f: dolfinx.fem.Function) -> np.ndarray:
    """Values of the owned dofs of ``f``, shape ``(size_local, block size)``."""
    im, bs = f.function_space.dofmap.index_map, f.function_space.dofmap.index_map_bs
    return f.x.array.reshape(-1, bs)[: im.size_local]


def _global_max(comm: MPI.Comm, values: np.ndarray, initial: float = -np.inf) -> float:
    return float(comm.allreduce(float(np.max(values, initial=initial)), op=MPI.MAX))


def _global_min(comm: MPI.Comm, values: np.ndarray, initial: float = np.inf) -> float:
    return float(comm.allreduce(float(np.min(values, initial=initial)), op=MPI.MIN))


class Postprocessor:
    """Nodal gap, contact set and areas, Cartesian displacement of one :class:`PenalizedProblem`.

    Built once per problem: the ``dolfinx.fem.Expression``s (gap, Cartesian displacement) and
    the lumped masses are compiled/assembled here and reused for every ``κ`` and load
    parameter; each method reads the current ``problem.zeta``.

    Attributes:
        problem: The problem.
        P1: Scalar P1 space on the mesh (vertex values).
        gap: ``g(ζ)`` at the vertices (a P1 Function, refreshed by :meth:`nodal_gap`).
        contact_indicator: 1 on contact vertices, 0 elsewhere (refreshed by :meth:`indicator`).
        U: Cartesian displacement ``ζ_i a^i`` in the space of ``ζ`` (refreshed by
            :meth:`cartesian_displacement`).
        mass: Lumped masses ``∫ φ_i √a dy`` of the owned vertices (vertex quadrature).
        mass_projected: Lumped masses ``∫ φ_i dy`` of the owned vertices.
        gap_scale: ``max θ·q`` over the mesh vertices (scale of the contact tolerance).
    """

    def __init__(self, problem: PenalizedProblem) -> None:
        self.problem = problem
        mesh = problem.mesh
        self.comm: MPI.Comm = mesh.comm
        self.P1 = dolfinx.fem.functionspace(mesh, ("Lagrange", 1))
        self.gap = dolfinx.fem.Function(self.P1, name="gap")
        self.contact_indicator = dolfinx.fem.Function(self.P1, name="contact")
        self.U = dolfinx.fem.Function(problem.V, name="U")
        self._gap_expr = dolfinx.fem.Expression(problem.g, self.P1.element.interpolation_points)
        zeta = problem.zeta
        U = ufl.as_vector(problem.G.cartesian([zeta[i] for i in range(3)]))
        self._U_expr = dolfinx.fem.Expression(U, problem.V.element.interpolation_points)

        # lumped masses m_i = ∫ φ_i √a dy and ∫ φ_i dy with the vertex rule (MODEL.md §7)
        dxv = ufl.Measure(
            "dx", domain=mesh, metadata={"quadrature_rule": "vertex", "quadrature_degree": 1}
        )
        phi = ufl.TestFunction(self.P1)
        self.mass = self._assemble_owned(phi * problem.G.sqrt_a * dxv)
        self.mass_projected = self._assemble_owned(phi * dxv)

        n_owned = self.P1.dofmap.index_map.size_local
        points = self.P1.tabulate_dof_coordinates()[:n_owned]
        theta = problem.shell.surface.theta_numpy(points)
        theta_q = sum(theta[k] * problem.q[k] for k in range(3))
        self.gap_scale = _global_max(self.comm, np.abs(theta_q), 0.0)
        self._trees: dict[tuple[str, float], dolfinx.geometry.BoundingBoxTree] = {}

    def _assemble_owned(self, linear_form: Any) -> np.ndarray:
        """Assemble a P1 linear form and return its owned entries (ghost contributions added)."""
        vec = dolfinx.fem.assemble_vector(dolfinx.fem.form(linear_form))
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        return vec.array[: self.P1.dofmap.index_map.size_local].copy()

    def nodal_gap(self) -> dolfinx.fem.Function:
        """``g(ζ) = (θ + ζ_i a^i)·q`` at the mesh vertices (MODEL.md §4), as a P1 Function.

        For P2 ``ζ`` these are still the vertex values (the P1 interpolation points).
        """
        self.gap.interpolate(self._gap_expr)
        self.gap.x.scatter_forward()
        return self.gap

    def tolerance(self, tol_rel: float = 1e-12) -> float:
        """The contact threshold ``tol_rel · max θ·q``: a vertex touches if ``g ≤`` this."""
        return tol_rel * self.gap_scale

    def _contact_mask(self, tol_rel: float) -> np.ndarray:
        """Contact flags of all local P1 dofs (owned and ghost), from a fresh nodal gap."""
        return self.nodal_gap().x.array <= self.tolerance(tol_rel)

    def contact(self, tol_rel: float = 1e-12) -> dict[str, float | int]:
        """The contact set ``{g(ζ) ≤ tol}`` at the vertices and its measures (MODEL.md §7).

        Args:
            tol_rel: Tolerance relative to ``max θ·q``.

        Returns:
            ``contact_area`` (``Σ`` lumped ``∫ φ_i √a dy`` over contact vertices),
            ``contact_area_projected`` (same with ``∫ φ_i dy``), ``max_violation``
            (``max {g}^-`` over vertices), ``min_gap``, ``num_contact_nodes`` and ``tol``;
            global values.
        """
        n_owned = self.P1.dofmap.index_map.size_local
        mask = self._contact_mask(tol_rel)[:n_owned]
        g = self.gap.x.array[:n_owned]
        comm = self.comm
        area = comm.allreduce(float(self.mass[mask].sum()), op=MPI.SUM)
        projected = comm.allreduce(float(self.mass_projected[mask].sum()), op=MPI.SUM)
        count = comm.allreduce(int(mask.sum()), op=MPI.SUM)
        min_gap = _global_min(comm, g)
        return {
            "contact_area": float(area),
            "contact_area_projected": float(projected),
            "max_violation": max(-min_gap, 0.0),
            "min_gap": min_gap,
            "num_contact_nodes": int(count),
            "tol": self.tolerance(tol_rel),
        }

    def indicator(self, tol_rel: float = 1e-12) -> dolfinx.fem.Function:
        """The contact indicator: a P1 Function, 1 on contact vertices, 0 elsewhere."""
        self.contact_indicator.x.array[:] = self._contact_mask(tol_rel).astype(float)
        return self.contact_indicator

    def cartesian_displacement(self) -> dolfinx.fem.Function:
        """``U = ζ_i a^i``: Cartesian components of the displacement, in the space of ``ζ``."""
        self.U.interpolate(self._U_expr)
        self.U.x.scatter_forward()
        return self.U

    def zeta3_range(self) -> tuple[float, float]:
        """Global ``(min, max)`` of the dofs of the transverse component ``ζ_3``."""
        z3 = _owned(self.problem.zeta)[:, 2]
        return _global_min(self.comm, z3), _global_max(self.comm, z3)

    def total_mass(self) -> tuple[float, float]:
        """``(Σ_i ∫ φ_i √a dy, Σ_i ∫ φ_i dy)``: the lumped surface area and the domain area."""
        return (
            float(self.comm.allreduce(float(self.mass.sum()), op=MPI.SUM)),
            float(self.comm.allreduce(float(self.mass_projected.sum()), op=MPI.SUM)),
        )

    def summary(self, tol_rel: float = 1e-12) -> dict[str, float | int]:
        """Contact measures, range of ``ζ_3`` and energies (``problem.energies()``) in one dict."""
        out: dict[str, float | int] = dict(self.contact(tol_rel))
        out["zeta3_min"], out["zeta3_max"] = self.zeta3_range()
        out |= self.problem.energies()
        return out

    def cross_section(self, n: int = 401, axis: str = "y1", at: float = 0.0) -> CrossSection:
        """:func:`cross_section` of the current ``ζ``, reusing the line's bounding-box tree."""
        if axis not in AXES:
            raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
        key = (axis, float(at))
        if key not in self._trees:
            self._trees[key] = line_tree(self.problem.mesh, axis, at)
        return cross_section(self.problem, n=n, axis=axis, at=at, tree=self._trees[key])


# -- cross-sections (MODEL.md §7, batch 3) ------------------------------------------------------
@dataclass(frozen=True)
class CrossSection:
    """The shell along a line of ω: reference and deformed points and their heights.

    Attributes:
        axis: ``"y1"`` (line ``y2 = at``) or ``"y2"`` (line ``y1 = at``).
        at: The fixed coordinate.
        s: Parameter along the line (the running coordinate ``y1`` or ``y2``), shape ``(m,)``.
        y: Points of ω, shape ``(m, 2)``.
        zeta: Covariant components ``ζ_i(y)``, shape ``(m, 3)``.
        reference: ``θ(y)``, shape ``(m, 3)``.
        deformed: ``θ(y) + ζ_i(y) a^i(y)``, shape ``(m, 3)``.
        height_reference: ``θ(y)·q`` (height above the plane), shape ``(m,)``.
        height_deformed: ``(θ + ζ_i a^i)(y)·q = g(ζ)(y)``, shape ``(m,)``.
        q: Unit normal of the plane.
    """

    axis: str
    at: float
    s: np.ndarray
    y: np.ndarray
    zeta: np.ndarray
    reference: np.ndarray
    deformed: np.ndarray
    height_reference: np.ndarray
    height_deformed: np.ndarray
    q: np.ndarray


def _mesh_extent(mesh: dolfinx.mesh.Mesh, k: int) -> tuple[float, float]:
    x = mesh.geometry.x[:, k]
    return _global_min(mesh.comm, x), _global_max(mesh.comm, x)


def line_tree(mesh: dolfinx.mesh.Mesh, axis: str, at: float) -> dolfinx.geometry.BoundingBoxTree:
    """Bounding-box tree of the local cells that meet the line of a cross-section.

    The line is ``y2 = at`` for ``axis="y1"`` (``y1 = at`` for ``"y2"``); a tree of these
    cells only (about ``1/√N`` of them) is all the point search along it needs, and costs a
    fraction of a tree of the whole mesh.
    """
    tdim = mesh.topology.dim
    cells = mesh.topology.index_map(tdim)
    nodes = mesh.geometry.dofmaps[0][: cells.size_local + cells.num_ghosts]
    c = mesh.geometry.x[nodes, 1 - AXES.index(axis)]
    pad = 1e-12 * (1.0 + abs(at))
    meets = (c.min(axis=1) <= at + pad) & (c.max(axis=1) >= at - pad)
    return dolfinx.geometry.bb_tree(mesh, tdim, entities=np.flatnonzero(meets).astype(np.int32))


def _sample(
    u: dolfinx.fem.Function, points: np.ndarray, tree: dolfinx.geometry.BoundingBoxTree
) -> tuple[np.ndarray, np.ndarray]:
    """Values of ``u`` at the points inside the mesh, gathered on every rank.

    Returns:
        ``(found, values)``: indices of the points found by some rank and ``u`` there (one value
        per point: the lowest rank that has it).
    """
    mesh = u.function_space.mesh
    candidates = dolfinx.geometry.compute_collisions_points(tree, points)
    colliding = dolfinx.geometry.compute_colliding_cells(mesh, candidates, points)
    found, cells = [], []
    for i in range(points.shape[0]):
        links = colliding.links(i)
        if len(links) > 0:
            found.append(i)
            cells.append(links[0])
    idx = np.asarray(found, dtype=np.int64)
    ncomp = int(np.prod(u.ufl_shape))
    vals = np.zeros((0, ncomp))
    if len(idx):
        vals = u.eval(points[idx], np.asarray(cells, dtype=np.int32)).reshape(len(idx), ncomp)
    gathered = mesh.comm.allgather((idx, vals))
    values = np.full((points.shape[0], ncomp), np.nan)
    have = np.zeros(points.shape[0], dtype=bool)
    for i, v in gathered:
        new = ~have[i]
        values[i[new]] = v[new]
        have[i[new]] = True
    where = np.flatnonzero(have)
    return where, values[where]


def cross_section(
    problem: PenalizedProblem,
    n: int = 401,
    axis: str = "y1",
    at: float = 0.0,
    tree: dolfinx.geometry.BoundingBoxTree | None = None,
) -> CrossSection:
    """Sample ``ζ`` along a straight line of ω and build the reference and deformed shell there.

    ``n`` equispaced points span the mesh's extent along ``axis`` on the line (``y2 = at`` for
    ``axis="y1"``); the points outside the mesh (a polygonal disk misses a little of its
    bounding box) are dropped. Each MPI rank evaluates the points its cells contain and every
    rank receives all values (MODEL.md §7, batch 3: cross-sections of ``θ + ζ_i a^i``).

    Args:
        problem: The problem; its current ``zeta`` is sampled.
        n: Number of sample points.
        axis: ``"y1"`` or ``"y2"``: the running coordinate.
        at: The value of the other coordinate.
        tree: A bounding-box tree of (at least) the cells that meet the line (built by
            :func:`line_tree` if not given).

    Returns:
        The :class:`CrossSection` (identical on all ranks).
    """
    if axis not in AXES:
        raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
    if n < 2:
        raise ValueError(f"a cross-section needs n >= 2 points, got {n}")
    mesh = problem.mesh
    k = AXES.index(axis)
    lo, hi = _mesh_extent(mesh, k)
    s = np.linspace(lo, hi, n)
    points = np.zeros((n, 3))
    points[:, k] = s
    points[:, 1 - k] = at
    if tree is None:
        tree = line_tree(mesh, axis, at)
    where, zeta = _sample(problem.zeta, points, tree)
    y = points[where, :2]
    G = problem.shell.surface.geometry_numpy(y)
    m = len(where)
    reference = np.column_stack([np.broadcast_to(np.asarray(t, float), (m,)) for t in G.theta])
    U = G.cartesian([zeta[:, i] for i in range(3)])
    deformed = reference + np.column_stack([np.broadcast_to(u, (m,)) for u in U])
    q = np.asarray(problem.q, float)
    return CrossSection(
        axis=axis,
        at=float(at),
        s=s[where],
        y=y,
        zeta=zeta,
        reference=reference,
        deformed=deformed,
        height_reference=reference @ q,
        height_deformed=deformed @ q,
        q=q,
    )


def horizontal_direction(q: Sequence[float], axis: str = "y1") -> np.ndarray:
    """Unit vector of the plane ``x·q = 0`` closest to the Cartesian axis ``e_1`` (or ``e_2``).

    The horizontal coordinate of a cross-section point ``x`` is ``x·t`` (``x_1`` for
    ``q = (0, 0, 1)`` and ``axis = "y1"``).
    """
    q = np.asarray(q, float) / np.linalg.norm(q)
    for e in (np.eye(3)[AXES.index(axis)], *np.eye(3)):
        t = e - (e @ q) * q
        if np.linalg.norm(t) > 1e-8:
            return t / np.linalg.norm(t)
    raise ValueError(f"no horizontal direction for q = {q}")  # pragma: no cover
