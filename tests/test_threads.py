"""NumPy's BLAS threads under MPI (shellobstacle.threads)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator

import pytest
from mpi4py import MPI

from shellobstacle import compat  # noqa: F401
from shellobstacle.threads import (
    USER_VARIABLES,
    _numpy_openblas,
    blas_threads,
    coretype_warning,
    limit_blas_threads,
    numpy_blas_config,
)

pytestmark = pytest.mark.skipif(
    _numpy_openblas() is None, reason="NumPy's BLAS is not an OpenBLAS reachable here"
)


@pytest.fixture
def restore_threads() -> Iterator[int]:
    """The thread count before the test, set back after it."""
    before = blas_threads()
    assert before is not None
    yield before
    set_threads, _ = _numpy_openblas()
    set_threads(before)


def test_several_ranks_get_one_thread_each(restore_threads: int) -> None:
    set_threads, _ = _numpy_openblas()
    set_threads(2)
    assert blas_threads() == 2
    assert limit_blas_threads(2, environ={}) == 1
    assert blas_threads() == 1


@pytest.mark.parametrize("variable", USER_VARIABLES)
def test_a_user_setting_is_kept(variable: str, restore_threads: int) -> None:
    set_threads, _ = _numpy_openblas()
    set_threads(2)
    assert limit_blas_threads(2, environ={variable: "2"}) is None
    assert blas_threads() == 2


def test_one_rank_is_left_alone(restore_threads: int) -> None:
    set_threads, _ = _numpy_openblas()
    set_threads(2)
    assert limit_blas_threads(1, environ={}) is None
    assert blas_threads() == 2


@pytest.mark.mpi
def test_under_mpiexec_each_rank_runs_one_thread() -> None:
    """What importing shellobstacle did in this very process (one thread on several ranks)."""
    if MPI.COMM_WORLD.size == 1:
        pytest.skip("needs mpiexec -n 2")
    if any(os.environ.get(name) for name in USER_VARIABLES):
        pytest.skip("a thread count was set by the user")
    assert blas_threads() == 1


CRASHED = "OpenBLAS 0.3.34.237.2  USE64BITINT DYNAMIC_ARCH NO_AFFINITY Haswell MAX_THREADS=64"
FINE = "OpenBLAS 0.3.33.112.0  USE64BITINT DYNAMIC_ARCH NO_AFFINITY Haswell MAX_THREADS=64"


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


def test_importing_the_package_warns_exactly_when_numpy_is_affected() -> None:
    """A fresh interpreter with OPENBLAS_CORETYPE=Haswell: the import warns if and only if
    NumPy's BLAS is the OpenBLAS release that crashed (importing alone does not crash)."""
    env = {**os.environ, "OPENBLAS_CORETYPE": "Haswell"}
    proc = subprocess.run(
        [sys.executable, "-c", "import shellobstacle"], env=env, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    affected = numpy_blas_config().startswith("OpenBLAS 0.3.34")
    assert ("RuntimeWarning: OPENBLAS_CORETYPE=Haswell" in proc.stderr) == affected
