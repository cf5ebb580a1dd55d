"""NumPy's BLAS threads under MPI (shellobstacle.threads)."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
from mpi4py import MPI

from shellobstacle import compat  # noqa: F401
from shellobstacle.threads import USER_VARIABLES, _numpy_openblas, blas_threads, limit_blas_threads

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
