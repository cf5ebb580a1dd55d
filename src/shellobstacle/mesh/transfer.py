"""Interpolation between meshes of one domain (DOLFINx's non-matching interpolation).

Interpolating ``f`` on one mesh into a space ``V`` on another needs, for each of ``V``'s
interpolation points, the cell of ``f``'s mesh that holds it: DOLFINx finds them
(``create_interpolation_data``, a bounding-box search and a point location) and then
evaluates ``f`` there (``interpolate_nonmatching``). The search costs far more than the
evaluation and depends only on the two spaces, so :class:`Interpolation` makes it once per
source space and keeps it. On nested meshes (a mesh and its uniform refinements) a Lagrange
function of a coarser mesh is interpolated exactly.
"""

from __future__ import annotations

from typing import Any

import dolfinx
import numpy as np

__all__ = ["Interpolation"]


class Interpolation:
    """Interpolation into ``V`` of Functions on any mesh of the same domain (collective).

    Args:
        V: the space interpolated into.
        padding: how far outside a source cell a point may lie and still be found in it.

    The point location of each source space is kept (with the space) for the life of this
    object: keep one per target space while its sources are reused.
    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, padding: float = 1e-12) -> None:
        self.V = V
        self.padding = padding
        mesh = V.mesh
        imap = mesh.topology.index_map(mesh.topology.dim)
        self.cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
        self._data: dict[int, tuple[dolfinx.fem.FunctionSpace, Any]] = {}
        self.searches = 0  # point locations made

    def data(self, source: dolfinx.fem.FunctionSpace) -> Any:
        """The owners of ``V``'s interpolation points in ``source``'s mesh (made once)."""
        kept = self._data.get(id(source))
        if kept is None or kept[0] is not source:
            found = dolfinx.fem.create_interpolation_data(
                self.V, source, self.cells, padding=self.padding
            )
            self.searches += 1
            kept = self._data[id(source)] = (source, found)
        return kept[1]

    def forget(self) -> None:
        """Drop the kept point locations (and the source spaces they hold)."""
        self._data.clear()

    def into(self, f: dolfinx.fem.Function, out: dolfinx.fem.Function) -> None:
        """``out ← f`` interpolated (``out`` a Function of ``V`` or of a space that shares
        its mesh and interpolation points)."""
        out.interpolate_nonmatching(f, self.cells, self.data(f.function_space))
        out.x.scatter_forward()

    def __call__(self, f: dolfinx.fem.Function, name: str | None = None) -> dolfinx.fem.Function:
        """``f`` interpolated into a new Function of ``V`` (named ``name``, else ``f``'s)."""
        out = dolfinx.fem.Function(self.V, name=f.name if name is None else name)
        self.into(f, out)
        return out
