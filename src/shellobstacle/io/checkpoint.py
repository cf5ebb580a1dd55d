"""Records of the finished steps of a sweep, so that ``--resume`` continues an interrupted one.

A sweep (the κ ladder of batch 1, the (q, level) grid of batch 2, a load sweep, the meshes of the
solver comparison) records every finished step in ``OUT/steps/`` as soon as it is done:

``meta.json``
    The command, its sweep options and the resolved configuration of the run; ``--resume``
    refuses a folder whose ``meta.json`` differs from the new invocation, naming the difference.
``<step>.json``
    One record per finished step: its table row(s) and the numbers it produced (Newton steps,
    seconds, ...). Written atomically (temporary file, then ``os.replace``) by rank 0.
``<step>.npy``
    The solution ζ of the last finished step of a sweep, when a later step starts from it (warm
    start) or compares with it (Cauchy differences). Stored independently of the partition: one
    row ``(y1, y2, ζ_1, ζ_2, ζ_3)`` per node of the finite element space, sorted by the
    coordinates; it is restored on a re-generated mesh by matching the node coordinates (to
    1e-9 of the domain's size), which also verifies that the mesh is the interrupted run's.
    Older vectors of a sweep are deleted once a newer step is recorded, and all of them when
    the command finishes.

Each step's mesh is also fingerprinted (global numbers of vertices and cells, the sums of the
vertex coordinates) in ``<sweep>_mesh.json``; a resumed sweep on a different mesh is refused.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mpi4py import MPI

import dolfinx
import numpy as np

from shellobstacle.io.folders import ResultsError
from shellobstacle.io.records import jsonable, write_json

__all__ = [
    "MESH_DIFFERS",
    "STEPS",
    "Checkpoint",
    "CheckpointError",
    "meta_differences",
    "open_checkpoint",
]

#: the subfolder of a result folder that holds the step records
STEPS = "steps"
MESH_DIFFERS = "the mesh differs from the interrupted run's: cannot resume"
#: meta.json keys that must agree for ``--resume`` (the rest is information)
COMPARED = ("command", "batch", "mode", "options", "config")


class CheckpointError(ResultsError):
    """The records in ``steps/`` cannot be used (different run, different mesh, missing file)."""


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=-]", "_", name)


def _normalize(data: Any) -> Any:
    """``data`` as it reads back from JSON (tuples → lists, numpy scalars → Python)."""
    return json.loads(json.dumps(data, default=jsonable))


def meta_differences(old: Any, new: Any, path: str = "") -> list[str]:
    """Human-readable differences ``key: old → new`` between two JSON-like values."""
    if isinstance(old, Mapping) and isinstance(new, Mapping):
        out = []
        for key in list(old) + [k for k in new if k not in old]:
            sub = f"{path}.{key}" if path else str(key)
            if key not in new:
                out.append(f"{sub}: {old[key]!r} in the interrupted run, absent now")
            elif key not in old:
                out.append(f"{sub}: absent in the interrupted run, {new[key]!r} now")
            else:
                out += meta_differences(old[key], new[key], sub)
        return out
    if old != new:
        return [f"{path}: {old!r} in the interrupted run, {new!r} now"]
    return []


def open_checkpoint(
    folder: Path,
    meta: dict[str, Any],
    resume: bool,
    comm: MPI.Comm = MPI.COMM_WORLD,
) -> Checkpoint:
    """Start recording in ``folder/steps`` (a fresh run) or check it for ``--resume``.

    A fresh run writes ``meta.json`` into a new ``steps/`` (an earlier one is removed, though
    :func:`~shellobstacle.io.folders.prepare_folder` gives a fresh run a folder without it).
    A resumed run compares ``meta`` with the recorded one on the keys :data:`COMPARED` and
    refuses (:class:`CheckpointError`, naming the difference) if they differ.
    """
    steps = Path(folder) / STEPS
    meta = _normalize(meta)
    error, old = None, None
    if comm.rank == 0:
        if resume:
            again = "cannot resume: start again with --overwrite instead of --resume"
            try:
                old = json.loads((steps / "meta.json").read_text())
            except (OSError, ValueError) as err:
                old, error = None, f"cannot read {steps / 'meta.json'}: {err}; {again}"
            if old is not None and not isinstance(old, dict):
                old, error = None, f"{steps / 'meta.json'} is not the record of a run; {again}"
            if old is not None:
                diff = meta_differences(
                    {k: old.get(k) for k in COMPARED}, {k: meta.get(k) for k in COMPARED}
                )
                if diff:
                    more = f" (and {len(diff) - 3} more)" if len(diff) > 3 else ""
                    error = (
                        f"cannot resume '{folder}': it holds an interrupted run of a different "
                        f"command or configuration: {'; '.join(diff[:3])}{more}"
                    )
        else:
            if steps.exists():
                shutil.rmtree(steps)
            steps.mkdir(parents=True)
    error, old = comm.bcast((error, old), root=0)
    if error:
        raise CheckpointError(error)
    if not resume:
        write_json(steps / "meta.json", meta, comm)
    checkpoint = Checkpoint(folder, comm)
    checkpoint.recorded_meta = old
    return checkpoint


class Checkpoint:
    """The step records of one result folder; ``Checkpoint(None)`` records nothing.

    Records are written by rank 0 and read by rank 0 and broadcast, so every rank takes the
    same decisions. Vectors are gathered to rank 0 to be written and read by every rank.
    """

    def __init__(
        self,
        folder: Path | None,
        comm: MPI.Comm = MPI.COMM_WORLD,
        prefix: str = "",
        stats: dict[str, int] | None = None,
    ) -> None:
        self.dir = None if folder is None else Path(folder) / STEPS
        self.comm = comm
        self.prefix = prefix
        #: shared by all scopes: records loaded (steps not recomputed) and saved
        self.stats = stats if stats is not None else {"loaded": 0, "saved": 0}
        #: the interrupted run's meta.json (set by :func:`open_checkpoint` on resume)
        self.recorded_meta: dict[str, Any] | None = None

    @property
    def enabled(self) -> bool:
        """Whether steps are recorded at all."""
        return self.dir is not None

    def scope(self, name: str) -> Checkpoint:
        """The same store with the keys prefixed by ``name`` (one sweep)."""
        prefix = f"{self.prefix}_{name}" if self.prefix else name
        return Checkpoint(
            None if self.dir is None else self.dir.parent, self.comm, prefix, self.stats
        )

    def path(self, key: str, suffix: str) -> Path:
        """The file of ``key`` (``.json`` record or ``.npy`` vector)."""
        assert self.dir is not None
        name = f"{self.prefix}_{key}" if self.prefix else key
        return self.dir / f"{_safe(name)}{suffix}"

    # -- records ------------------------------------------------------------------------------
    def _read(self, key: str) -> dict[str, Any] | None:
        if self.dir is None:
            return None
        record = None
        if self.comm.rank == 0:
            p = self.path(key, ".json")
            if p.is_file():
                record = json.loads(p.read_text())
        return self.comm.bcast(record, root=0)

    def load(self, key: str) -> dict[str, Any] | None:
        """The record of a finished step (the same on every rank), or None."""
        record = self._read(key)
        if record is not None:
            self.stats["loaded"] += 1
        return record

    def save(self, key: str, record: dict[str, Any]) -> None:
        """Record a finished step (atomically, rank 0)."""
        if self.dir is None:
            return
        write_json(self.path(key, ".json"), record, self.comm)
        self.stats["saved"] += 1

    # -- meshes -------------------------------------------------------------------------------
    def check_mesh(self, mesh: Any, key: str = "mesh") -> None:
        """Record the mesh's fingerprint, or compare it with the recorded one.

        Raises:
            CheckpointError: the mesh is not the one of the interrupted run.
        """
        if self.dir is None:
            return
        mine = mesh_fingerprint(mesh)
        old = self._read(key)
        if old is None:
            write_json(self.path(key, ".json"), mine, self.comm)
            return
        same = old["vertices"] == mine["vertices"] and old["cells"] == mine["cells"]
        for a, b in zip(old["sums"], mine["sums"], strict=True):
            same = same and abs(a - b) <= 1e-10 * max(abs(a), abs(b), float(mine["vertices"]))
        if not same:
            raise CheckpointError(
                f"{MESH_DIFFERS} ({self.prefix or 'mesh'}: {old['vertices']} vertices, "
                f"{old['cells']} cells then, {mine['vertices']} vertices, {mine['cells']} cells "
                "now, or moved vertices)"
            )

    # -- vectors ------------------------------------------------------------------------------
    def save_vector(self, key: str, u: Any) -> None:
        """Save the Function ``u`` (Lagrange, any block size) partition-independently.

        Collective. Rows ``(coordinates, values)`` of the owned nodes are gathered to rank 0,
        sorted by the coordinates and written atomically.
        """
        if self.dir is None:
            return
        V = u.function_space
        imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
        gdim = V.mesh.geometry.dim
        n = imap.size_local
        x = V.tabulate_dof_coordinates()[:n, :gdim]
        rows = np.hstack([x, u.x.array[: n * bs].reshape(n, bs)])
        parts = self.comm.gather(rows, root=0)
        if self.comm.rank == 0:
            data = np.vstack(parts)
            data = data[np.lexsort(data[:, gdim - 1 :: -1].T)] if data.size else data
            path = self.path(key, ".npy")
            tmp = path.with_name(f".{path.name}.tmp")
            with tmp.open("wb") as f:
                np.save(f, data)
            os.replace(tmp, path)

    def restore_vector(self, key: str, u: Any) -> None:
        """Set the Function ``u`` from :meth:`save_vector`'s file (collective).

        Raises:
            CheckpointError: the file is missing, or the nodes of ``u``'s space are not the
                saved ones (the mesh differs from the interrupted run's).
        """
        assert self.dir is not None
        path = self.path(key, ".npy")
        error = None
        if self.comm.rank == 0 and not path.is_file():
            error = f"the record of step {path.stem} has no saved solution {path}: cannot resume"
        error = self.comm.bcast(error, root=0)
        if error:
            raise CheckpointError(error)
        data = np.load(path)
        V = u.function_space
        imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
        gdim = V.mesh.geometry.dim
        n = imap.size_local + imap.num_ghosts
        problem = ""
        if data.ndim != 2 or data.shape[1] != gdim + bs:
            problem = f"saved {data.shape[1] - gdim} values per node, the space has {bs}"
        elif data.shape[0] != imap.size_global:
            problem = f"{data.shape[0]} nodes then, {imap.size_global} now"
        idx = np.full(n, -1, dtype=np.int64)
        if not problem:
            idx = _match(data[:, :gdim], V.tabulate_dof_coordinates()[:n, :gdim])
        unmatched = self.comm.allreduce(int(np.count_nonzero(idx < 0)), op=MPI.SUM)
        problem = self.comm.allreduce(problem, op=MPI.MAX)  # the same on every rank
        if problem or unmatched:
            detail = problem or f"{unmatched} nodes not found in the saved solution"
            raise CheckpointError(f"{MESH_DIFFERS} ({path.name}: {detail})")
        u.x.array[: n * bs] = data[idx, gdim:].ravel()
        u.x.scatter_forward()

    def drop_vector(self, key: str | None) -> None:
        """Delete a vector (and its solver state) that no later step needs (rank 0)."""
        if self.dir is None or key is None or self.comm.rank != 0:
            return
        self.path(key, ".npy").unlink(missing_ok=True)
        self.path(f"{key}.zone", ".npy").unlink(missing_ok=True)

    # -- solver state -------------------------------------------------------------------------
    def save_solver(self, key: str, solver: Any) -> None:
        """Save the state a Newton solver carries between steps (its contact zone), collective.

        A resumed run restores it with :meth:`restore_solver`, so that the steps it solves
        again are those of the uninterrupted run (to the last bit serially; under MPI to
        round-off, as MUMPS' parallel factorization does not repeat its last bits from run to
        run).
        """
        if self.dir is None:
            return
        zone = solver.zone_indicator()
        if zone is not None:
            self.save_vector(f"{key}.zone", zone)

    def restore_solver(self, key: str, solver: Any) -> None:
        """Give ``solver`` the state :meth:`save_solver` saved with step ``key`` (collective)."""
        if self.dir is None or getattr(solver, "zone", None) is None:
            return
        exists = self.comm.bcast(
            self.path(f"{key}.zone", ".npy").is_file() if self.comm.rank == 0 else None, root=0
        )
        if not exists:
            return
        u = dolfinx.fem.Function(solver.problem.V)
        self.restore_vector(f"{key}.zone", u)
        solver.set_zone_indicator(u)

    def finish(self) -> None:
        """The command finished: delete the remaining vectors (the JSON records stay)."""
        if self.dir is None or self.comm.rank != 0:
            return
        for p in self.dir.glob("*.npy"):
            p.unlink(missing_ok=True)


def _match(saved: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Index into ``saved`` of each row of ``local`` (equal to 1e-9 of the extent), else -1.

    The points of a planar mesh (at most two varying coordinates) are binned on a grid finer
    than the distance of any two nodes; a point is looked up in its own bin and, when it sits
    on a bin border, in the neighbouring ones.
    """
    out = np.full(local.shape[0], -1, dtype=np.int64)
    if saved.shape[0] == 0:
        return out
    extent = float(np.max(np.ptp(saved, axis=0)))
    tol = 1e-9 * max(extent, 1e-300)
    varying = np.ptp(saved, axis=0) > 0
    constant = np.all(np.abs(local[:, ~varying] - saved[0, ~varying]) <= tol, axis=1)
    if varying.sum() > 2:
        raise CheckpointError("saved solutions are supported on planar meshes only")
    saved, local = saved[:, varying], local[:, varying]
    dims = saved.shape[1]
    grid = 8.0 * tol
    lo = saved.min(axis=0)

    def key(cells: np.ndarray) -> np.ndarray:
        k = np.zeros(cells.shape[0], dtype=np.int64)
        for d in range(dims):  # at most 1.25e8 + 1 bins per axis: fits 31 bits
            k = k * np.int64(2**31) + cells[:, d]
        return k

    k_saved = key(np.rint((saved - lo) / grid).astype(np.int64))
    order = np.argsort(k_saved)
    k_sorted = k_saved[order]
    q_local = np.rint((local - lo) / grid).astype(np.int64)
    offsets = np.array(np.meshgrid(*[[0, -1, 1]] * dims, indexing="ij")).reshape(dims, -1).T
    for off in offsets:  # (0, 0) first
        todo = np.flatnonzero((out < 0) & constant)
        if todo.size == 0:
            break
        k = key(q_local[todo] + off)
        pos = np.minimum(np.searchsorted(k_sorted, k), k_sorted.size - 1)
        hit = k_sorted[pos] == k
        cand = order[pos[hit]]
        close = np.max(np.abs(saved[cand] - local[todo[hit]]), axis=1, initial=0.0) <= tol
        out[todo[hit][close]] = cand[close]
    return out


def mesh_fingerprint(mesh: Any) -> dict[str, Any]:
    """Global numbers of vertices and cells, the sums of the nodes' coordinates and squares."""
    tdim = mesh.topology.dim
    nodes = mesh.geometry.index_map()
    x = mesh.geometry.x[: nodes.size_local, : mesh.geometry.dim]
    sums = mesh.comm.allreduce(np.concatenate([x.sum(axis=0), (x**2).sum(axis=0)]), op=MPI.SUM)
    return {
        "vertices": int(nodes.size_global),
        "cells": int(mesh.topology.index_map(tdim).size_global),
        "sums": [float(s) for s in sums],
    }
