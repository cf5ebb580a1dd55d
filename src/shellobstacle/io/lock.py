"""One run at a time per result folder: a file lock beside it, held for the whole run.

A run takes ``.NAME.lock`` beside its folder ``NAME`` (:class:`filelock.FileLock`: an exclusive
``flock``, not waiting) before it looks into the folder, and keeps it until the command ends.
The lock covers the folder, its staging folder ``.NAME.partial`` (``--overwrite``) and the
final swap. The holder writes who it is (pid, host, command) into the file, for the message a
refused run prints. The operating system drops the lock when its process ends, however it
ends: the lock file that a killed run leaves behind blocks nothing. The holder removes the file
while still holding it; a run that locked a file no longer in place tries again (filelock), so
two runs never hold two different files for one folder. Where no file can be made beside the
folder (an unwritable parent), the folder's own descriptor is locked.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shlex
import socket
import sys
import time
from pathlib import Path

from filelock import FileLock, Timeout, lock_descriptor

__all__ = ["FolderInUseError", "lock_file", "lock_folder", "release_folder", "release_folders"]

#: how long a refused run waits for the holder to have written who it is
_OWNER_WAIT = 1.0


class FolderInUseError(Exception):
    """Another live process holds the lock of the folder; ``owner`` says which."""

    def __init__(self, folder: Path, owner: str) -> None:
        super().__init__(f"{folder}: {owner}")
        self.folder, self.owner = folder, owner


#: the folders this process has locked, with their lock (a file lock, or the folder's own
#: descriptor); a run that prepares its folder twice reuses its lock
_held: dict[Path, FileLock | int] = {}


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


def _write_owner(fd: int) -> None:
    os.write(fd, (_owner() + "\n").encode())


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


def lock_folder(folder: Path) -> None:
    """Lock ``folder`` for this process (its parent must exist). Neither a lock file beside it
    nor the folder itself can be opened (an unwritable parent and no folder): nothing is
    locked, and the folder cannot be created either, which the caller reports.

    Raises:
        FolderInUseError: another live process holds the lock.
    """
    folder = _canonical(folder)
    if folder in _held:
        return
    path = lock_file(folder)
    lock = FileLock(path, timeout=0, thread_local=False, on_acquired=_write_owner)
    try:
        lock.acquire()
    except Timeout:
        raise FolderInUseError(folder, _read_owner(path)) from None
    except OSError as err:
        if err.errno not in (errno.EACCES, errno.EPERM, errno.EROFS):
            raise
        _lock_itself(folder)
        return
    _held[folder] = lock


def _lock_itself(folder: Path) -> None:
    """Lock the folder's own descriptor, where no lock file can be written beside it."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    if not lock_descriptor(fd, blocking=False):
        os.close(fd)
        raise FolderInUseError(folder, "a process that could not say which")
    _held[folder] = fd


def release_folder(folder: Path) -> None:
    """Release the lock of ``folder`` if this process holds it (a lock file is removed while
    still locked, so nobody holds it)."""
    folder = _canonical(folder)
    lock = _held.pop(folder, None)
    if isinstance(lock, FileLock):
        with contextlib.suppress(OSError):
            lock_file(folder).unlink()
        lock.release()
    elif lock is not None:
        os.close(lock)


def release_folders() -> None:
    """Release every folder lock of this process (the command has ended)."""
    for folder in list(_held):
        release_folder(folder)
