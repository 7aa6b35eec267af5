"""`ritactl fetch` throughput: copying the robot's files over the bus (ipc, 1 MiB chunks).

Goal: the copy is not the bottleneck of a gigabit link, i.e. ≥ 100 MB/s
on the same machine; a re-run that finds everything already here costs two sha256 passes.
"""
from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench.common import machine, start_ritad  # noqa: E402
from daemon.bus.client import Client  # noqa: E402
from daemon.ctl.fetch import fetch  # noqa: E402

SIZES_MB = (200, 1)  # one big file, and many small ones (below)
SMALL_FILES = 200


def main() -> None:
    print(f"# bench_fetch\n\nMachine: {machine()}\n")
    r = start_ritad()
    ep, tmp = r.endpoint, r.tmp
    data = tmp / "data" / "datasets"
    rng = np.random.default_rng(1)
    (data / "big").mkdir(parents=True)
    (data / "big" / "blob.bin").write_bytes(rng.bytes(SIZES_MB[0] * 1_000_000))
    (data / "small").mkdir()
    for i in range(SMALL_FILES):
        (data / "small" / f"{i:04d}.png").write_bytes(rng.bytes(SIZES_MB[1] * 1_000_000 // 10))
    rows = []
    try:
        with Client(ep, timeout=30) as c:
            for what, path, total in (("one 200 MB file", "datasets/big", SIZES_MB[0] * 1e6),
                                      (f"{SMALL_FILES} files of 100 kB", "datasets/small",
                                       SMALL_FILES * 1e5)):
                dest = tmp / "laptop"
                t = time.perf_counter()
                fetch(c, [path], dest, say=lambda _: None)
                first = time.perf_counter() - t
                t = time.perf_counter()
                r = fetch(c, [path], dest, say=lambda _: None)
                again = time.perf_counter() - t
                assert not r["fetched"] and not r["errors"]
                rows.append((what, total / first / 1e6, first, again))
                shutil.rmtree(dest)
    finally:
        r.stop()
    print("| what | throughput | time | re-run (all skipped) | goal |\n|---|---|---|---|---|")
    for what, mbs, first, again in rows:
        print(f"| {what}, ipc | {mbs:.0f} MB/s | {first:.2f} s | {again:.2f} s | ≥ 100 MB/s |")


if __name__ == "__main__":
    main()
