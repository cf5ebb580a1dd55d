"""The documentation's generated parts cannot drift from the code they describe."""

import re
import subprocess
import sys
from pathlib import Path

from mpi4py import MPI

import pytest

import shellobstacle
from shellobstacle.config.schema import reference_text

DOCS = Path(__file__).parents[2] / "docs"


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


ROOT = DOCS.parent
CITED = ("src", "tests", "benchmarks", "demos", "docs")


def _sources() -> list[Path]:
    files = [ROOT / "README.md"]
    for folder in CITED:
        files += [
            p
            for p in (ROOT / folder).rglob("*")
            if p.suffix in (".py", ".md") and "_build" not in p.parts and p.is_file()
        ]
    return files


def test_model_citations_name_sections_of_docs_model() -> None:
    """Every "docs/model.md §n" (and "model §n" link text) names a numbered section of
    docs/model.md, and nothing cites the spec kept outside the repository."""
    sections = set(re.findall(r"^## (\d+)\. ", (DOCS / "model.md").read_text(), re.M))
    assert sections == {str(n) for n in range(1, len(sections) + 1)}
    cited: dict[str, set[str]] = {}
    outside = "MODEL" + ".md"
    for path in _sources():
        text = path.read_text()
        assert outside not in text, f"{path} cites {outside}, which the repository lacks"
        for group in re.findall(r"model(?:\.md)?\]? ?((?:§[\d–, §]+))", text):
            for n in re.findall(r"\d+", group):
                cited.setdefault(n, set()).add(str(path.relative_to(ROOT)))
    assert cited, "no citation found: the pattern is wrong"
    unknown = {n: sorted(paths) for n, paths in cited.items() if n not in sections}
    assert not unknown, f"sections cited but missing from docs/model.md: {unknown}"


def test_relative_links_of_the_docs_reach_files() -> None:
    """A relative Markdown link of the site names a file (a folder is no page on the site)."""
    broken = []
    for path in DOCS.rglob("*.md"):
        if "_build" in path.parts:
            continue
        text = re.sub(r"\$\$.*?\$\$|\$[^$\n]*\$", "", path.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            if not (path.parent / target.split("#")[0]).is_file():
                broken.append(f"{path.relative_to(DOCS)}: {target}")
    assert not broken, broken


def test_performance_page_is_a_summary() -> None:
    """docs/performance.md states targets and standing in at most 200 lines; neither it nor the
    records (docs/perf/) carry dates (history is git's), and the records stay out of the
    site's sidebar."""
    assert len((DOCS / "performance.md").read_text().splitlines()) <= 200
    for page in [DOCS / "performance.md", *(DOCS / "perf").rglob("*.md")]:
        assert not re.findall(r"\b20\d\d-\d\d-\d\d\b", page.read_text()), page
    toctrees = re.findall(r"```\{toctree\}(.*?)```", (DOCS / "index.md").read_text(), re.S)
    entries = [line.strip() for tree in toctrees for line in tree.splitlines()]
    assert "performance" in entries
    assert not [e for e in entries if e.startswith("perf/")]
    for record in (DOCS / "perf").rglob("*.md"):
        assert record.read_text().startswith("---\norphan: true\n---"), record


@pytest.mark.slow  # Sphinx executes every demo: about a minute
@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="one build, serially")
def test_the_site_builds_with_warnings_as_errors() -> None:
    """``./run docs -W --keep-going -E``: every page read again, every demo executed, no
    warning. A test, so that ``./run test`` builds the site on a free core beside the others
    (pytest-xdist) instead of after them."""
    done = subprocess.run(
        [sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-q", "-E",
         str(DOCS), str(DOCS / "_build" / "html")],
        cwd=ROOT, capture_output=True, text=True, timeout=1800,
    )  # fmt: skip
    assert done.returncode == 0, (done.stdout + done.stderr)[-4000:]
    # a default such as ``environ=os.environ`` is shown as written, not as the build's values
    pages = (DOCS / "_build" / "html" / "api").glob("*.html")
    leaked = [page.name for page in pages if "environ({" in page.read_text()]
    assert not leaked, f"these pages show the build machine's environment: {leaked}"
