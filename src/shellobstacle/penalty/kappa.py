"""κ on one mesh (docs/model.md §6): the continuation ladder of a
:class:`~shellobstacle.penalty.spec.PenaltySpec` at the mesh's size and, on an adapted mesh,
how ``κ = h^q`` follows the cells.

With ``penalty.exponent = q`` a mesh's κ is ``h_max^q`` with the largest cell diameter, as on
any other mesh (``"largest"``), ``κ(x) = h_T^q`` cell by cell (``"local"``: ``h_max^q`` times
the cellwise factor ``ρ = (h_T/h_max)^q``, a DG0 Function that
:class:`~shellobstacle.models.problem.PenalizedProblem` takes as ``kappa_scale``), or
``h_min^q`` (``"finest"``). A fixed ``penalty.kappa`` is the same on every mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

from mpi4py import MPI  # noqa: F401  (MPI before DOLFINx)

import dolfinx
import numpy as np

from shellobstacle.mesh.measures import mesh_size, mesh_size_min
from shellobstacle.penalty.spec import KAPPA_MODES, PenaltySpec

__all__ = ["MeshKappa", "kappa_on_mesh", "local_kappa_scale"]


@dataclass(frozen=True)
class MeshKappa:
    """κ of a penalty on one mesh.

    Attributes:
        h: the mesh size the ladder is taken at (``h_min`` for ``"finest"``, else ``h_max``).
        ladder: :meth:`PenaltySpec.ladder` at ``h``, ending at the mesh's κ (``[0.0]``
            without a penalty: the exact nodal problem).
        scale: None, or the DG0 factor ``ρ`` of ``κ(x) = κ ρ(x)`` (``"local"``).
        kappa_min: the smallest ``κ(x)`` on the mesh.
        kappa_max: the largest ``κ(x)`` on the mesh.
    """

    h: float
    ladder: list[float]
    scale: dolfinx.fem.Function | None
    kappa_min: float
    kappa_max: float


def kappa_on_mesh(
    penalty: PenaltySpec | None, mesh: dolfinx.mesh.Mesh, mode: str = "largest"
) -> MeshKappa:
    """The ladder, the cellwise scale and the range of κ of ``penalty`` on ``mesh`` (collective).

    Args:
        penalty: κ or ``h^exponent``; None for the exact nodal problem (κ = 0).
        mesh: the mesh.
        mode: one of :data:`~shellobstacle.penalty.spec.KAPPA_MODES`: how ``κ = h^q`` follows
            an adapted mesh (unused with a fixed ``penalty.kappa``).
    """
    if mode not in KAPPA_MODES:
        raise ValueError(f"the κ mode must be one of {KAPPA_MODES}, got {mode!r}")
    h_max = mesh_size(mesh)
    if penalty is None:
        return MeshKappa(h_max, [0.0], None, 0.0, 0.0)
    if penalty.exponent is None or mode == "largest":
        target = penalty.target(h_max)
        return MeshKappa(h_max, penalty.ladder(h_max), None, target, target)
    q = float(penalty.exponent)
    h_min = mesh_size_min(mesh)
    if mode == "finest":
        return MeshKappa(h_min, penalty.ladder(h_min), None, h_min**q, h_min**q)
    rho = local_kappa_scale(mesh, q, h_max)
    return MeshKappa(h_max, penalty.ladder(h_max), rho, h_min**q, h_max**q)


def local_kappa_scale(
    mesh: dolfinx.mesh.Mesh, exponent: float, h_max: float
) -> dolfinx.fem.Function:
    """The DG0 factor ``(h_T / h_max)^q`` of ``κ(x) = h_max^q (h_T/h_max)^q = h_T^q``."""
    W = dolfinx.fem.functionspace(mesh, ("DG", 0))
    rho = dolfinx.fem.Function(W, name="kappa_scale")
    imap = mesh.topology.index_map(mesh.topology.dim)
    cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
    rho.x.array[W.dofmap.list[cells, 0]] = (mesh.h(mesh.topology.dim, cells) / h_max) ** exponent
    return rho
