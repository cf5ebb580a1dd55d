"""Options of the adaptive loop (the config's ``[adapt]``): plain data with its validation,
importable without DOLFINx (the configuration builds them)."""

from __future__ import annotations

from dataclasses import dataclass, field

from shellobstacle.messages import not_one_of
from shellobstacle.penalty.spec import KAPPA_MODES

__all__ = ["MAX_LEVELS", "AdaptOptions"]

#: the most refinement levels of one adaptive solve
MAX_LEVELS = 60


@dataclass(frozen=True)
class AdaptOptions:
    """Solve → estimate → mark → refine, until a target is met (:mod:`shellobstacle.adapt.loop`).

    Attributes:
        fraction: Dörfler's bulk fraction ``θ``: the marked cells hold at least ``θ`` of
            ``Σ η_T²`` (:mod:`~shellobstacle.adapt.marking`).
        max_levels: the most refinements; the loop solves ``max_levels + 1`` meshes at most.
        target_error: stop once the estimate ``η`` is at most this (None: no such target).
        target_dofs: stop after the first mesh with at least this many dofs (None: none).
        kappa: how κ follows the mesh (:func:`~shellobstacle.penalty.kappa.kappa_on_mesh`).
            With ``penalty.exponent = q``: ``"largest"``, ``κ = h^q`` with ``h`` the
            largest cell diameter (the package's ``h`` everywhere else); ``"local"``,
            ``κ(x) = h_T^q`` on each cell ``T``; ``"finest"``, ``κ = h_min^q`` everywhere (the
            smallest cell). A fixed ``penalty.kappa`` is used on every mesh.
        free_boundary: also refine every cell the discrete free boundary runs through (the
            cells with vertices in and out of contact). Off by default: the indicators
            already mark it (docs/results/adaptive.md: the same error at equal dofs on the
            paper's problem, up to 10 % more on the paraboloid).
    """

    fraction: float = 0.5
    max_levels: int = 10
    target_error: float | None = None
    target_dofs: int | None = None
    kappa: str = field(default="largest", metadata={"choices": KAPPA_MODES})
    free_boundary: bool = False

    def __post_init__(self) -> None:
        if not 0.0 < self.fraction <= 1.0:
            raise ValueError(
                f"adapt.fraction must be in (0, 1] (Dörfler's θ; 0.5 is usual), got {self.fraction}"
            )
        if not 0 <= self.max_levels <= MAX_LEVELS:
            raise ValueError(
                f"adapt.max_levels must be between 0 and {MAX_LEVELS}, got {self.max_levels}"
            )
        if self.target_error is not None and not self.target_error > 0:
            raise ValueError(f"adapt.target_error must be > 0, got {self.target_error}")
        if self.target_dofs is not None and not self.target_dofs > 0:
            raise ValueError(f"adapt.target_dofs must be > 0, got {self.target_dofs}")
        if self.kappa not in KAPPA_MODES:
            raise ValueError(not_one_of("adapt.kappa", self.kappa, KAPPA_MODES))
