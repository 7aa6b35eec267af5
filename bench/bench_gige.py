"""GigE transport settings on the fake link: frames/s and incomplete frames, recommended against defaults.

Run: ``.venv/bin/python bench/bench_gige.py [--frames N] [--seeds K] [--loss P]``.

Everything here is :mod:`fakes.gige_link`'s model (read its docstring), run in virtual time: a
full 4024 x 3036 Mono8 frame (12.2 MB) per exposure, the camera in free run as fast as the link
lets it send, each frame taking the wire for its packets plus the resent ones. The per-packet
loss chances are this model's assumptions (``--loss`` at line rate, a tenth of it when the
camera's throughput limit keeps it under 95 % of the link), not measurements of a PHX122S, so
the table shows what each setting does in the model and how large the difference is for those
chances; it is not a prediction of the real camera's figures.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from fakes.gige_link import GigELink, LinkSettings  # noqa: E402

FRAME_BYTES = 4024 * 3036  # Mono8 at full resolution
CASES = (
    ("defaults: 1500-byte packets, no limit, no resend", LinkSettings(1500, 0, False), 9000),
    ("defaults + resend on", LinkSettings(1500, 0, True), 9000),
    ("jumbo packets only (9000)", LinkSettings(9000, 0, False), 9000),
    ("9000 + resend on, no limit", LinkSettings(9000, 0, True), 9000),
    ("recommended: 9000, limit 115 MB/s, resend on", LinkSettings(9000, 115_000_000, True), 9000),
    ("recommended, NIC without jumbo frames (path MTU 1500)", LinkSettings(9000, 115_000_000, True), 1500),
)


def run_case(s: LinkSettings, mtu: int, frames: int, seed: int, loss: float) -> dict[str, float]:
    link = GigELink(np.random.default_rng(seed), path_mtu=mtu, loss_at_line_rate=loss, loss_limited=loss / 10)
    seconds = 0.0
    complete = 0
    for _ in range(frames):
        ok, t = link.send(FRAME_BYTES, s)
        seconds += t
        complete += ok
    c = link.counters
    return {"fps": frames / seconds, "complete_fps": complete / seconds,
            "incomplete_pct": 100.0 * c["incomplete_frames"] / frames,
            "resends_per_frame": c["resend_requests"] / frames, "lost_packets": float(c["lost_packets"])}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=500, help="frames per seed and case (default 500)")
    ap.add_argument("--seeds", type=int, default=5, help="seeds per case (default 5)")
    ap.add_argument("--loss", type=float, nargs="+", default=[2e-5, 2e-4],
                    help="per-packet loss chances at line rate, one table each (default 2e-5 2e-4)")
    a = ap.parse_args(argv)
    print(f"machine: {machine()}")
    for loss in a.loss:
        print(f"\nmodel: fakes/gige_link.py; {a.frames} frames x {a.seeds} seeds per case; loss {loss:g} per "
              f"packet at line rate, {loss / 10:g} under the throughput limit\n")
        table(a.frames, a.seeds, loss)
    return 0


def table(frames: int, seeds: int, loss: float) -> None:
    print("| case | frames/s sent | complete frames/s | incomplete frames | resend requests / frame "
          "| packets lost for good |")
    print("|---|---|---|---|---|---|")
    for name, s, mtu in CASES:
        rows = [run_case(s, mtu, frames, seed, loss) for seed in range(seeds)]
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
        print(f"| {name} | {mean['fps']:.2f} | {mean['complete_fps']:.2f} | {mean['incomplete_pct']:.1f} % "
              f"| {mean['resends_per_frame']:.3f} | {mean['lost_packets']:.0f} |")


if __name__ == "__main__":
    sys.exit(main())
