"""Self-describing result folders: results are never mixed or lost, files written atomically.

A folder *holds results* when it has ``summary.json`` (solve), ``report.md`` (experiment,
reproduce) or a finished step in ``steps/`` (an interrupted experiment or reproduce, which
``--resume`` continues). A folder without them is the leftover of a run that failed early and
does not block a rerun. Replacing results (``--overwrite``) writes the new run beside the old
folder and swaps it in whole at the end (:class:`ResultFolder`). A run locks its folder before it
looks into it (:mod:`shellobstacle.io.lock`): a second run into a folder that a live run is
writing is refused.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI

from shellobstacle.io.lock import FolderInUseError, lock_folder, release_folder

__all__ = [
    "ResultFolder",
    "ResultsError",
    "has_step_records",
    "holds_results",
    "prepare_folder",
    "staging_folder",
]


class ResultsError(ValueError):
    """The output folder cannot be used as asked (it holds results, it is a file, ...)."""


#: files whose presence means a folder holds results (besides finished steps in ``steps/``)
RESULT_FILES = ("summary.json", "report.md")
#: files only a run writes: a folder with one of them is a result folder
RUN_MARKERS = ("log.txt", "summary.json", "report.md", "steps/meta.json")
#: what a run writes; without results beside them, they are what a failed run left
RUN_FILES = ("config.toml", "log.txt", "checks.txt", "steps")
RUN_SUFFIXES = (".bp", ".png", ".csv")
#: the temporary files of atomic writes (:func:`~shellobstacle.io.records.atomic_write`,
#: figures, ParaView folders)
TEMPORARY_SUFFIXES = (".tmp", ".tmp.bp", ".old")


def staging_folder(target: Path) -> Path:
    """The hidden folder beside ``target`` that a run replacing ``target`` writes into."""
    return target.with_name(f".{target.name}.partial")


def _real(target: Path) -> Path:
    """``target`` as an absolute path; for a symbolic link, the folder it points to (which a
    replacement replaces, keeping the link)."""
    return Path(os.path.realpath(target) if target.is_symlink() else os.path.abspath(target))


def _aside(target: Path) -> Path:
    """Where ``target`` is moved for the moment of the swap."""
    return target.with_name(f".{target.name}.old")


def has_step_records(folder: Path) -> bool:
    """Whether ``folder/steps`` records a finished step (not only meta.json and mesh
    fingerprints, which :mod:`shellobstacle.io.checkpoint` writes before the first step)."""
    steps = folder / "steps"
    return steps.is_dir() and any(
        p.name != "meta.json" and not p.name.endswith("mesh.json") for p in steps.glob("*.json")
    )


def holds_results(folder: Path) -> bool:
    """Whether ``folder`` holds results: a summary, a report or finished steps."""
    return any((folder / n).exists() for n in RESULT_FILES) or has_step_records(folder)


def _leftover(name: str) -> bool:
    """Whether an entry of a folder is one a run writes (not a file of the user's)."""
    if name.startswith("."):
        return name.endswith(TEMPORARY_SUFFIXES)
    return name in RUN_FILES or name.endswith(RUN_SUFFIXES)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


@dataclass(frozen=True)
class ResultFolder:
    """Where a run writes (``path``) and where its results are once it ends (``target``).

    A run writes straight into ``target`` when that holds no results. A run that replaces
    results (``--overwrite``) writes into :func:`staging_folder` beside it, and
    :meth:`commit` swaps the new folder in whole when the run ends: until then ``target`` is
    untouched, and nothing of the old run survives in the new folder.
    """

    target: Path
    path: Path

    @property
    def staged(self) -> bool:
        """Whether the run writes beside ``target`` and replaces it when it ends."""
        return self.path != self.target

    def commit(self, comm: MPI.Comm = MPI.COMM_WORLD) -> None:
        """The run has ended with results: replace ``target`` by them (collective).

        Raises:
            ResultsError: the swap failed; ``target`` is then unchanged.
        """
        if not self.staged:
            return
        comm.barrier()  # every rank has closed its files (ParaView output is collective)
        error = None
        if comm.rank == 0:
            try:
                _swap(self.path, _real(self.target))
            except OSError as err:
                error = (
                    f"cannot move the new results from '{self.path}' to '{self.target}' "
                    f"({err.strerror or err}): '{self.target}' is unchanged, the new results "
                    f"are in '{self.path}'"
                )
        error = comm.bcast(error, root=0)
        if error:
            raise ResultsError(error)


def _swap(new: Path, target: Path) -> None:
    """Put the folder ``new`` in the place of ``target``; on failure ``target`` is unchanged.

    A folder cannot be renamed onto a non-empty one: the old folder is moved aside to
    ``.NAME.old`` for the moment between the two renames (a run cut short there is repaired by
    :func:`prepare_folder`), then deleted.
    """
    if not target.exists():
        os.replace(new, target)
        return
    old = _aside(target)
    _remove(old)
    os.replace(target, old)
    try:
        os.replace(new, target)
    except OSError:
        os.replace(old, target)
        raise
    shutil.rmtree(old, ignore_errors=True)


def prepare_folder(
    out: str | Path | None,
    default: str,
    overwrite: bool,
    comm: MPI.Comm = MPI.COMM_WORLD,
    resume: bool = False,
) -> ResultFolder:
    """Choose and create the result folder (rank 0); the same on every rank.

    * ``out=None``: a new folder ``default``, ``default-2``, ... (earlier folders are never
      touched).
    * ``out`` missing or empty, or holding only what a run writes before it has results
      (``config.toml``, ``log.txt``, ``steps/`` without a finished step, ...): those are
      removed and the run writes into ``out``; the rerun of a failed command proceeds.
    * ``out`` holding results (``summary.json``, ``report.md``, finished steps): refused,
      unless ``overwrite``: then the run writes into ``.NAME.partial`` beside it and
      :meth:`ResultFolder.commit` swaps it in at the end. A ``.NAME.partial`` left by a failed
      or interrupted run is removed, unless it holds finished steps (then only
      ``overwrite`` removes it; ``resume`` continues it).
    * ``resume``: continues ``.NAME.partial`` if it holds the records of an interrupted run
      (``steps/meta.json``), else ``out`` itself, which must hold them.
    * ``out`` (with ``.NAME.partial``) being written by another live run: refused. Rank 0
      keeps the folder's lock until :func:`shellobstacle.io.lock.release_folders`.

    Raises:
        ResultsError: the folder cannot be used as asked; the message names the path and fix.
    """
    error: str | None = None
    folder: ResultFolder | None = None
    if comm.rank == 0:
        try:
            if resume:
                folder, error = _resumed(out)
            elif out is None:
                folder, error = _new(Path(default))
            else:
                folder, error = _given(Path(out), overwrite)
        except OSError as err:
            where = err.filename or out or default
            error = f"cannot prepare the output folder '{where}': {err.strerror or err}"
            error += ": choose another -o"
    error, folder = comm.bcast((error, folder), root=0)
    if error:
        raise ResultsError(error)
    assert folder is not None
    return folder


def _claim(target: Path) -> str | None:
    """Lock ``target`` for this run (once its parent exists); why not, if another run holds it."""
    if not target.parent.is_dir():
        return None  # nothing there yet; _given claims it once the parents are made
    try:
        lock_folder(target)
    except FolderInUseError as busy:
        return (
            f"output folder '{target}' is in use by another run ({busy.owner}): wait for it to "
            "end, or choose another -o"
        )
    return None


def _resumed(out: str | Path | None) -> tuple[ResultFolder | None, str | None]:
    if out is None:
        return None, "--resume needs -o OUT, the result folder of the interrupted run"
    target = Path(out)
    if busy := _claim(target):
        return None, busy
    partial = staging_folder(_real(target))
    if (partial / "steps" / "meta.json").is_file():
        return ResultFolder(target, partial), None
    if not target.is_dir():
        return None, (
            f"--resume: '{target}' does not exist: there is nothing to resume "
            "(run without --resume to start)"
        )
    if not (target / "steps" / "meta.json").is_file():
        return None, (
            f"--resume: '{target}' holds no records of an interrupted run "
            "(no steps/meta.json): cannot resume"
        )
    return ResultFolder(target, target), None


def _new(base: Path) -> tuple[ResultFolder | None, str | None]:
    path, k = base, 1
    while True:
        try:
            if _claim(path) is None:  # (a name another run is claiming is skipped)
                path.mkdir(parents=True)
                return ResultFolder(path, path), None
        except FileExistsError:
            release_folder(path)
        except OSError as err:
            return None, (
                f"cannot create the output folder '{path}' ({err.strerror or err}): run from "
                "a writable folder or choose one with -o"
            )
        k += 1
        path = base.with_name(f"{base.name}-{k}")


def _blocked_parent(path: Path) -> str | None:
    """Why ``path`` cannot be created, naming the ancestor at fault, or None."""
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        if parent.is_symlink():
            return _dangling(parent)
        parent = parent.parent
    if not parent.is_dir():
        return f"'{parent}' is a file, so the output folder '{path}' cannot be created"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"'{parent}' is not writable, so the output folder '{path}' cannot be created"
    return None


def _dangling(link: Path) -> str:
    """A symbolic link to nothing: where it points (a path the user can create)."""
    return f"'{link}' is a symbolic link to '{os.readlink(link)}', which does not exist"


def _given(path: Path, overwrite: bool) -> tuple[ResultFolder | None, str | None]:
    again = "choose another -o"
    if path.is_symlink() and not path.exists():
        return None, f"{_dangling(path)}: create that folder or {again}"
    if path.exists() and not path.is_dir():
        return None, f"output path '{path}' is a file, not a folder: {again} or remove the file"
    if busy := _claim(path):
        return None, busy
    real = _real(path)
    old = _aside(real)
    if old.is_dir():  # a swap was cut short: keep whichever complete folder is in place
        if real.exists():
            shutil.rmtree(old)
        else:
            os.replace(old, real)
    partial = staging_folder(real)
    if has_step_records(partial) and not overwrite:
        return None, (
            f"'{partial}' holds the finished steps of an interrupted run replacing "
            f"'{path}': continue it with the same command and --resume -o {path}, or "
            "pass --overwrite to start again"
        )
    if not path.exists():
        blocked = _blocked_parent(path)
        if blocked:
            return None, f"{blocked}: {again}"
        path.parent.mkdir(parents=True, exist_ok=True)
        if busy := _claim(path):
            return None, busy
        _remove(partial)
        path.mkdir(exist_ok=True)
        return ResultFolder(path, path), None
    if not os.access(path, os.W_OK | os.X_OK):
        return None, f"output folder '{path}' is not writable: {again}"
    entries = sorted(p.name for p in path.iterdir())
    results = holds_results(path)
    run_folder = any((path / m).exists() for m in RUN_MARKERS)
    if not entries or (run_folder and not results and all(map(_leftover, entries))):
        _remove(partial)
        for name in entries:  # what a failed run left before it had results
            _remove(path / name)
        return ResultFolder(path, path), None
    if not run_folder:
        shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
        return None, (
            f"output folder '{path}' holds files that are not results of shellobstacle "
            f"({shown}): {again} (--overwrite replaces only result folders)"
        )
    if not overwrite:
        if has_step_records(path) and not any((path / n).exists() for n in RESULT_FILES):
            return None, (
                f"output folder '{path}' holds the finished steps of an interrupted run: "
                f"continue it with the same command and --resume -o {path}, or pass "
                f"--overwrite to start again, or {again}"
            )
        what = "results" if results else f"files of its own ({', '.join(entries[:3])})"
        return None, (
            f"output folder '{path}' already holds {what}; {again}, or pass --overwrite "
            "to replace them"
        )
    cwd = Path.cwd().resolve()
    if cwd == real.resolve() or real.resolve() in cwd.parents:
        return None, (
            f"--overwrite cannot replace '{path}': the current folder is inside it; run from "
            f"elsewhere or {again}"
        )
    if not os.access(real.parent, os.W_OK | os.X_OK):
        return None, (
            f"--overwrite cannot replace '{path}': its parent folder '{real.parent}' is not "
            f"writable (the new results are written beside it, then swapped in): {again}"
        )
    _remove(partial)
    partial.mkdir()
    return ResultFolder(path, partial), None
