"""The wheel installs a working ``shellobstacle``: built from a copy of the sources, installed
(not editable) into a fresh virtual environment, it runs ``check`` and a small ``solve`` with
the configuration it ships.

The new environment sees this one's site-packages as a plain path entry after its own (a
``.pth`` line: the ``.pth`` files in there, such as an editable install of shellobstacle, are
not run) and links to the libraries of this environment's ``lib/`` (MPICH), so DOLFINx is not
downloaded again; pip installs the wheel with ``--no-index``, so the pinned ranges of
pyproject.toml must hold for the dependencies found there.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

from mpi4py import MPI

import pytest

pytestmark = [
    pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="fresh processes, serially"),
    pytest.mark.slow,  # a wheel build and a fresh environment: minutes
]

ROOT = Path(__file__).parents[2]
PACKAGE = ROOT / "src" / "shellobstacle"


def run(*command: str | Path, **environ: str) -> subprocess.CompletedProcess:
    """``command`` without this process's PYTHONPATH (it would import the sources)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | environ
    return subprocess.run(
        [str(c) for c in command], env=env, capture_output=True, text=True, timeout=600
    )


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel of a clean copy of the sources (no build files left in the work tree)."""
    source = tmp_path_factory.mktemp("source")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.so")
    shutil.copytree(ROOT / "src", source / "src", ignore=ignore)
    out = tmp_path_factory.mktemp("dist")
    build = run(
        sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", out, source
    )
    assert build.returncode == 0, build.stderr
    (path,) = out.glob("shellobstacle-*.whl")
    return path


@pytest.fixture(scope="module")
def venv(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh environment with the wheel installed, its dependencies this environment's."""
    env = tmp_path_factory.mktemp("venv") / "env"
    made = run(sys.executable, "-m", "venv", "--without-pip", env)
    assert made.returncode == 0, made.stderr
    python = env / "bin" / "python"
    purelib = run(python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))")
    Path(purelib.stdout.strip(), "dependencies.pth").write_text(sysconfig.get_path("purelib"))
    # what dependency wheels install beside site-packages, in the prefix's lib/ (the MPICH
    # wheel's libmpi, which mpi4py looks for below sys.prefix)
    for entry in (Path(sys.prefix) / "lib").iterdir():
        if not entry.name.startswith("python"):
            (env / "lib" / entry.name).symlink_to(entry)
    installed = run(sys.executable, "-m", "pip", "--python", python, "install", "--no-index", wheel)
    assert installed.returncode == 0, installed.stderr + installed.stdout
    return env


def test_the_wheel_holds_every_module_and_the_package_data(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = [*PACKAGE.rglob("*.py"), *PACKAGE.glob("configs/*.toml")]
    expected = {str(p.relative_to(PACKAGE.parent)) for p in shipped}
    assert any(name.endswith(".toml") for name in expected)
    assert expected <= names, sorted(expected - names)


def test_the_environment_imports_the_installed_wheel(venv: Path) -> None:
    """shellobstacle and its configuration come from the new environment."""
    probe = (
        "import json, shellobstacle\n"
        "from shellobstacle.experiments.reproduce import PAPER_CONFIG\n"
        "print(json.dumps([shellobstacle.__file__, str(PAPER_CONFIG)]))"
    )
    out = run(venv / "bin" / "python", "-c", probe)
    assert out.returncode == 0, out.stderr
    module, config = map(Path, json.loads(out.stdout))
    for path in (module, config):
        assert path.resolve().is_relative_to(venv.resolve()), path
    assert config.is_file()


def test_version_and_doctor_name_the_dependencies_within_their_ranges(venv: Path) -> None:
    version = run(venv / "bin" / "shellobstacle", "--version")
    assert version.returncode == 0, version.stderr
    import shellobstacle

    assert version.stdout.splitlines()[0] == f"shellobstacle {shellobstacle.__version__}"
    for name in ("dolfinx", "petsc4py", "numpy", "sympy", "matplotlib", "gmsh", "rich"):
        assert f" {name} " in version.stdout
    doctor = run(venv / "bin" / "shellobstacle", "doctor")
    assert doctor.returncode in (0, 1), doctor.stderr
    assert "dependencies: " in doctor.stdout
    assert "outside the range" not in doctor.stdout


def test_check_and_a_small_solve_with_the_shipped_config(venv: Path, tmp_path: Path) -> None:
    shellobstacle = venv / "bin" / "shellobstacle"
    config = run(
        venv / "bin" / "python",
        "-c",
        "from shellobstacle.experiments.reproduce import PAPER_CONFIG; print(PAPER_CONFIG)",
    ).stdout.strip()
    check = run(shellobstacle, "check", config, "--set", "domain.h=0.05")
    assert check.returncode == 0, check.stderr
    assert "elliptic" in check.stdout and "fail" not in check.stdout
    out = tmp_path / "solve"
    solve = run(shellobstacle, "solve", config, "-o", out, "--set", "domain.h=0.05", "-q")
    assert solve.returncode == 0, solve.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] is True
    assert summary["contact_area"] > 0
