"""What a mesh will cost before it is made: vertices, dofs and memory, against the machine.

A one-character typo in ``h`` (``0.0001`` for ``0.001``) asks for 10⁸ vertices: meshing alone
would run for hours and exhaust the memory. :func:`require_fits` estimates the cost from the
domain's area and ``h`` (:func:`~shellobstacle.mesh.domains.estimated_vertices`) and refuses, in one
line with the estimate, what cannot fit in this machine's memory.

The memory per dof (:mod:`~shellobstacle.mesh.memory`) was measured on the paper's problem with
the direct solver and with multigrid, which factorizes only the coarsest mesh; the figures are
estimates within a factor of about 1.5, good for refusing what is far out of reach, not for
planning a run to the last gigabyte (``--force`` proceeds anyway). A refusal for the direct
solver names multigrid when its estimate fits. The estimate never chooses the solver:
``solver.linear_solver = "auto"`` is resolved from the problem alone
(:mod:`~shellobstacle.solvers.auto`). Messages give memory in GiB (2³⁰ bytes), the unit
``free -g`` and the documentation use.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI

from shellobstacle.mesh import memory
from shellobstacle.mesh.domains import DomainSpec, coarsening_steps, estimated_vertices
from shellobstacle.mesh.memory import (
    BYTES_PER_VERTEX_MESH,
    GIB,
    MEMORY_SHARE,
    bytes_per_dof,
)
from shellobstacle.messages import ConfigError

__all__ = ["Estimate", "ResourceError", "estimate", "require_fits"]


class ResourceError(ConfigError):
    """The mesh asked for cannot fit in this machine's memory."""


@dataclass(frozen=True)
class Estimate:
    """Estimated size and peak memory (all ranks together) of a mesh and its solve."""

    vertices: float
    dofs: float
    bytes_mesh: float
    bytes_solve: float


def mesh_vertices(spec: DomainSpec) -> float | None:
    """Estimated vertices of the mesh of ``spec`` after its refinements (None: unknown)."""
    if spec.kind == "rectangle":
        (x0, y0), (x1, y1) = spec.corners
        count = _points_along(x1 - x0, spec.h) * _points_along(y1 - y0, spec.h)
    elif spec.kind == "file":
        count = _msh_nodes(Path(spec.path)) if spec.path else None
        if count is None:
            return None
    else:
        count = estimated_vertices(spec)
    return count * 4.0**spec.refinements  # a uniform refinement quadruples the cells


def _points_along(length: float, h: float) -> float:
    """Vertices on a side of ``length`` cut into cells of at most ``h`` (``inf`` beyond the
    floats: ``ceil`` of ``inf`` raises, an integer product may not convert back)."""
    cells = length / h
    return float(math.ceil(cells)) + 1.0 if math.isfinite(cells) else math.inf


def estimate(
    spec: DomainSpec, model: str = "membrane", degree: int = 1, linear_solver: str = "direct"
) -> Estimate | None:
    """Vertices, dofs (3 components; P2 adds the edge midpoints, about 3 per vertex) and the
    peak memory of meshing only and of a solve with ``linear_solver``; None when the mesh size
    cannot be known."""
    vertices = mesh_vertices(spec)
    if vertices is None:
        return None
    nodes = vertices if degree == 1 else 4.0 * vertices
    dofs = 3.0 * nodes
    per_dof = bytes_per_dof(model, degree, linear_solver)
    return Estimate(vertices, dofs, vertices * BYTES_PER_VERTEX_MESH, dofs * per_dof)


def require_fits(
    spec: DomainSpec,
    model: str = "membrane",
    degree: int = 1,
    solve: bool = True,
    what: str = "[domain]",
    comm: MPI.Comm = MPI.COMM_WORLD,
    linear_solver: str = "direct",
) -> Estimate | None:
    """Raise :class:`ResourceError` (on every rank) when the mesh of ``spec`` (and its solve
    with ``linear_solver``, if ``solve``) would need more than :data:`MEMORY_SHARE` of this
    machine's memory.

    The ranks on this machine need their share of the whole run's memory (the mesh is
    distributed evenly), plus :data:`BASE_BYTES` each. ``linear_solver`` is the one the solve
    will use (``"auto"`` resolved: :func:`~shellobstacle.solvers.auto.estimated_linear_solver`).
    """
    est = estimate(spec, model, degree, linear_solver)
    if est is None:
        return None

    def need_with(bytes_solve: float) -> float:
        return memory.need(bytes_solve if solve else est.bytes_mesh, comm)

    need = need_with(est.bytes_solve)
    have = memory.machine_memory()
    if not need <= MEMORY_SHARE * have:
        size = _describe(spec)
        task = "solving" if solve else "meshing"
        if not math.isfinite(need):
            raise ResourceError(
                f"{what}: {size} gives more vertices than a float can count (over 1e308): "
                "use a larger h"
            )
        multigrid = need_with(est.dofs * bytes_per_dof(model, degree, "multigrid"))
        levels = coarsening_steps(spec) + spec.refinements > 0
        needs = memory.multigrid_needs_levels(model) and not levels
        refine = " with domain.refinements >= 1" if needs else ""
        instead = (
            f', solver.linear_solver = "multigrid"{refine} (about {multigrid / GIB:.3g} GiB)'
            if solve and multigrid <= MEMORY_SHARE * have and linear_solver != "multigrid"
            else ""
        )
        raise ResourceError(
            f"{what}: {size} gives about {est.vertices:.2g} vertices and {est.dofs:.2g} dofs; "
            f"{task} needs about {need / GIB:.3g} GiB on this machine, more than "
            f"{MEMORY_SHARE:.0%} of its {have / GIB:.3g} GiB: use a larger h{instead}, more "
            "machines under MPI, or pass --force"
        )
    return est


def _describe(spec: DomainSpec) -> str:
    """The sizes that set the mesh's vertices, as the user wrote them."""
    parts = [f"h = {spec.h:g}" if spec.kind != "file" else f"the mesh {spec.path}"]
    for name in ("central_h", "edge_h"):
        if getattr(spec, name) is not None:
            parts.append(f"{name} = {getattr(spec, name):g}")
    if spec.refinements:
        parts.append(f"{spec.refinements} refinement(s)")
    return ", ".join(parts)


def _msh_nodes(path: Path) -> float | None:
    """The node count in a gmsh ``.msh`` file's ``$Nodes`` header (formats 2 and 4)."""
    try:
        with path.open("rb") as f:
            head = f.read(1 << 16).decode("latin-1")
    except OSError:
        return None
    m = re.search(r"\$MeshFormat\s+([\d.]+)", head)
    n = re.search(r"\$Nodes\s+([^\n]+)", head)
    if not (m and n):
        return None
    fields = n.group(1).split()
    try:
        count = float(fields[1] if m.group(1).startswith("4") else fields[0])
    except (IndexError, ValueError):
        return None
    return count if math.isfinite(count) and count >= 0 else None  # else gmsh will refuse it
