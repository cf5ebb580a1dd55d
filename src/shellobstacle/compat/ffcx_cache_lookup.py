"""FFCx 0.11 lists its whole JIT cache folder at every cache hit.

Upstream: FFCx issue #886 ("get_cached_module lists the whole cache directory on every cache
hit"): ``get_cached_module`` finds a compiled form's module with an ``importlib`` finder over
the cache folder, which lists the folder (four files per form ever compiled on the machine)
at every hit, a cost that grows without bound. Fixed by FFCx pull request #887 (merged into
FFCx's main after 0.11.0: the module is found by its file name), in no release yet.
:func:`locate_jit_modules_by_path` does the same for FFCx 0.11 (:data:`AFFECTED`) and nothing
for any other release; drop this module when the FFCx pin moves past 0.11.
``tests/io/test_jit_cache.py`` checks that FFCx 0.11's own lookup lists the folder and that the
replacement does not.
"""

from __future__ import annotations

from typing import Any

__all__ = ["AFFECTED", "locate_jit_modules_by_path"]

#: the FFCx release series (major, minor) whose lookup lists the cache folder
AFFECTED = ("0", "11")


def locate_jit_modules_by_path() -> bool:
    """Let FFCx 0.11 load a cached form from its file name, ``NAME`` plus an extension suffix,
    without listing the cache folder. Only a finished entry (``NAME.c``, ``NAME.c.cached`` and
    the module) is loaded so; any other state takes FFCx's own way (the exclusive ``NAME.c``,
    the wait for ``NAME.c.cached``) and fails as FFCx does. Idempotent; returns whether the
    lookup is FFCx 0.11's replaced one."""
    import importlib.machinery
    import importlib.util
    from pathlib import Path

    import ffcx
    import ffcx.codegeneration.jit as jit

    if getattr(jit.get_cached_module, "by_path", False):
        return True
    if tuple(ffcx.__version__.split(".")[:2]) != AFFECTED:
        return False
    ffcx_lookup = jit.get_cached_module

    def get_cached_module(
        module_name: str, object_names: list[str], cache_dir: Any, timeout: int
    ) -> tuple[Any, Any]:
        folder = Path(cache_dir)
        source = folder / f"{module_name}.c"
        if source.exists() and source.with_suffix(".c.cached").exists():
            for suffix in importlib.machinery.EXTENSION_SUFFIXES:
                path = folder / f"{module_name}{suffix}"
                if path.exists():
                    spec = importlib.util.spec_from_file_location(module_name, path)
                    module = importlib.util.module_from_spec(spec)
                    spec.loader.exec_module(module)
                    return [getattr(module.lib, name) for name in object_names], module
        return ffcx_lookup(module_name, object_names, cache_dir, timeout)

    get_cached_module.by_path = True  # type: ignore[attr-defined]
    get_cached_module.ffcx = ffcx_lookup  # type: ignore[attr-defined]
    jit.get_cached_module = get_cached_module
    return True
