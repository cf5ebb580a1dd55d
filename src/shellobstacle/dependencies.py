"""The versions of the key dependencies, and the ranges pyproject.toml pins them to.

pyproject.toml pins NumPy, SymPy, matplotlib, gmsh and rich (and, in the ``dolfinx`` extra,
the DOLFINx wheel and mpi4py) to the releases the test suite passed with.
``shellobstacle --version`` and ``shellobstacle doctor`` print what is installed; the doctor
names an installed release outside its pinned range as a problem (the package may work with
it, but it was not tested with it).
"""

from __future__ import annotations

import importlib
import importlib.metadata
from collections.abc import Iterable, Mapping

from packaging.requirements import InvalidRequirement, Requirement
from packaging.utils import canonicalize_name
from packaging.version import InvalidVersion, Version

__all__ = ["KEY_MODULES", "installed_versions", "out_of_range", "pinned_ranges", "summary"]

#: The modules whose versions matter for the results, by import name. DOLFINx, petsc4py, UFL,
#: Basix and FFCx come with whichever DOLFINx 0.11 is installed (wheel, conda-forge, Docker).
KEY_MODULES = (
    "mpi4py",
    "petsc4py",
    "dolfinx",
    "basix",
    "ufl",
    "ffcx",
    "numpy",
    "sympy",
    "matplotlib",
    "gmsh",
    "rich",
)
#: pinned distributions (canonical names) that install these modules under another name
_MODULE_OF = {"dolfinx-solver-real": "dolfinx"}


def _version_of(name: str) -> str | None:
    """The module's ``__version__``, else its distribution's; None if it is not importable."""
    try:
        module = importlib.import_module(name)
    except ImportError:
        return None
    version = getattr(module, "__version__", None)
    if version is None:
        try:
            version = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            return "unknown"
    return str(version)


def installed_versions(names: Iterable[str] = KEY_MODULES) -> dict[str, str | None]:
    """``{module: version}`` of the key modules (None: not importable). Imports them."""
    return {name: _version_of(name) for name in names}


def pinned_ranges(requires: Iterable[str] | None = None) -> dict[str, Requirement]:
    """The installed shellobstacle's pinned requirements (and its ``dolfinx`` extra's), by
    canonical distribution name; ``requires``: Requires-Dist lines instead of the metadata's."""
    if requires is None:
        try:
            requires = importlib.metadata.requires("shellobstacle") or []
        except importlib.metadata.PackageNotFoundError:  # run from a source tree
            return {}
    ranges = {}
    for line in requires:
        try:
            req = Requirement(line)
        except InvalidRequirement:
            continue
        if req.marker is None or req.marker.evaluate({"extra": "dolfinx"}):
            ranges[canonicalize_name(req.name)] = req
    return ranges


def out_of_range(
    installed: Mapping[str, str | None], ranges: Mapping[str, Requirement]
) -> list[str]:
    """One line per installed key module whose release lies outside its pinned range."""
    lines = []
    for dist, req in ranges.items():
        module = _MODULE_OF.get(dist, dist)
        version = installed.get(module)
        if version is None or not req.specifier:
            continue
        try:
            inside = req.specifier.contains(Version(version), prereleases=True)
        except InvalidVersion:
            continue
        if not inside:
            lines.append(
                f"{module} {version} is outside the range shellobstacle was tested with "
                f"({req.name}{req.specifier}): install '{req.name}{req.specifier}', or run the "
                "test suite (./run test) with this release"
            )
    return lines


def summary(installed: Mapping[str, str | None]) -> str:
    """``"dolfinx 0.11.0, petsc4py 3.25.5, ..."`` (modules that are not importable left out)."""
    return ", ".join(f"{name} {v}" for name, v in installed.items() if v is not None)
