"""How often an exactly right σ fails issue #33's coverage line, against the product's measured cases.

The line: per experiment (40 stops), the 95th percentile of |e|/σ at most 1.73, the 95 % radius of an
isotropic 2-D Gaussian whose σ is the radial rms. That radius is where the *population's* 95 % lies; the
95th percentile of 40 draws scatters around it, so a right σ exceeds it in a large share of experiments.
A share ``f`` of the variance may be common to all stops of an experiment (one draw each: the calibration,
the mount, the stored bias), which makes the 40 values dependent.

    PYTHONPATH=$PWD .venv/bin/python bench/coverage_sampling.py [--rows bench/results/X.jsonl.gz]

``--rows``: a shapes harness's rows (bench/accuracy_shapes.py): its cases' p95 against the same line.
Seeded; one second. docs/accuracy.md, "After stop 41".
"""
from __future__ import annotations

import argparse
import gzip
import json
import statistics

import numpy as np

LINE, STOPS = 1.73, 40


def p95_right_sigma(common_share: float, experiments: int, rng: np.random.Generator) -> np.ndarray:
    """The p95 of |e|/σ over ``STOPS`` stops, per simulated experiment, for a σ that is exactly right."""
    common = rng.normal(size=(experiments, 1, 2)) * np.sqrt(common_share / 2)  # per axis: half the variance
    own = rng.normal(size=(experiments, STOPS, 2)) * np.sqrt((1.0 - common_share) / 2)
    ratio = np.linalg.norm(common + own, axis=2)  # radial rms of common + own is 1: |e|/σ itself
    return np.percentile(ratio, 95, axis=1)


def sampling_table(cases: int, experiments: int, seed: int) -> list[str]:
    """Markdown rows: per common share, P(p95 > LINE), the median p95, misses expected in ``cases``."""
    rng = np.random.default_rng(seed)
    rows = ["| common share of the variance | P(p95 > 1.73) | median p95 | expected misses of "
            f"{cases} | P(none of {cases}) |", "|---:|---:|---:|---:|---:|"]
    for share in (0.0, 0.2, 0.3, 0.5):
        p95 = p95_right_sigma(share, experiments, rng)
        p = float((p95 > LINE).mean())
        rows.append(f"| {share:.1f} | {p:.3f} | {float(np.median(p95)):.2f} | {cases * p:.0f} | "
                    f"{(1.0 - p) ** cases:.0e} |")
    return rows


def measured(path: str) -> list[str]:
    """The shapes harness's cases against the line: how many exceed it, with and without `warn`."""
    with gzip.open(path, "rt") if path.endswith(".gz") else open(path) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    p95 = [r["p95_ratio"] for r in rows if r.get("p95_ratio") is not None]
    over = [r for r in rows if (r.get("p95_ratio") or 0.0) > LINE]
    ok = sum(1 for r in over if r.get("verdict") == "ok")
    return [f"{path}: {len(p95)} cases, median p95 {statistics.median(p95):.2f}, "
            f"{len(over)} over {LINE} ({len(over) - ok} warn, {ok} ok)"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=264, help="cases in the harness (default: 264)")
    ap.add_argument("--experiments", type=int, default=100_000, help="simulated experiments per share")
    ap.add_argument("--seed", type=int, default=41)
    ap.add_argument("--rows", help="a shapes harness's rows (.jsonl or .jsonl.gz)")
    args = ap.parse_args(argv)
    print("\n".join(sampling_table(args.cases, args.experiments, args.seed)))
    if args.rows:
        print("\n".join(measured(args.rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
