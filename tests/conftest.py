"""Test configuration: the DOLFINx wheel's environment is checked once, as the command does.

The suite runs the plain library: ``./run test`` sets ``SHELLOBSTACLE_TUNING=off`` for the
commands it starts, and the tuning's own tests start their processes with it set.
"""

import pytest

from shellobstacle.compat import bootstrap

bootstrap()


@pytest.fixture
def shared_dir(tmp_path):
    """A folder that every MPI rank sees (rank 0's temporary folder)."""
    from cli_helpers import shared_folder

    yield from shared_folder(tmp_path)
