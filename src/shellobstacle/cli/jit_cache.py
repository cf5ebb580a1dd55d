"""DOLFINx's FFCx JIT cache, shared by every process: no run leaves a broken entry in it.

FFCx's protocol (``ffcx/codegeneration/jit.py``): the process that creates ``NAME.c``
exclusively compiles it (CFFI rewrites the source, builds ``NAME.o`` and the module), then
creates ``NAME.c.cached`` exclusively; any other process finding ``NAME.c`` waits (10 s by
default) for ``NAME.c.cached`` and loads the module. An entry is therefore broken when

* ``NAME.c`` has no ``NAME.c.cached`` and its compiler is gone (interrupted, killed): every
  later compilation waits, then fails with a ``TimeoutError``;
* ``NAME.c.cached`` has no ``NAME.c``: every later compilation creates the source again,
  compiles, and fails with ``FileExistsError`` on the marker (a process that deleted another's
  source left this);
* ``NAME.c.cached`` has no module: every later compilation fails to load it.

FFCx 0.11 renames the source of a failed compilation to ``NAME.c.failed`` only for an
``Exception``; an interrupt (``KeyboardInterrupt``, ``SystemExit``) leaves it in place, and no
upstream issue about it was found. This module stays with the command line, whose interrupt
handling it uses (:mod:`shellobstacle.compat` holds the workarounds the library needs).

:func:`guarded_compilations` makes an interrupted compilation (Ctrl-C, ``SystemExit``) remove
the source that this process created, by name, before the interrupt goes on, so that nobody
waits for it; it never touches an entry another process created. :func:`broken_entries` finds
the broken entries (what ``shellobstacle doctor`` reports) and :func:`repair` removes the file
whose presence breaks each.
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shellobstacle.cli.interrupt import immediate

__all__ = [
    "NO_MODULE",
    "NO_SOURCE",
    "UNFINISHED",
    "UNFINISHED_AGE",
    "BrokenEntry",
    "broken_entries",
    "cache_dir",
    "guarded_compilations",
    "repair",
]

#: a source without its marker is taken for a dead compilation once this old (seconds)
UNFINISHED_AGE = 600.0

#: the sources this process created and is compiling (the innermost compilation last)
_compiling: list[Path] = []
#: FFCx's functions that :func:`guarded_compilations` wraps, while it does
_originals: dict[str, Callable[..., Any]] = {}


def cache_dir() -> Path:
    """DOLFINx's JIT cache folder (``XDG_CACHE_HOME``, ``dolfinx_jit_options.json``)."""
    from dolfinx.jit import get_options

    return Path(get_options()["cache_dir"])


def _abandon(sources: list[Path]) -> None:
    """Remove the unfinished sources that this process created (an interrupted compilation):
    another process then compiles them afresh instead of waiting for them."""
    for source in sources:
        with contextlib.suppress(OSError):
            if not source.with_suffix(".c.cached").exists():
                source.unlink()


def _recording(get_cached_module: Callable[..., Any]) -> Callable[..., Any]:
    def recorded(module_name: str, object_names: Any, cache_dir: Any, timeout: int) -> Any:
        with immediate():  # may wait for another process's compilation
            found = get_cached_module(module_name, object_names, cache_dir, timeout)
        if found[0] is None:  # this process created the source: it compiles it
            _compiling.append(Path(cache_dir) / f"{module_name}.c")
        return found

    return recorded


def _guarding(compile_objects: Callable[..., Any]) -> Callable[..., Any]:
    def guarded(*args: Any, **kwargs: Any) -> Any:
        mark = len(_compiling)
        try:
            with immediate():
                return compile_objects(*args, **kwargs)
        except Exception:
            raise  # (FFCx renames the source to NAME.c.failed itself)
        except BaseException:
            _abandon(_compiling[mark:])
            raise
        finally:
            del _compiling[mark:]

    return guarded


@contextlib.contextmanager
def guarded_compilations() -> Iterator[None]:
    """While the block runs, an interrupted FFCx compilation of this process removes its own
    unfinished source (FFCx leaves it, and the next compilation would wait for it and fail)."""
    import ffcx.codegeneration.jit as jit

    if _originals:  # already guarded (a nested block)
        yield
        return
    _originals.update((n, getattr(jit, n)) for n in _WRAPPED)
    for name, wrap in _WRAPPED.items():
        setattr(jit, name, wrap(_originals[name]))
    try:
        yield
    finally:
        for name, original in _originals.items():
            setattr(jit, name, original)
        _originals.clear()


_WRAPPED = {
    "get_cached_module": _recording,
    "compile_forms": _guarding,
    "compile_expressions": _guarding,
}


#: why an entry is broken: a marker without its source, ...
NO_SOURCE = "marker without its source"
#: ... a marker without its module, ...
NO_MODULE = "marker without its module"
#: ... a source without its marker, older than :data:`UNFINISHED_AGE`
UNFINISHED = "source never finished (a killed run?)"


@dataclass(frozen=True)
class BrokenEntry:
    """A broken entry of the cache: its source path and why (:data:`NO_SOURCE`, ...)."""

    source: Path
    why: str

    @property
    def marker(self) -> Path:
        return self.source.with_suffix(".c.cached")

    def culprits(self) -> list[Path]:
        """The files whose presence breaks the entry, the source first (nobody waits for a
        lone marker)."""
        return {
            NO_SOURCE: [self.marker],
            NO_MODULE: [self.source, self.marker],
            UNFINISHED: [self.source],
        }[self.why]


def _module_exists(source: Path) -> bool:
    stem = source.with_suffix("")
    return any(
        stem.with_name(stem.name + s).exists() for s in importlib.machinery.EXTENSION_SUFFIXES
    )


def broken_entries(folder: Path | None = None, now: float | None = None) -> list[BrokenEntry]:
    """The broken entries of the cache ``folder`` (DOLFINx's by default); a source without
    its marker counts once older than :data:`UNFINISHED_AGE` (younger, it may be compiling)."""
    folder = cache_dir() if folder is None else folder
    now = time.time() if now is None else now
    found = []
    for name in sorted({p.name.split(".", 1)[0] for p in folder.glob("libffcx_*.c*")}):
        source = folder / f"{name}.c"
        with contextlib.suppress(OSError):
            cached = source.with_suffix(".c.cached").exists()
            if cached and not source.exists():
                found.append(BrokenEntry(source, NO_SOURCE))
            elif cached and not _module_exists(source):
                found.append(BrokenEntry(source, NO_MODULE))
            elif not cached and source.exists() and now - source.stat().st_mtime > UNFINISHED_AGE:
                found.append(BrokenEntry(source, UNFINISHED))
    return found


def repair(entries: list[BrokenEntry]) -> list[Path]:
    """Remove the files that break ``entries`` (only sources and markers: a process compiling
    the entry meanwhile writes them again, whole); returns them."""
    removed = []
    for entry in entries:
        for path in entry.culprits():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed.append(path)
    return removed
