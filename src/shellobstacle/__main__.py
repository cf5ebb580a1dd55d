"""``shellobstacle`` (and ``python -m shellobstacle``): the command line.

The entry point checks the DOLFINx wheel's environment (:mod:`.compat`), starts the watcher
that makes Ctrl-C take effect within seconds also inside long calls into C (:mod:`.interrupt`),
then runs :func:`shellobstacle.cli.main`, which itself changes nothing in the process (tests
and scripts call it directly). The process is left as the environment made it: the variables
that tune it are the user's (docs/user-guide.md, "Process tuning").
"""

from __future__ import annotations

import sys

__all__ = ["main"]


def main() -> int:
    """Bootstrap and run the command line; returns its exit code (130 after a Ctrl-C in the
    second or two of imports before the command line handles it itself)."""
    try:
        from shellobstacle.compat import bootstrap

        bootstrap()
        from mpi4py import MPI

        from shellobstacle.cli import interrupt
        from shellobstacle.cli.main import main as cli_main

        interrupt.install(comm=MPI.COMM_WORLD)
        return cli_main()  # which reports an interrupt of its run itself
    except KeyboardInterrupt:  # while the modules load, before the run's own handling
        if "interrupt" in locals():
            interrupt.acknowledge()
        print("shellobstacle: interrupted while starting; nothing was written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
