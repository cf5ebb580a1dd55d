"""Helpers shared by the command-line tests: running ``main``, asserting a user error, and
``examples/small.toml`` on a coarse mesh with one change (the error tests' config)."""

from __future__ import annotations

import copy
import os
import shutil
import sys
import tempfile
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mpi4py import MPI

import pytest

from shellobstacle.cli.main import main
from shellobstacle.config.loader import to_toml

COMM = MPI.COMM_WORLD
#: the command line's tests run on one rank (a test on 2 ranks is marked ``mpi``)
serial = pytest.mark.skipif(COMM.size > 1, reason="CLI tests run serially")
EXAMPLES = Path(__file__).parents[1] / "examples"
SMALL = EXAMPLES / "small.toml"
#: ``examples/small.toml`` on a coarse mesh (h = 0.1): the config the error tests change
BASE: dict[str, Any] = tomllib.loads(SMALL.read_text())
BASE["domain"]["h"] = 0.1
#: the value that removes a key or a section in :func:`changed`
DELETE = object()


def run(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    """``main(args)``: exit code, stdout, stderr."""
    capsys.readouterr()
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def run_on_all_ranks(args: list[str]) -> int:
    """``main(args)`` on every rank; returns once rank 0 has written its files."""
    code = main(args)
    COMM.barrier()
    return code


def assert_user_error(code: int, err: str, *needles: str) -> None:
    """Exit code 2, one ``shellobstacle: error:`` line naming every needle, no traceback."""
    assert code == 2, err
    assert "Traceback" not in err, err
    assert err.startswith("shellobstacle: error: "), err
    assert len(err.strip().splitlines()) == 1, err
    for needle in needles:
        assert needle in err, f"{needle!r} not in {err!r}"


def shared_folder(tmp_path: Path) -> Iterator[Path]:
    """A folder that every MPI rank sees (rank 0's temporary folder), removed afterwards."""
    path = Path(tempfile.mkdtemp(dir=tmp_path)) if COMM.rank == 0 else None
    path = COMM.bcast(path, root=0)
    yield path
    COMM.barrier()
    if COMM.rank == 0:
        shutil.rmtree(path, ignore_errors=True)


def mpiexec() -> str | None:
    """The mpiexec that ``./run test`` uses (``MPIEXEC``, else the one beside this Python, else
    the one on PATH), or None."""
    beside = Path(sys.executable).parent / "mpiexec"
    if os.environ.get("MPIEXEC"):
        return os.environ["MPIEXEC"]
    return str(beside) if beside.exists() else shutil.which("mpiexec")


def changed(changes: dict[str, Any] | None = None) -> dict[str, Any]:
    """:data:`BASE` with ``{"section.key": value}`` or ``{"section": table}`` applied (the
    value :data:`DELETE` removes the key or the section)."""
    data = copy.deepcopy(BASE)
    for dotted, value in (changes or {}).items():
        section, _, key = dotted.partition(".")
        if not key:  # a whole section
            if value is DELETE:
                del data[section]
            else:
                data[section] = value
        elif value is DELETE:
            del data[section][key]
        else:
            data.setdefault(section, {})[key] = value
    return data


def write_config(folder: Path, changes: dict[str, Any] | None = None, name: str = "c.toml") -> Path:
    """:func:`changed` written to ``folder / name``."""
    data = changed(changes)
    # a "section" that is not a table has to come before the first [table]
    top = [f"{k} = {v!r}" for k, v in data.items() if not isinstance(v, dict)]
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    path = folder / name
    path.write_text("\n".join([*top, to_toml(tables)]))
    return path


def check_error(capsys, tmp_path, changes, *needles, command="check") -> str:
    """Write the changed config, run ``command`` on it and assert a user error."""
    path = write_config(tmp_path, changes)
    extra = ["-o", str(tmp_path / "out"), "-q"] if command == "solve" else []
    code, _, err = run(capsys, command, str(path), *extra)
    assert_user_error(code, err, *needles)
    return err


def check_row(out: str, name: str) -> str:
    """The row of the assumption ``name`` in the table ``check`` prints."""
    return next(line for line in out.splitlines() if line.startswith(name))
