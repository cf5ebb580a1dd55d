"""What touching fresh memory costs on this machine: a block allocated, written and freed.

Each round waits its pause, maps ``--gib`` GiB of anonymous memory (4 kB pages as glibc's
malloc gets them for a large block, or with ``--huge`` transparent huge pages requested by
``madvise`` as NumPy does for large arrays), writes it twice and unmaps it: the first write
pays the page faults, the second is the memory's own speed. ``--ranks 2`` runs two such
processes at the same time (do two cores fault in parallel?). One JSON line per process and
round.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import mmap
import multiprocessing
import time


def _anon_huge_kib() -> int:
    """kB of this process's anonymous memory in transparent huge pages (Linux; else 0)."""
    try:
        with open("/proc/self/smaps_rollup") as f:
            return sum(int(line.split()[1]) for line in f if line.startswith("AnonHugePages:"))
    except OSError:
        return 0


def rounds(tag: int, gib: float, pauses: list[float], huge: bool) -> list[dict]:
    """Map, write twice and unmap ``gib`` GiB after each pause; seconds per round."""
    n = int(gib * 2**30)
    out = []
    for k, pause in enumerate(pauses):
        time.sleep(pause)
        t = time.perf_counter()
        # private, as malloc's memory is (a shared anonymous mapping is shmem, which gets
        # no transparent huge pages under this kernel's shmem_enabled = never)
        block = mmap.mmap(-1, n, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
        if huge:
            block.madvise(mmap.MADV_HUGEPAGE)
        address = ctypes.addressof(ctypes.c_char.from_buffer(block))
        ctypes.memset(address, 1, n)
        first = time.perf_counter() - t
        t = time.perf_counter()
        ctypes.memset(address, 2, n)
        again = time.perf_counter() - t
        huge_kib = _anon_huge_kib()
        del address
        block.close()
        out.append(
            {"process": tag, "round": k, "pause_s": pause, "gib": gib, "huge_pages": huge,
             "first_write_s": first, "second_write_s": again,
             "first_write_s_per_gib": first / gib, "anon_huge_pages_gib": huge_kib / 2**20}
        )  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--gib", type=float, default=1.0)
    ap.add_argument("--pauses", default="0,0,0,3,3", help="seconds before each round")
    ap.add_argument("--ranks", type=int, default=1, help="processes at the same time")
    ap.add_argument("--huge", action="store_true", help="madvise(MADV_HUGEPAGE)")
    args = ap.parse_args()
    pauses = [float(p) for p in args.pauses.split(",")]
    with multiprocessing.Pool(args.ranks) as pool:
        work = [(r, args.gib, pauses, args.huge) for r in range(args.ranks)]
        results = pool.starmap(rounds, work)
    for rows in results:
        for row in rows:
            row["processes"] = args.ranks
            print(
                json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()})
            )


if __name__ == "__main__":
    main()
