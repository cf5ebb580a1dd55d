"""The configuration reference in docs/ is the validator's own output (it cannot drift)."""

from pathlib import Path

from shellobstacle.schema import reference_text


def test_config_reference_is_up_to_date() -> None:
    """docs/config-reference.md equals ``shellobstacle config-reference``."""
    path = Path(__file__).parents[1] / "docs" / "config-reference.md"
    assert path.read_text().strip() == reference_text().strip(), (
        "regenerate with: .venv/bin/shellobstacle config-reference > docs/config-reference.md"
    )
