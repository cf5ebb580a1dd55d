"""The penalty's data: ``κ`` given directly or as ``h^exponent``, and its continuation ladder
(docs/model.md §6).

A small frozen dataclass of the Python API that mirrors the config's ``[penalty]`` table; it
validates at construction with the config's messages and knows nothing about meshes (κ on a
mesh: :mod:`~shellobstacle.penalty.kappa`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from shellobstacle.spec import boolean, finite  # the config's checks of a value

__all__ = ["KAPPA_MODES", "PenaltySpec", "at_exponent", "kappa_at"]

#: how κ = h^exponent follows an adapted mesh (:mod:`~shellobstacle.penalty.kappa`): the
#: largest cell (h as everywhere else), the local cell size, or the smallest cell
KAPPA_MODES = ("largest", "local", "finest")


def kappa_at(h: float, exponent: float) -> float:
    """``κ = h^exponent`` (the paper's coupling of κ to the mesh size ``h``)."""
    return h ** float(exponent)


@dataclass(frozen=True)
class PenaltySpec:
    """``κ`` given directly or as ``h^exponent`` (the paper's coupling), and whether to reach
    it through a ladder of larger κ (warm starts, docs/model.md §6)."""

    kappa: float | None = None
    exponent: float | None = None
    continuation: bool = True

    def __post_init__(self) -> None:
        for name in ("kappa", "exponent"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, finite(getattr(self, name), f"penalty.{name}"))
        boolean(self.continuation, "penalty.continuation")
        if self.kappa is not None and self.exponent is not None:
            raise ValueError("give either penalty.kappa or penalty.exponent, not both")
        if self.kappa is None and self.exponent is None:
            raise ValueError("[penalty] needs 'kappa' (a number) or 'exponent' (κ = h^exponent)")
        if self.kappa is not None:
            if not self.kappa > 0:
                raise ValueError(f"penalty.kappa must be > 0, got {self.kappa}")
            if self.kappa < 1e-100:
                raise ValueError(f"penalty.kappa = {self.kappa} is too small (at least 1e-100)")
        if self.exponent is not None and not 0 < self.exponent <= 20:
            raise ValueError(
                "penalty.exponent must be in (0, 20] (κ = h^20 is already far below what "
                f"double precision resolves), got {self.exponent}"
            )

    def target(self, h: float) -> float:
        """The κ to solve for on a mesh of size ``h``."""
        return self.kappa if self.kappa is not None else kappa_at(h, self.exponent)  # type: ignore[arg-type]

    def ladder(self, h: float) -> list[float]:
        """The continuation path ending at :meth:`target` (just the target if disabled):
        ``h^0.5, h^1, …`` below the exponent, or the powers of ten above ``kappa``."""
        target = self.target(h)
        if not self.continuation:
            return [target]
        if self.exponent is not None:
            qs = [0.5 * k for k in range(1, int(2 * self.exponent) + 1) if 0.5 * k < self.exponent]
            path = [kappa_at(h, qq) for qq in qs]
        else:
            path = [10.0**-k for k in range(0, 40) if 10.0**-k > target]
        return [k for k in path if k > 0] + [target]


def at_exponent(penalty: PenaltySpec | None, exponent: float) -> PenaltySpec:
    """``κ = h^exponent`` with ``penalty``'s other choices (its ``continuation``; None: the
    defaults): the penalty of a study that sets or sweeps the exponent."""
    return dataclasses.replace(
        penalty or PenaltySpec(exponent=exponent), kappa=None, exponent=exponent
    )
