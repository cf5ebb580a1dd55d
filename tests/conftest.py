"""Test configuration: the DOLFINx wheel's environment is checked once, as the command does.

The suite runs the plain library: ``./run test`` sets ``SHELLOBSTACLE_TUNING=off`` for the
commands it starts, and the tuning's own tests start their processes with it set.
"""

from shellobstacle.compat import bootstrap

bootstrap()
