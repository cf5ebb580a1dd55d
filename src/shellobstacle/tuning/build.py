"""The package's C helpers (``native/*.c``), compiled once per machine and cached.

Built with the C compiler that DOLFINx's form compiler uses too (``CC``, else Python's), into
``$XDG_CACHE_HOME/shellobstacle`` or ``~/.cache/shellobstacle``; a build is named by a hash of
its source and compiler, so an edited source or another compiler builds anew (and removes the
older builds of that helper).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sysconfig
from collections.abc import Sequence
from pathlib import Path

__all__ = ["NATIVE", "build", "compiler"]

NATIVE = Path(__file__).with_name("native")


def cache_dir() -> Path:
    """Where the compiled helpers are kept."""
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "shellobstacle"


def compiler() -> str | None:
    """The C compiler's path (``CC`` may carry flags: ``'gcc -m64'``), or None."""
    cc = os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc"
    return shutil.which(cc.split()[0]) if cc.split() else None


def build(name: str, cc: str, libraries: Sequence[str] = ()) -> Path:
    """``native/<name>.c`` compiled to a shared library (atomic rename into the cache).

    Raises ``subprocess.SubprocessError`` or ``OSError`` when it cannot be built.
    """
    source = NATIVE / f"{name}.c"
    tag = hashlib.sha256(source.read_bytes() + cc.encode()).hexdigest()[:16]
    target = cache_dir() / f"{name}-{tag}.so"
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    command = [cc, "-O2", "-fPIC", "-shared", "-fvisibility=hidden", str(source), "-o", str(tmp)]
    try:
        subprocess.run([*command, *libraries], check=True, capture_output=True, timeout=120)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    for stale in target.parent.glob(f"{name}-*.so"):  # builds of earlier sources or compilers
        if stale != target:
            stale.unlink(missing_ok=True)
    return target
