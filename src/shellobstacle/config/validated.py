"""The validated configuration (:class:`Config`): what :mod:`shellobstacle.config.loader`
builds from TOML, or a Python program builds directly with the loader's defaults."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.config.keys import REQUIRED
from shellobstacle.config.options import solver_options
from shellobstacle.config.schema import SCHEMA
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.messages import ConfigError, not_one_of
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.options import config_keys
from shellobstacle.solvers.registry import DEFAULT, METHODS, discretization_for, options_for
from shellobstacle.spec import Discretization, Shell

__all__ = ["Config", "default_degree", "method_of", "require_penalty"]


@dataclass(frozen=True)
class Config:
    """A validated configuration: the physical shell and every numerical choice
    (``method_options``: the options of ``method`` when it is not Newton's).

    Read from TOML (:func:`load_config`, :func:`parse_config`) or built in Python with the
    loader's defaults: ``Config(shell, DomainSpec("disk", h=0.02), penalty=PenaltySpec(
    exponent=1.5))`` takes P2 for Koiter's model (else P1), the vertex penalty rule for a
    nodal method on P1, Newton's method and its default options.

    Raises:
        ConfigError: an unknown method, a penalized method without ``penalty``, or options
            not of the method's ``options_type``.
    """

    shell: Shell
    domain: DomainSpec
    discretization: Discretization | None = None  # None: P2 for Koiter's model, else P1
    penalty: PenaltySpec | None = None  # None for the methods of κ = 0 (not .penalized)
    solver: NewtonOptions = dataclasses.field(default_factory=NewtonOptions)
    method: str = DEFAULT
    output: Mapping[str, bool] = dataclasses.field(default_factory=lambda: _defaults("output"))
    resolved: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    source: str = "<python>"
    method_options: Any = None  # the options of solver.method when it is not Newton's
    adapt: AdaptOptions | None = None  # [adapt]: solve on adaptively refined meshes
    #: the TOML document read (``--set`` overrides applied); None for a Config built in Python
    document: Mapping[str, Any] | None = dataclasses.field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ConfigError(not_one_of("solver.method", self.method, METHODS.keys()))
        chosen = METHODS[self.method]
        require_penalty(self.method, self.penalty)
        disc = self.discretization or Discretization(degree=default_degree(self.shell.model))
        object.__setattr__(self, "discretization", discretization_for(chosen, disc))
        try:
            options_for(chosen, self.method_options)
        except TypeError as err:
            raise ConfigError(str(err)) from None

    @property
    def options(self) -> Any:
        """The options ``method`` solves with: ``method_options``, or Newton's ``solver``."""
        return options_for(METHODS[self.method], self.method_options, self.solver)

    def with_options(self, options: object) -> Config:
        """This configuration solved by the method whose ``options_type`` ``options`` is an
        instance of, with those options (its ``[solver]`` keys in :attr:`resolved`; no
        :attr:`document`: further overrides are refused)."""
        method = method_of(options, self.method)
        if method == DEFAULT:
            mine = {"solver": options, "method_options": None}
        else:
            mine = {"method_options": options}
        changed = dataclasses.replace(self, method=method, document=None, **mine)
        if "solver" in self.resolved:
            sv = {**self.resolved["solver"], "method": method}
            for key, f in config_keys(type(options)).items():
                sv[key] = copy.deepcopy(getattr(options, f.name))
            object.__setattr__(changed, "resolved", {**self.resolved, "solver": sv})
        return changed

    def options_of(self, method: str) -> Any:
        """The options of ``method`` (any of them, e.g. Brezis–Sibony beside Newton in an
        experiment) from the keys of ``[solver]`` it reads; the others keep its defaults."""
        return solver_options(method, self.resolved["solver"], self.resolved["solver"])


def _defaults(section: str) -> dict[str, Any]:
    """The defaults of the keys of ``[section]`` that have one."""
    return {
        name: copy.deepcopy(key.default)
        for name, key in SCHEMA[section].items()
        if key.default is not REQUIRED
    }


def default_degree(model: str) -> int:
    """The element degree when none is given: 2 for Koiter's ζ_3 ∈ H², else 1."""
    return 2 if model == "koiter" else 1


def require_penalty(method: str, penalty: PenaltySpec | None) -> None:
    """Raise ConfigError when ``method`` is penalized and ``penalty`` is None."""
    if penalty is None and METHODS[method].penalized:
        raise ConfigError(f"solver.method = {method!r} needs a penalty (kappa or exponent)")


def method_of(options: object, current: str = DEFAULT) -> str:
    """The method whose ``options_type`` ``options`` is an instance of (``current`` when
    several share it and it is one of them).

    Raises:
        ConfigError: no method (or several, ``current`` not among them) takes such options.
    """
    names = [m.name for m in METHODS.values() if m.options_type is type(options)]
    if current in names or len(names) == 1:
        return current if current in names else names[0]
    takes = ", ".join(f"{m.options_type.__name__}" for m in METHODS.values() if m.options_type)
    raise ConfigError(
        f"solver={type(options).__name__}(…) is not the options of one method: give one of "
        f"{takes}, or a mapping of [solver] keys"
    )
