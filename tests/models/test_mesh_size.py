"""The mesh sizes are computed once per mesh: later calls reduce nothing (serial and MPI)."""

from __future__ import annotations

import gc
import weakref

import pytest
from conftest import square

from shellobstacle.mesh import measures


@pytest.mark.mpi
def test_mesh_size_is_computed_once_per_mesh(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two calls of each size on one mesh measure its cells once each; another mesh is
    measured anew, and a mesh released is forgotten."""
    measured = []
    diameters = measures._cell_diameters
    monkeypatch.setattr(
        measures, "_cell_diameters", lambda mesh: measured.append(mesh) or diameters(mesh)
    )
    mesh, other = square(n=4), square(n=8)
    h = measures.mesh_size(mesh)
    assert measures.mesh_size(mesh) == h and len(measured) == 1
    h_min = measures.mesh_size_min(mesh)
    assert measures.mesh_size_min(mesh) == h_min and len(measured) == 2
    assert measures.mesh_size(other) == pytest.approx(h / 2) and len(measured) == 3
    released = weakref.ref(other)
    del measured[:], other
    gc.collect()
    assert released() is None and mesh in measures._SIZES
