"""Benchmark of the dataset contract checks on a full-size referencing folder.

Writes one referencing dataset with a rendered 4024×3036 image (simulated world), then
times ``validate_folder`` (JSON Schemas + value checks + the PNG read and inflated in
pure Python), the PNG check alone, ``recompute`` (which validates first: the share of
validation in it), and ``ritactl validate`` as a command (process start included).

Run: ``.venv/bin/python bench/bench_datasets.py``
"""
from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import FULL, ROOT, machine, write_referencing_folder  # noqa: E402

from daemon.compute.recompute import recompute  # noqa: E402
from daemon.bus.datasets import validate_folder  # noqa: E402
from daemon.bus.png_check import png_info  # noqa: E402


def timed(fn, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> int:
    root = Path(tempfile.mkdtemp(prefix="rita-bench-ds-")) / "ref"
    write_referencing_folder(root)
    assert validate_folder(root) == [], validate_folder(root)
    png_mb = (root / "run0.png").stat().st_size / 2 ** 20
    v = timed(lambda: validate_folder(root), 5)
    p = timed(lambda: png_info(root / "run0.png"), 5)
    r = timed(lambda: recompute(root), 3)
    cli = timed(lambda: subprocess.run([sys.executable, "-m", "daemon.ctl.main", "validate", str(root)],
                                       cwd=ROOT, check=True, capture_output=True), 3)
    med = statistics.median
    print(machine())
    print(f"\nreferencing folder, one {FULL[0]}×{FULL[1]} 8-bit PNG ({png_mb:.1f} MiB)\n")
    print("| metric | median (min–max) |\n|---|---|")
    print(f"| validate_folder (schemas + values + PNG), n=5 | {med(v) * 1000:.0f} ms "
          f"({min(v) * 1000:.0f}–{max(v) * 1000:.0f}) |")
    print(f"| of which the PNG check (chunks, CRCs, inflate), n=5 | {med(p) * 1000:.0f} ms |")
    print(f"| recompute (validation included), n=3 | {med(r):.2f} s ({min(r):.2f}–{max(r):.2f}); "
          f"validation {100 * med(v) / med(r):.0f} % of it |")
    print(f"| `ritactl validate` command, process start included, n=3 | {med(cli) * 1000:.0f} ms |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
