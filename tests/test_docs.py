"""The documentation's generated parts cannot drift from the code they describe."""

import re
from pathlib import Path

import shellobstacle
from shellobstacle.config.schema import reference_text

DOCS = Path(__file__).parents[1] / "docs"


def test_config_reference_is_up_to_date() -> None:
    """docs/config-reference.md equals ``shellobstacle config-reference``."""
    path = DOCS / "config-reference.md"
    assert path.read_text().strip() == reference_text().strip(), (
        "regenerate with: .venv/bin/shellobstacle config-reference > docs/config-reference.md"
    )


def test_api_reference_lists_every_name_of_the_package() -> None:
    """The first table of docs/api.md is ``shellobstacle.__all__``, each name linked to the
    module that defines it (where its documentation is)."""
    listed = re.findall(r"^   ~([\w.]+)\.(\w+)$", (DOCS / "api.md").read_text(), re.M)
    names = [name for name in shellobstacle.__all__ if name != "__version__"]
    assert sorted(name for _, name in listed) == sorted(names)
    for module, name in listed:
        assert getattr(shellobstacle, name).__module__ == module, name


def test_every_demo_is_on_the_site() -> None:
    """docs/demos.md lists every script of demos/ (the site executes them)."""
    text = (DOCS / "demos.md").read_text()
    demos = sorted(p.stem for p in (DOCS.parent / "demos").glob("*.py"))
    assert sorted(re.findall(r"^demos/(\w+)$", text, re.M)) == demos
