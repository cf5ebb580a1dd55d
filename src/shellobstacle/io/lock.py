"""One run at a time per result folder: an advisory lock beside it, held for the whole run.

A run takes ``.NAME.lock`` beside its folder ``NAME`` (:func:`fcntl.flock`, exclusive, not
waiting) before it looks into the folder, and keeps it until the command ends. The lock covers
the folder, its staging folder ``.NAME.partial`` (``--overwrite``) and the final swap. The file
records the holder (pid, host, command) for the message a refused run prints. The operating
system drops the lock when its process ends, however it ends: the lock file that a killed run
leaves behind blocks nothing. A lock file is removed by its holder while still locked, and a
run that locked a file that is no longer in place tries again, so two runs never hold two
different files for one folder.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import shlex
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "FolderInUseError",
    "FolderLock",
    "lock_file",
    "lock_folder",
    "release_folder",
    "release_folders",
]

#: how long a refused run waits for the holder to have written who it is
_OWNER_WAIT = 1.0


class FolderInUseError(Exception):
    """Another live process holds the lock of the folder; ``owner`` says which."""

    def __init__(self, folder: Path, owner: str) -> None:
        super().__init__(f"{folder}: {owner}")
        self.folder, self.owner = folder, owner


@dataclass
class FolderLock:
    """The lock of one result folder, held by this process until :meth:`release`."""

    folder: Path
    path: Path | None  # the lock file (None: the folder's own descriptor is locked)
    fd: int

    def release(self) -> None:
        """Remove the lock file (still locked, so nobody holds it) and unlock."""
        _held.pop(self.folder, None)
        if self.path is not None:
            with contextlib.suppress(OSError):
                self.path.unlink()
        os.close(self.fd)


#: the folders this process has locked (a run that prepares its folder twice reuses its lock)
_held: dict[Path, FolderLock] = {}


def lock_file(folder: Path) -> Path:
    """The lock file of ``folder`` (an absolute path without symbolic links)."""
    return folder.with_name(f".{folder.name}.lock")


def _canonical(folder: Path) -> Path:
    """``folder`` with every symbolic link of its path resolved (also a not yet created one)."""
    return Path(os.path.realpath(folder))


def _owner() -> str:
    """This process as a refused run names it: pid, host, command."""
    program = sys.argv[0] if sys.argv else ""
    if program == "-c":
        program = "python -c ..."
    elif Path(program).name == "__main__.py":
        program = Path(program).parent.name  # python -m shellobstacle
    else:
        program = Path(program).name
    command = " ".join([program, shlex.join(sys.argv[1:])])
    if len(command) > 200:
        command = command[:197] + "..."
    return f"pid {os.getpid()} on {socket.gethostname()}: {command}"


def _read_owner(path: Path) -> str:
    """Who holds the lock file ``path``, as it wrote itself in."""
    deadline = time.monotonic() + _OWNER_WAIT
    while True:
        with contextlib.suppress(OSError):
            text = path.read_text(errors="replace").strip()
            if text:
                return text
        if time.monotonic() > deadline:
            return "a process that has not said which"
        time.sleep(0.05)


def lock_folder(folder: Path) -> FolderLock | None:
    """Lock ``folder`` for this process (its parent must exist); None when neither a lock file
    beside it nor the folder itself can be opened (an unwritable parent and no folder: the
    folder cannot be created either, which the caller reports).

    Raises:
        FolderInUseError: another live process holds the lock.
    """
    folder = _canonical(folder)
    if folder in _held:
        return _held[folder]
    path = lock_file(folder)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            if err.errno not in (errno.EACCES, errno.EPERM, errno.EROFS):
                raise
            return _lock_itself(folder)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise FolderInUseError(folder, _read_owner(path)) from None
        except BaseException:
            os.close(fd)
            raise
        try:
            in_place = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            in_place = False
        if not in_place:  # its holder removed it between our open and our lock
            os.close(fd)
            continue
        os.ftruncate(fd, 0)
        os.write(fd, (_owner() + "\n").encode())
        lock = _held[folder] = FolderLock(folder, path, fd)
        return lock


def _lock_itself(folder: Path) -> FolderLock | None:
    """Lock the folder's own descriptor, where no lock file can be written beside it."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise FolderInUseError(folder, "a process that could not say which") from None
    lock = _held[folder] = FolderLock(folder, None, fd)
    return lock


def release_folder(folder: Path) -> None:
    """Release the lock of ``folder`` if this process holds it."""
    if (lock := _held.get(_canonical(folder))) is not None:
        lock.release()


def release_folders() -> None:
    """Release every folder lock of this process (the command has ended)."""
    for lock in list(_held.values()):
        lock.release()
