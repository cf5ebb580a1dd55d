"""The gmsh physical curves of a mesh read from a file, kept as segments of γ.

A ``domain.kind = "file"`` mesh may name parts of its boundary by physical curves (``tag =
3`` of an ``[[edge]]``). The tagged boundary edges of the file are kept as segments
(:func:`read_segments`, on the rank that reads the file, then broadcast) and remembered with
the mesh (:func:`remember`); a refined mesh inherits them (:func:`inherit`), and
:func:`tagged_facets` finds the facets of a tag on any mesh of ω by their midpoints, which
lie on the file's segments whatever the refinement (a file's boundary nodes are not moved).
"""

from __future__ import annotations

import weakref

from mpi4py import MPI  # noqa: F401  (loads MPI before dolfinx)

import dolfinx
import numpy as np

__all__ = ["inherit", "read_segments", "remember", "tagged_facets", "tags_of"]

_LINE = 1  # gmsh element type of the 2-node line

#: mesh → {physical tag: segments, an array (n, 2, 2) of end points (y1, y2)}
_SEGMENTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def read_segments(model) -> dict[int, np.ndarray]:
    """The 2-node lines of each 1D physical group of a gmsh model, as segments by tag."""
    tags, coords, _ = model.mesh.getNodes()
    where = {int(t): i for i, t in enumerate(tags)}
    xy = np.asarray(coords, dtype=float).reshape(-1, 3)[:, :2]
    out: dict[int, np.ndarray] = {}
    for dim, group in model.getPhysicalGroups(1):
        ends = []
        for entity in model.getEntitiesForPhysicalGroup(dim, group):
            types, _, nodes = model.mesh.getElements(1, int(entity))
            for kind, n in zip(types, nodes, strict=True):
                if kind == _LINE:
                    ends.append(np.asarray([where[int(t)] for t in n]).reshape(-1, 2))
        if ends:
            out[int(group)] = xy[np.concatenate(ends)]
    return out


def remember(mesh: dolfinx.mesh.Mesh, segments: dict[int, np.ndarray]) -> None:
    """``mesh`` carries the tagged segments ``segments`` (every rank holds all of them)."""
    _SEGMENTS[mesh] = segments


def inherit(fine: dolfinx.mesh.Mesh, coarse: dolfinx.mesh.Mesh) -> None:
    """``fine``, refined from ``coarse``, carries ``coarse``'s tagged segments (if any)."""
    if coarse in _SEGMENTS:
        _SEGMENTS[fine] = _SEGMENTS[coarse]


def tags_of(mesh: dolfinx.mesh.Mesh) -> list[int]:
    """The physical tags of ``mesh``'s boundary (empty: a mesh without tags)."""
    return sorted(_SEGMENTS.get(mesh, {}))


def tagged_facets(mesh: dolfinx.mesh.Mesh, tag: int, facets: np.ndarray) -> np.ndarray:
    """The facets of ``facets`` (local indices of boundary facets) whose midpoint lies on a
    segment of physical curve ``tag`` (to 1e-9 of the segment's length)."""
    segments = _SEGMENTS.get(mesh, {}).get(tag)
    if segments is None or not len(facets):
        return facets[:0]
    nodes = dolfinx.mesh.entities_to_geometry(mesh, mesh.topology.dim - 1, facets)
    m = mesh.geometry.x[nodes][:, :, :2].mean(axis=1)  # (facet, xy)
    p, d = segments[:, 0], segments[:, 1] - segments[:, 0]  # (segment, xy)
    length2 = np.einsum("si,si->s", d, d)
    on = np.zeros(len(facets), dtype=bool)
    for start in range(0, len(segments), 256):  # (facet, segment) blocks
        q, e, ee = p[start : start + 256], d[start : start + 256], length2[start : start + 256]
        r = m[:, None, :] - q[None]
        cross = r[..., 0] * e[None, :, 1] - r[..., 1] * e[None, :, 0]
        along = np.einsum("fsi,si->fs", r, e)
        hit = (np.abs(cross) <= 1e-9 * ee) & (along >= -1e-9 * ee) & (along <= ee * (1 + 1e-9))
        on |= hit.any(axis=1)
    return facets[on]
