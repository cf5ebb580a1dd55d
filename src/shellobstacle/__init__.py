"""shellobstacle: linearly elastic shells, membrane and Koiter, against a rigid obstacle.

The obstacle problem of Meixner & Piersanti (2024) for elliptic membrane shells, and Koiter's
model for any thin shell, against any rigid obstacle ``g(x) ≥ 0`` (a plane, a ball, a cylinder,
a formula): penalty and exact solvers, adaptive refinement, geometric multigrid, MPI.

The Python API mirrors the configuration file: :func:`solve` takes a config file, a mapping
shaped like one or a :class:`Config` built in Python, and overrides of its sections::

    from shellobstacle import Config, DomainSpec, Load, Material, PenaltySpec, Shell, Surface
    from shellobstacle import solve

    result = solve("examples/paper.toml", domain={"h": 0.02})
    shell = Shell(Surface.spherical_cap(1.0, 0.85), Material(1e-3, 0.4, 0.012),
                  Load(("0", "0", "-1e-5")))
    result = solve(Config(shell, DomainSpec("disk", h=0.02), penalty=PenaltySpec(exponent=1.5)))
    result.contact.area, result.validity.warnings()

Names are imported lazily: ``import shellobstacle`` loads neither DOLFINx nor MPI and changes
nothing in the process, and the package may be imported before or after ``dolfinx`` and
``petsc4py``. Progress is logged to the ``shellobstacle`` logger, which prints nothing
until the application configures :mod:`logging`. Process tuning for long runs is set from the
environment (docs/user-guide.md).
"""

from __future__ import annotations

import importlib
import logging
from typing import Any

__version__ = "0.1.0"

# the library logs through ``logging.getLogger("shellobstacle.…")`` and configures no output:
# the command line (or the application) adds the handlers
logging.getLogger(__name__).addHandler(logging.NullHandler())

_EXPORTS = {
    "Surface": "shellobstacle.geometry.surface",
    "Shell": "shellobstacle.spec",
    "Material": "shellobstacle.spec",
    "Load": "shellobstacle.spec",
    "Obstacle": "shellobstacle.spec",
    "DomainSpec": "shellobstacle.mesh.domains",
    "Discretization": "shellobstacle.spec",
    "PenalizedProblem": "shellobstacle.models.problem",
    "PenaltySpec": "shellobstacle.penalty.spec",
    "Config": "shellobstacle.config.validated",
    "load_config": "shellobstacle.config.loader",
    "NewtonOptions": "shellobstacle.solvers.newton.options",
    "NewtonSolver": "shellobstacle.solvers.newton.solver",
    "ConvergenceError": "shellobstacle.solvers.result",
    "continuation": "shellobstacle.solvers.newton.continuation",
    "exact_solution": "shellobstacle.api",
    "make_mesh": "shellobstacle.api",
    "Postprocessor": "shellobstacle.post.contact",
    "solve": "shellobstacle.api",
    "solve_problem": "shellobstacle.api",
    "SolveResult": "shellobstacle.solvers.result",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'shellobstacle' has no attribute {name!r}")
