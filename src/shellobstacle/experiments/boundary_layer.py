"""The boundary layer of ζ_3 at the clamped edge γ: a mesh graded towards γ, the distance of
the cells to γ, ζ_3's profile along y2 = 0 near the edge and the layer's width (where Koiter's
ζ_3 first reaches half of the membrane's, going inwards); used by
:mod:`shellobstacle.experiments.koiter_limit`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import dolfinx
import numpy as np

from shellobstacle.mesh.domains import GRADED_KINDS, DomainSpec
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.sections import sample

__all__ = [
    "BAND",
    "EDGE_FRACTION",
    "EDGE_WIDTHS",
    "distance_to_boundary",
    "graded_domain",
    "layer_width",
    "zeta3_profile",
]

#: the band along the edge where ζ_3 is sampled, as a fraction of the domain's extent in y1
BAND = 0.25
#: ``edge_share`` counts the cells within this many √ε of γ
EDGE_WIDTHS = 3.0
#: The default mesh size along γ, as a fraction of the domain's ``h``. With h/2,
#: ``examples/paper.toml`` (h = 0.0058, band 3√0.001 ≈ 0.095) makes about 60k vertices and
#: 0.71 M P2 dofs, estimated at 6.9 GiB (:mod:`shellobstacle.mesh.resources`): the estimate may be
#: 1.5 times short and still stays within the 80 % of a 24 GiB machine that may be used. h/4
#: (2.3 M dofs, 22 GiB) does not fit there, h/3 (13 GiB) has no room for the estimate's error.
EDGE_FRACTION = 0.5


def graded_domain(
    domain: DomainSpec,
    epsilons: Sequence[float],
    edge_h: float | None = None,
    edge_width: float | None = None,
) -> DomainSpec:
    """``domain`` graded towards γ: ``edge_h`` (default: its own, else :data:`EDGE_FRACTION`
    · h) within ``edge_width`` (default: its own, else 3√ε of the smallest ε) of the edge."""
    if domain.kind not in GRADED_KINDS:
        return domain
    h = domain.h
    edge_h = edge_h or domain.edge_h or EDGE_FRACTION * h
    edge_width = edge_width or domain.edge_width or EDGE_WIDTHS * math.sqrt(min(epsilons))
    return dataclasses.replace(domain, edge_h=min(edge_h, h), edge_width=edge_width)


def layer_width(d: np.ndarray, koiter: np.ndarray, membrane: np.ndarray) -> float:
    """The distance from the edge where ``koiter`` first reaches half of ``membrane`` going
    inwards (linear interpolation of the ratio), where ``|membrane|`` is at least a tenth of
    its largest value in the band; NaN if it never does."""
    order = np.argsort(d)
    d, koiter, membrane = d[order], koiter[order], membrane[order]
    significant = np.abs(membrane) >= 0.1 * np.abs(membrane).max(initial=0.0)
    if not significant.any():
        return float("nan")
    ratio = np.where(significant, koiter / np.where(significant, membrane, 1.0), 0.0)
    above = np.flatnonzero(significant & (ratio >= 0.5))
    if not len(above):
        return float("nan")
    k = above[0]
    if k == 0:
        return float(d[0])
    r0, r1 = ratio[k - 1], ratio[k]
    return float(d[k - 1] + (0.5 - r0) / (r1 - r0) * (d[k] - d[k - 1]))


def distance_to_boundary(mesh: dolfinx.mesh.Mesh) -> dolfinx.fem.Function:
    """A DG0 function: the distance from each cell's midpoint to the nearest boundary vertex."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    facets = dolfinx.mesh.exterior_facet_indices(mesh.topology)
    x = dolfinx.mesh.entities_to_geometry(mesh, tdim - 1, facets)  # the facets' end points
    local = mesh.geometry.x[x.ravel(), :2]
    boundary = np.concatenate(mesh.comm.allgather(local))
    W = dolfinx.fem.functionspace(mesh, ("DG", 0))
    n = mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
    mid = dolfinx.mesh.compute_midpoints(mesh, tdim, np.arange(n, dtype=np.int32))[:, :2]
    dist = dolfinx.fem.Function(W)
    for start in range(0, len(mid), 4096):  # brute force in chunks: ~10⁸ pairs at most
        chunk = mid[start : start + 4096, None, :] - boundary[None, :, :]
        dist.x.array[start : start + len(chunk)] = np.sqrt((chunk**2).sum(axis=2).min(axis=1))
    return dist


def zeta3_profile(problem: PenalizedProblem, points: np.ndarray, tree: Any) -> np.ndarray:
    """ζ_3 of ``problem`` at ``points`` (NaN where no cell of this rank holds one), with
    ``tree`` the bounding-box tree of the points' line
    (:func:`~shellobstacle.post.sections.line_tree`)."""
    found, values = sample(problem.zeta, points, tree)
    out = np.full(points.shape[0], np.nan)
    out[found] = values[:, 2]
    return out
