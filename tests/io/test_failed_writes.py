"""A failed write leaves the previous file whole: a figure is written to a temporary file and
renamed, a ParaView ``.bp`` folder appears complete or not at all."""

from __future__ import annotations

from pathlib import Path

from mpi4py import MPI

import pytest
from cli_helpers import serial

pytestmark = serial


def test_failed_figure_keeps_the_previous_png(tmp_path, monkeypatch) -> None:
    """A figure is written to a temporary file and renamed: a failure leaves the old file."""
    import matplotlib.pyplot as plt

    from shellobstacle.post.plotting import save_atomically

    path = tmp_path / "cross_section.png"
    path.write_bytes(b"previous figure")
    fig = plt.figure()

    def broken_savefig(fname, **kwargs):
        Path(fname).write_bytes(b"half a PNG")
        raise OSError("disk full")

    monkeypatch.setattr(fig, "savefig", broken_savefig)
    with pytest.raises(OSError, match="disk full"):
        save_atomically(fig, path, dpi=10)
    plt.close(fig)
    assert path.read_bytes() == b"previous figure"
    assert list(tmp_path.iterdir()) == [path]


class _FakeVTXWriter:
    """Stands in for dolfinx.io.VTXWriter: writes a folder, optionally fails half-way."""

    fail = False

    def __init__(self, comm, filename, functions, engine):
        self.folder = Path(filename)
        self.folder.mkdir()
        (self.folder / "md.idx").write_text("new")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def write(self, t):
        if self.fail:
            raise RuntimeError("ADIOS2 failed")
        (self.folder / "data.0").write_text("new")


@pytest.mark.parametrize("fail", [False, True])
def test_vtx_folder_is_replaced_atomically(tmp_path, monkeypatch, fail: bool) -> None:
    """A .bp folder appears complete or not at all; an old one survives a failed write."""
    import dolfinx.io

    from shellobstacle.io import paraview as output

    monkeypatch.setattr(_FakeVTXWriter, "fail", fail)
    monkeypatch.setattr(dolfinx.io, "VTXWriter", _FakeVTXWriter)
    path = tmp_path / "surface.bp"
    path.mkdir()
    (path / "md.idx").write_text("old")
    (path / "stale.0").write_text("old")
    if fail:
        with pytest.raises(RuntimeError, match="ADIOS2 failed"):
            output._write(MPI.COMM_WORLD, path, [])
        assert sorted(p.name for p in path.iterdir()) == ["md.idx", "stale.0"]
    else:
        assert output._write(MPI.COMM_WORLD, path, []) == path
        assert sorted(p.name for p in path.iterdir()) == ["data.0", "md.idx"]
        assert (path / "md.idx").read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["surface.bp"]
