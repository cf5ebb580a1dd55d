"""Does NumPy's OpenBLAS survive a forced kernel choice (``OPENBLAS_CORETYPE``) on this machine?

Some machines set ``OPENBLAS_CORETYPE`` for older OpenBLAS builds. On this project's machine
(AMD EPYC, family 25, AVX-512), NumPy 2.5.2-2.5.5 (their OpenBLAS 0.3.34) crashed with a
segmentation fault in a plain 500 x 500 matrix product when it was ``Haswell`` or ``Zen``
(``shellobstacle doctor`` names it). For each core type this runs that product in a fresh
interpreter and prints one JSON line: the core type, NumPy's version and OpenBLAS, and the
interpreter's return code (0: fine, -11: killed by SIGSEGV).

    .venv/bin/python benchmarks/numpy_coretype.py
    .venv/bin/python benchmarks/numpy_coretype.py --coretypes Haswell,SkylakeX
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

PROBE = """
import numpy as np
rng = np.random.default_rng(0)
for n in (64, 200, 500, 1000):
    a, b = rng.random((n, n)), rng.random((n, n))
    c = a @ b
    assert abs(c[0, 0] - a[0] @ b[:, 0]) < 1e-9 * n
"""

CORETYPES = "unset,Prescott,Nehalem,Sandybridge,Haswell,Zen,SkylakeX,Cooperlake,SapphireRapids"


def numpy_blas() -> str:
    """NumPy's version and the configuration string of its BLAS."""
    import numpy as np

    from shellobstacle.threads import numpy_blas_config

    return f"numpy {np.__version__}, {numpy_blas_config()}"


def main() -> None:
    """Run the probe once per core type and print JSON lines."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--coretypes", default=CORETYPES, help="'unset' runs without the variable")
    args = ap.parse_args()
    blas = numpy_blas()
    for coretype in args.coretypes.split(","):
        env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE",)}
        if coretype != "unset":
            env["OPENBLAS_CORETYPE"] = coretype
        proc = subprocess.run(
            [sys.executable, "-c", PROBE], env=env, capture_output=True, timeout=300
        )
        rec = {"benchmark": "numpy_coretype", "coretype": coretype, "numpy_blas": blas}
        rec["returncode"] = proc.returncode
        print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
