"""``shellobstacle doctor``: the environment, the process tuning in force and known problems."""

from __future__ import annotations

import os
import subprocess
import sys

from mpi4py import MPI

import pytest

from shellobstacle.cli.doctor import coretype_warning, numpy_blas_config
from shellobstacle.dependencies import out_of_range, pinned_ranges
from shellobstacle.io.records import TIMING_VARIABLES

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="fresh processes, serially")

CRASHED = "OpenBLAS 0.3.34.237.2  USE64BITINT DYNAMIC_ARCH NO_AFFINITY Haswell MAX_THREADS=64"
FINE = "OpenBLAS 0.3.33.112.0  USE64BITINT DYNAMIC_ARCH NO_AFFINITY Haswell MAX_THREADS=64"


def doctor(**environ: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in TIMING_VARIABLES} | environ
    return subprocess.run(
        [sys.executable, "-m", "shellobstacle", "doctor"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize(
    ("environ", "tuning"),
    [
        ({}, "none set"),
        (
            {"MALLOC_MMAP_MAX_": "0", "OPENBLAS_NUM_THREADS": "1"},
            "OPENBLAS_NUM_THREADS=1 MALLOC_MMAP_MAX_=0",
        ),
    ],
)
def test_the_doctor_shows_versions_and_the_process_tuning_in_force(
    environ: dict[str, str], tuning: str
) -> None:
    out = doctor(**environ)
    assert out.returncode in (0, 1), out.stderr
    text = out.stdout
    assert "DOLFINx 0.11" in text and "PETSc" in text and "MPI:" in text
    (deps,) = [line for line in text.splitlines() if line.startswith("dependencies: ")]
    assert all(f" {name} " in deps for name in ("petsc4py", "numpy", "sympy", "gmsh", "rich"))
    assert f"process tuning (docs/user-guide.md): {tuning}\n" in text
    (blas,) = [line for line in text.splitlines() if line.startswith("NumPy's BLAS: ")]
    if environ:  # NumPy's OpenBLAS takes the thread count from the environment
        assert blas.endswith(", 1 thread(s)")
    problems = [line for line in text.splitlines() if line.startswith("problem: ")]
    assert (out.returncode == 1) == bool(problems)
    assert ("no problems found" in text) == (not problems)


def test_a_crashing_forced_kernel_is_a_problem_exactly_when_numpy_is_affected() -> None:
    out = doctor(OPENBLAS_CORETYPE="Haswell")
    affected = numpy_blas_config().startswith("OpenBLAS 0.3.34")
    assert ("problem: OPENBLAS_CORETYPE=Haswell" in out.stdout) == affected
    if affected:
        assert out.returncode == 1


@pytest.mark.parametrize("coretype", ["Haswell", "zen", " ZEN "])
def test_forced_kernels_that_crashed_are_named_with_the_fix(coretype: str) -> None:
    message = coretype_warning({"OPENBLAS_CORETYPE": coretype}, CRASHED)
    assert message is not None
    assert f"OPENBLAS_CORETYPE={coretype.strip()}" in message
    assert "OpenBLAS 0.3.34.237.2)" in message
    assert "unset OPENBLAS_CORETYPE" in message and "numpy<=2.5.1" in message


@pytest.mark.parametrize(
    ("environ", "config"),
    [
        ({}, CRASHED),
        ({"OPENBLAS_CORETYPE": ""}, CRASHED),
        ({"OPENBLAS_CORETYPE": "SkylakeX"}, CRASHED),
        ({"OPENBLAS_CORETYPE": "Haswell"}, FINE),
        ({"OPENBLAS_CORETYPE": "Haswell"}, ""),
    ],
)
def test_no_warning_for_other_kernels_or_releases(environ: dict, config: str) -> None:
    assert coretype_warning(environ, config) is None


def test_unfinished_compilations_are_a_problem_with_the_files_named(tmp_path, monkeypatch):
    """A source without FFCx's ``.c.cached`` marker, older than ten minutes, is reported with
    its name and the fix; a finished one and one still being compiled are not."""
    import os
    import time

    import dolfinx.jit

    from shellobstacle.cli import doctor

    monkeypatch.setattr(dolfinx.jit, "get_options", lambda: {"cache_dir": tmp_path})
    for name in ("finished", "killed", "compiling"):
        (tmp_path / f"libffcx_forms_{name}.c").write_text("/* source */")
    (tmp_path / "libffcx_forms_finished.c.cached").write_text("")
    (tmp_path / "libffcx_forms_finished.so").write_text("")
    old = time.time() - 3600
    for name in ("finished", "killed"):
        os.utime(tmp_path / f"libffcx_forms_{name}.c", (old, old))
    _, problems = doctor.report("test")
    stale = [p for p in problems if "FFCx cache" in p]
    assert len(stale) == 1 and f"1 broken entry in the FFCx cache {tmp_path}" in stale[0]
    assert "libffcx_forms_killed.c: source never finished" in stale[0]
    assert "compiling.c" not in stale[0] and "finished.c" not in stale[0]
    assert "shellobstacle doctor --repair" in stale[0]


REQUIRES = [
    "numpy<2.6,>=2.5",
    "rich<16,>=15",
    "packaging>=24",
    'dolfinx-solver-real<0.12,>=0.11; extra == "dolfinx"',
    'pytest>=8; extra == "test"',
]


def test_the_pinned_ranges_are_the_package_s_and_its_dolfinx_extra_s() -> None:
    assert set(pinned_ranges(REQUIRES)) == {"numpy", "rich", "packaging", "dolfinx-solver-real"}


def test_a_release_outside_its_pinned_range_is_named_with_the_fix() -> None:
    """The DOLFINx wheel's range applies to the module ``dolfinx``; a module that is not
    installed (DOLFINx from conda-forge has no such wheel, but its module is checked) is not
    a problem."""
    ranges = pinned_ranges(REQUIRES)
    within = {"numpy": "2.5.5", "rich": "15.0.0", "dolfinx": "0.11.0.post0", "packaging": None}
    assert out_of_range(within, ranges) == []
    (numpy,) = out_of_range(within | {"numpy": "2.6.0"}, ranges)
    assert numpy.startswith("numpy 2.6.0 is outside the range shellobstacle was tested with")
    assert "install 'numpy<2.6,>=2.5'" in numpy
    (dolfinx,) = out_of_range(within | {"dolfinx": "0.12.0"}, ranges)
    assert dolfinx.startswith("dolfinx 0.12.0 is outside") and "dolfinx-solver-real" in dolfinx
