"""The DOLFINx binary wheel's bootstrap: MPI loaded before DOLFINx, in any import order.

The wheel ``dolfinx-solver-real`` needs ``mpi4py.MPI`` loaded before its compiled modules:
``import dolfinx_solver`` does that (and refuses a broken environment, a foreign petsc4py or
both scalar variants installed, with a message that says what to uninstall). The package's
modules import ``mpi4py`` first, as DOLFINx's own demos do, and the command line calls
:func:`bootstrap` before anything else.

A user's script that imports ``dolfinx`` or ``petsc4py`` *first* would fail with
``libmpi.so.12: cannot open shared object file``. ``./run setup`` therefore writes
:data:`PTH_NAME` into the virtual environment (:func:`install_pth`): at start-up it puts a
finder on ``sys.meta_path`` (:func:`order_mpi_first`) that imports ``dolfinx_solver`` just
before the first of :data:`NEEDS_MPI` and then removes itself; nothing is imported at
start-up but this module. Other DOLFINx installs (conda-forge, Docker, source builds) have no
such package and need nothing.

FFCx 0.11 finds a compiled form in its JIT cache by listing the whole cache folder at every
hit, a cost that grows with every form ever compiled on the machine; later FFCx releases look
the module up by its file name. :func:`locate_jit_modules_by_path` does the same for 0.11: the
command line and the tests call it through :func:`bootstrap`, and the start-up file's finder
when ``dolfinx`` is first imported.
"""

from __future__ import annotations

import contextlib
import importlib.abc
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the start-up file imports this module: nothing more than it needs
    from pathlib import Path

__all__ = [
    "NEEDS_MPI",
    "PTH_LINE",
    "PTH_NAME",
    "bootstrap",
    "install_pth",
    "locate_jit_modules_by_path",
    "order_mpi_first",
]

#: Top-level modules whose compiled parts link the wheel's MPI library.
NEEDS_MPI = ("dolfinx", "petsc4py", "slepc4py")
#: The start-up file ``./run setup`` writes into the environment's site-packages.
PTH_NAME = "shellobstacle-mpi-first.pth"
#: Its one line (a ``.pth`` runs lines that start with ``import``); silent without the package.
PTH_LINE = (
    'import sys; exec("try:\\n from shellobstacle.compat import order_mpi_first\\n'
    'except ImportError:\\n pass\\nelse:\\n order_mpi_first()")'
)


def bootstrap() -> str:
    """Check the DOLFINx wheel's environment and load MPI; returns how DOLFINx is installed.

    Raises:
        ImportError: the wheel's own message for an environment that cannot work.
    """
    try:
        import dolfinx_solver
    except ModuleNotFoundError:
        from mpi4py import MPI  # noqa: F401  (what the wheel's bootstrap would load)

        how = "not from the dolfinx-solver wheel (conda-forge, Docker or a source build)"
    else:
        name = dolfinx_solver.__name__.replace("_", "-")
        how = f"the {name} wheel {dolfinx_solver.__version__}"
    locate_jit_modules_by_path()
    return how


def locate_jit_modules_by_path() -> bool:
    """Let FFCx 0.11 load a cached form from its file name, ``NAME`` plus an extension suffix,
    without listing the cache folder (module docstring). Only a finished entry (``NAME.c``,
    ``NAME.c.cached`` and the module) is loaded so; any other state takes FFCx's own way (the
    exclusive ``NAME.c``, the wait for ``NAME.c.cached``) and fails as FFCx does. Idempotent;
    returns whether the lookup is FFCx 0.11's replaced one."""
    import importlib.machinery
    import importlib.util
    from pathlib import Path

    import ffcx
    import ffcx.codegeneration.jit as jit

    if getattr(jit.get_cached_module, "by_path", False):
        return True
    if tuple(ffcx.__version__.split(".")[:2]) != ("0", "11"):
        return False  # a later FFCx looks modules up by path itself
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


class _MPIFirst(importlib.abc.MetaPathFinder):
    """Imports the wheel's bootstrap before the first of :data:`NEEDS_MPI`, once."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name in NEEDS_MPI:
            sys.meta_path.remove(self)  # before the bootstrap, which imports them itself
            with contextlib.suppress(ModuleNotFoundError):  # not the wheel: nothing to order
                import dolfinx_solver  # noqa: F401
            if name == "dolfinx":  # which imports FFCx anyway
                locate_jit_modules_by_path()
        return None  # the module itself is found by the usual finders


def order_mpi_first() -> None:
    """Put the finder of the module docstring on ``sys.meta_path`` (once per process)."""
    if "dolfinx_solver" not in sys.modules and not any(
        isinstance(f, _MPIFirst) for f in sys.meta_path
    ):
        sys.meta_path.insert(0, _MPIFirst())


def install_pth(site_packages: str | Path | None = None) -> Path:
    """Write :data:`PTH_NAME` into ``site_packages`` (default: this environment's) unless it
    holds :data:`PTH_LINE` already; returns its path."""
    import sysconfig
    from pathlib import Path

    folder = Path(site_packages or sysconfig.get_paths()["purelib"])
    path = folder / PTH_NAME
    text = PTH_LINE + "\n"
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)
    return path
