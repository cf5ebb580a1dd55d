"""κ = h^q from the penalty's owner: the value at an exponent and a penalty at another exponent
with the config's other choices (the experiments' sweeps)."""

from __future__ import annotations

import pytest

from shellobstacle.penalty.spec import PenaltySpec, at_exponent, kappa_at


def test_kappa_at_is_the_target_and_the_ladder_of_an_exponent() -> None:
    """``kappa_at(h, q)`` is the κ a penalty ``h^q`` solves for, and its ladder's steps."""
    h = 0.0312
    assert kappa_at(h, 1.5) == PenaltySpec(exponent=1.5).target(h) == h**1.5
    assert PenaltySpec(exponent=2.0).ladder(h) == [kappa_at(h, q) for q in (0.5, 1.0, 1.5, 2.0)]


@pytest.mark.parametrize("given", [PenaltySpec(kappa=1e-5, continuation=False), None])
def test_at_exponent_keeps_the_other_choices(given: PenaltySpec | None) -> None:
    """A penalty at another exponent keeps the given one's continuation (None: the default)
    and drops a fixed κ."""
    p = at_exponent(given, 2.5)
    assert (p.kappa, p.exponent) == (None, 2.5)
    assert p.continuation == (given.continuation if given else True)
    assert p.ladder(0.1) == (
        [kappa_at(0.1, 2.5)] if given else PenaltySpec(exponent=2.5).ladder(0.1)
    )
