"""The conditions on the parts of γ (docs/model.md §8.1): which facets each
:class:`~shellobstacle.spec.Edge` selects on a mesh, the Dirichlet conditions they make, and
the boundary measure of the facets whose rotation is fixed.

========================  =========================  ==================================
condition                 fixed components of ζ      bending's boundary facet term
========================  =========================  ==================================
``clamped`` (default)     ζ_1, ζ_2, ζ_3 (membrane:   yes (∂_ν ζ_3 = 0, weakly)
                          ζ_3 as ``transverse``)
``simply-supported``      ζ_1, ζ_2, ζ_3              no (M_νν = 0, natural)
``free``                  none                       no
``symmetry`` (y_α = c)    ζ_α                        yes (∂_ν ζ_3 = 0, weakly)
========================  =========================  ==================================

A model builds its conditions from :func:`boundary_parts`::

    parts = boundary_parts(shell, mesh)
    bcs = dirichlet_bcs(V, parts)
    ds_clamped = rotation_measure(mesh, parts, {"quadrature_degree": q})

With no edge given, every facet is clamped and the forms are those of a clamped γ exactly
(the measure is the plain ``ds``).
"""

from __future__ import annotations

from dataclasses import dataclass

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import numpy as np
import ufl

from shellobstacle.geometry.translation import to_numpy
from shellobstacle.mesh.facet_tags import tagged_facets, tags_of
from shellobstacle.mesh.measures import boundary_facets
from shellobstacle.spec import EDGE_CONDITIONS, Shell

__all__ = [
    "BoundaryParts",
    "boundary_parts",
    "dirichlet_bcs",
    "dirichlet_dofs",
    "free_rotation_facets",
    "rotation_measure",
]

#: the value of each condition in the facet tags of :func:`rotation_measure`
CODES = {c: i + 1 for i, c in enumerate(EDGE_CONDITIONS)}
#: the conditions that fix the rotation across γ (the bending's boundary facet term)
ROTATION_FIXED = ("clamped", "symmetry")


@dataclass(frozen=True)
class BoundaryParts:
    """The owned boundary facets of one mesh by condition (local indices, sorted).

    Attributes:
        facets: condition → its facets (every condition of
            :data:`~shellobstacle.spec.EDGE_CONDITIONS`, some empty).
        symmetry: ``α`` → the facets of the symmetry parts on lines ``y_α = c``.
        transverse: the membrane's ``transverse`` (whether a clamped facet fixes ζ_3).
        given: whether any edge was given (False: γ clamped, the forms of a clamped γ).
    """

    facets: dict[str, np.ndarray]
    symmetry: dict[int, np.ndarray]
    transverse: str = "clamped"
    given: bool = False

    def components(self) -> dict[int, np.ndarray]:
        """Component ``i`` → the facets where ``ζ_i = 0``."""
        clamped = self.facets["clamped"]
        supported = self.facets["simply-supported"]
        out = {}
        for i in range(3):
            parts = [supported] if i == 2 and self.transverse != "clamped" else [clamped, supported]
            if i < 2:
                parts.append(self.symmetry.get(i, clamped[:0]))
            out[i] = np.unique(np.concatenate(parts)).astype(np.int32)
        return out


def boundary_parts(
    shell: Shell, mesh: dolfinx.mesh.Mesh, transverse: str = "clamped", check: bool = True
) -> BoundaryParts:
    """The facets of ``mesh``'s boundary by condition, for ``shell.edges`` (facets no edge
    selects are clamped).

    Args:
        check: refuse (ValueError, on every rank) an edge that selects no facet, two
            conditions on one facet, a tag on a mesh without tags, a symmetry part off a line
            ``y_α = c`` or about which θ is not symmetric, and a Koiter shell no part holds
            (False on the coarser levels of a hierarchy: the finest level was checked).
    """
    facets = boundary_facets(mesh)
    empty = facets[:0]
    if not shell.edges:
        parts = {c: empty for c in EDGE_CONDITIONS} | {"clamped": facets}
        return BoundaryParts(parts, {}, transverse, given=False)
    comm = mesh.comm
    condition = np.zeros(len(facets), dtype=np.int8)  # 0: no edge yet (clamped)
    chosen = np.full(len(facets), -1)
    midpoints = _midpoints(mesh, facets)
    symmetry: dict[int, list[np.ndarray]] = {0: [], 1: []}
    for k, edge in enumerate(shell.edges):
        if edge.tag is not None:
            if check and edge.tag not in tags_of(mesh):
                have = tags_of(mesh)
                raise ValueError(
                    f"{edge}: the mesh has no boundary tags "
                    + (f"but {have}" if have else "(only a domain.kind = 'file' mesh has them)")
                    + ": use where = '<condition in y1, y2>' or a tag of the file's physical curves"
                )
            mine = np.isin(facets, tagged_facets(mesh, edge.tag, facets))
        else:
            value = to_numpy(edge.predicate())(midpoints[:, 0], midpoints[:, 1])
            mine = value > 0.5
        if check:
            found = comm.allreduce(int(mine.sum()), op=MPI.SUM)
            fix = "widen its where (facet midpoints are tested) or fix its tag"
            _require(comm, found > 0, f"{edge} selects no facet of γ: {fix}")
            code = CODES[edge.condition]
            clash = mine & (condition != 0) & (condition != code)
            other = shell.edges[chosen[clash][0]] if clash.any() else None
            at = _point(midpoints[clash])
            message = f"{edge} and {other} both select the facet at y = {at}: give each facet one"
            _require(comm, other is None, message + " condition")
        condition[mine] = CODES[edge.condition]
        chosen[mine] = k
        if edge.condition == "symmetry":
            alpha = _symmetry_line(shell, mesh, facets[mine], str(edge), check)
            symmetry[alpha].append(facets[mine])
    condition[condition == 0] = CODES["clamped"]
    parts = {c: facets[condition == CODES[c]] for c in EDGE_CONDITIONS}
    if check and shell.model == "koiter":
        held = len(parts["clamped"]) + len(parts["simply-supported"])
        message = (
            "no edge is clamped or simply supported: the rigid motions make the stiffness "
            "singular; set one [[edge]] condition to 'clamped' or 'simply-supported'"
        )
        _require(comm, comm.allreduce(held, op=MPI.SUM) > 0, message)
    sym = {a: np.unique(np.concatenate(f)).astype(np.int32) for a, f in symmetry.items() if f}
    return BoundaryParts(parts, sym, transverse, given=True)


def dirichlet_dofs(V: dolfinx.fem.FunctionSpace, parts: BoundaryParts) -> dict[int, np.ndarray]:
    """Component ``i`` → the dofs of ``V.sub(i)`` (local, in ``V``'s numbering) held at 0."""
    tdim = V.mesh.topology.dim
    return {
        i: dolfinx.fem.locate_dofs_topological(V.sub(i), tdim - 1, facets)
        for i, facets in parts.components().items()
    }


def dirichlet_bcs(
    V: dolfinx.fem.FunctionSpace, parts: BoundaryParts
) -> list[dolfinx.fem.DirichletBC]:
    """``ζ_i = 0`` on the facets of each component (:meth:`BoundaryParts.components`), one
    condition per component that is held somewhere (a vector space ``V`` of ζ)."""
    bcs = []
    for i, dofs in dirichlet_dofs(V, parts).items():
        held = V.mesh.comm.allreduce(len(dofs), op=MPI.SUM)
        if held or not parts.given:
            bcs.append(dolfinx.fem.dirichletbc(PETSc.ScalarType(0), dofs, V.sub(i)))
    return bcs


def rotation_measure(
    mesh: dolfinx.mesh.Mesh, parts: BoundaryParts, metadata: dict
) -> ufl.Measure | None:
    """``ds`` over the facets whose rotation is fixed (clamped and symmetry parts), where
    the bending's boundary facet term imposes ``∂_ν ζ_3 = 0``; None where there is none.
    Without edges, the plain ``ds`` (all of γ clamped)."""
    if not parts.given:
        return ufl.Measure("ds", domain=mesh, metadata=metadata)
    held = sum(len(parts.facets[c]) for c in ROTATION_FIXED)
    if not mesh.comm.allreduce(held, op=MPI.SUM):
        return None
    facets = np.concatenate([parts.facets[c] for c in EDGE_CONDITIONS])
    values = np.concatenate([np.full(len(parts.facets[c]), CODES[c]) for c in EDGE_CONDITIONS])
    order = np.argsort(facets)
    tags = dolfinx.mesh.meshtags(
        mesh, mesh.topology.dim - 1, facets[order].astype(np.int32), values[order].astype(np.int32)
    )
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=tags, metadata=metadata)
    return ds(tuple(CODES[c] for c in ROTATION_FIXED))


def free_rotation_facets(mesh: dolfinx.mesh.Mesh, parts: BoundaryParts) -> np.ndarray:
    """The boundary facets, owned and ghost, whose rotation is free (simply supported and
    free parts): the hybrid bending form drops their facet terms there."""
    fmap = mesh.topology.index_map(mesh.topology.dim - 1)
    mark = dolfinx.la.vector(fmap, 1)
    mark.array[:] = 0.0
    for c in ("simply-supported", "free"):
        mark.array[parts.facets[c]] = 1.0
    mark.scatter_forward()
    return np.flatnonzero(mark.array > 0.5).astype(np.int32)


def _midpoints(mesh: dolfinx.mesh.Mesh, facets: np.ndarray) -> np.ndarray:
    """The midpoints ``(y1, y2)`` of ``facets``, shape ``(n, 2)``."""
    nodes = dolfinx.mesh.entities_to_geometry(mesh, mesh.topology.dim - 1, facets)
    return mesh.geometry.x[nodes][:, :, :2].mean(axis=1).reshape(-1, 2)


def _point(points: np.ndarray) -> str:
    return "(?)" if not len(points) else f"({points[0, 0]:.6g}, {points[0, 1]:.6g})"


def _require(comm: MPI.Comm, ok: bool, message: str) -> None:
    """Raise ValueError on every rank if ``ok`` is False on any (the first failing rank's
    ``message``)."""
    failed = comm.allgather(None if ok else message)
    first = next((m for m in failed if m is not None), None)
    if first is not None:
        raise ValueError(first)


def _symmetry_line(
    shell: Shell, mesh: dolfinx.mesh.Mesh, facets: np.ndarray, name: str, check: bool
) -> int:
    """``α`` of the line ``y_α = c`` the symmetry part ``facets`` lies on, after checking
    that θ is symmetric about it: ``θ(σy) = Rθ(y)`` with ``σ`` the reflection ``y_α → 2c −
    y_α`` and ``R`` the reflection of R³ about the plane ``x_α = θ_α(c, ·)`` (docs/model.md
    §8.1)."""
    comm = mesh.comm
    nodes = dolfinx.mesh.entities_to_geometry(mesh, mesh.topology.dim - 1, facets)
    y = mesh.geometry.x[nodes.ravel()][:, :2].reshape(-1, 2)
    low, high = np.full(2, np.inf), np.full(2, -np.inf)
    if len(y):
        low, high = y.min(axis=0), y.max(axis=0)
    comm.Allreduce(MPI.IN_PLACE, low, op=MPI.MIN)
    comm.Allreduce(MPI.IN_PLACE, high, op=MPI.MAX)
    x = mesh.geometry.x[:, :2]
    size = comm.allreduce(float(np.ptp(x, axis=0).max()) if len(x) else 0.0, op=MPI.MAX)
    flat = np.flatnonzero(high - low <= 1e-9 * size)
    if not check:
        return int(flat[0]) if len(flat) else 0
    span = f"[{low[0]:.6g}, {high[0]:.6g}] × [{low[1]:.6g}, {high[1]:.6g}]"
    message = (
        f"{name} is not on a line y1 = c or y2 = c (its facets span y ∈ {span}): select the "
        "facets of one such line, or use another condition"
    )
    _require(comm, len(flat) > 0, message)
    alpha = int(flat[0])
    c = 0.5 * (low[alpha] + high[alpha])
    owned = mesh.geometry.index_map().size_local
    points = x[:owned]
    mirrored, on_line = points.copy(), points.copy()
    mirrored[:, alpha] = 2 * c - points[:, alpha]
    on_line[:, alpha] = c
    theta = np.array(shell.surface.theta_numpy(points))
    image = np.array(shell.surface.theta_numpy(mirrored))
    line = np.array(shell.surface.theta_numpy(on_line))
    sign = np.ones((3, 1))
    sign[alpha] = -1
    shift = np.zeros_like(theta)
    shift[alpha] = 2 * line[alpha]
    error = image - sign * theta - shift  # θ(σy) − Rθ(y)
    ok = np.isfinite(error).all(axis=0) & np.isfinite(line[alpha])
    scale = 1.0 + float(np.abs(theta[:, ok]).max(initial=0.0))
    worst = float(np.abs(error[:, ok]).max(initial=0.0))
    plane = line[alpha][ok]  # θ_α on the line: the plane x_α = const of R
    top = comm.allreduce(float(plane.max(initial=-np.inf)), op=MPI.MAX)
    bottom = comm.allreduce(float(plane.min(initial=np.inf)), op=MPI.MIN)
    worst = max(comm.allreduce(worst, op=MPI.MAX), top - bottom if top >= bottom else 0.0)
    scale = comm.allreduce(scale, op=MPI.MAX)
    message = (
        f"{name}: θ is not symmetric about y{alpha + 1} = {c:.6g} (θ(σy) differs from the "
        f"mirror image of θ(y) by {worst:.3g}): use condition 'clamped' or 'simply-supported' there"
    )
    _require(comm, worst <= 1e-9 * scale, message)
    return alpha
