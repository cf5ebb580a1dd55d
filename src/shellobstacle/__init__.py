"""shellobstacle: elliptic membrane shells confined to a half-space (Meixner & Piersanti 2024).

The Python API mirrors the configuration file::

    from shellobstacle import DomainSpec, Load, Material, PenaltySpec, Shell, Surface, solve

    shell = Shell(Surface.spherical_cap(1.0, 0.85), Material(1e-3, 0.4, 0.012),
                  Load(("0", "0", "-1e-5")))
    result = solve(shell, DomainSpec("disk", h=0.02), PenaltySpec(exponent=1.5))

Names are imported lazily, so ``import shellobstacle`` does not start DOLFINx. It does set
up the process first (:mod:`shellobstacle.compat`: the DOLFINx wheel's MPI bootstrap, NumPy's
BLAS threads, glibc's malloc, the blocked DGEMMT under MUMPS), which must happen before
DOLFINx or PETSc are loaded: import ``shellobstacle`` before ``dolfinx`` and ``petsc4py``.
"""

from __future__ import annotations

import importlib
from typing import Any

from shellobstacle import compat  # noqa: F401  (before any DOLFINx or PETSc import)

__version__ = "0.1.0"

_EXPORTS = {
    "Surface": "shellobstacle.surface",
    "Shell": "shellobstacle.model",
    "Material": "shellobstacle.model",
    "Load": "shellobstacle.model",
    "Obstacle": "shellobstacle.model",
    "DomainSpec": "shellobstacle.domains",
    "Discretization": "shellobstacle.problem",
    "PenalizedProblem": "shellobstacle.problem",
    "PenaltySpec": "shellobstacle.config",
    "load_config": "shellobstacle.config",
    "NewtonOptions": "shellobstacle.solvers.newton",
    "Postprocessor": "shellobstacle.postprocess",
    "solve": "shellobstacle.pipeline",
    "solve_config": "shellobstacle.pipeline",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'shellobstacle' has no attribute {name!r}")
