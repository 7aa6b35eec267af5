"""``ritactl record``'s writing path against a plain sequential write of the same bytes.

Goal: the recorder's throughput ≥ 0.8× a plain write of the same bytes, measured in the same run,
so recording never becomes the bottleneck that costs the 1 kHz tracker path a record. The last
column says the real requirement directly: how many times faster than the session produces them
the recorder takes the workload's messages (its simulated seconds ÷ the recorder's seconds).

Method: bus messages are made up front exactly as a subscriber receives them (topic, msgpack
telemetry with each record's ``t_ns``; frame header + raw pixels), from a seeded RNG. "Recorder" is
what ``ritactl record`` does per message after ``recv``: unpack the msgpack, JSON-encode telemetry
and frame headers, add the Foxglove messages (a PoseInFrame per tracker record and per robot.state),
wrap the pixels in a CDR ``foxglove_msgs/msg/RawImage`` (or encode them as JPEG or PNG in a
``CompressedImage``: the rows marked so), add to the MCAP writer (chunking, compression, indexes),
then ``finish``.
"Plain" writes the same received bytes (the messages' frames, concatenated) to a file with one
``write`` per message. Both write to the same temporary folder without fsync (the page cache: the
stricter comparison, since a disk's own speed would hide the recorder's CPU cost); median of
``--repeat`` runs. Throughput is bus bytes in per second for both, so the ratio is the recorder's
cost per received byte. Workloads: the 1 kHz tracker stream (100 records per packet, as the fake
tracker batches them, plus robot.state at 10 Hz), frames at a reduced 640×480 Mono8, and full-size
12.2 MP Mono8 frames (20 of them: 4 s at 5 fps).
Run: ``.venv/bin/python bench/bench_record.py [--seconds 60] [--repeat 3]``.
"""
from __future__ import annotations

import argparse
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from daemon.bus.protocol import pack, telemetry, unpack  # noqa: E402
from daemon.ctl.record import Recorder  # noqa: E402

Message = list[bytes]


def tracker_session(seconds: int, rng: random.Random) -> list[Message]:
    """``seconds`` of the 1 kHz tracker stream in 100-record packets, and robot.state at 10 Hz."""
    msgs: list[Message] = []
    seq, rec = 0, 0
    t0 = 1_764_000_000_000_000_000
    for k in range(seconds * 10):
        t = t0 + k * 100_000_000
        seq += 1
        pts = {c: [rng.uniform(-3000, 3000) for _ in range(100)] for c in "xyz"}
        times = [t - 100_000_000 + (i + 1) * 1_000_000 for i in range(100)]  # each record's time, as ritad's
        data = {"n": 100, **pts, "status": [0] * 100,
                "device_time": [[ts // 10**9 for ts in times], [ts % 10**9 // 1000 for ts in times]],
                "host_time_ns": t, "host_monotonic_ns": t - t0, "seq": rec, "t_ns": times,
                "t_sigma_ns": [20_000] * 100}
        rec += 100
        msgs.append([b"tracker.point", telemetry(seq, t, data)])
        seq += 1
        state = {"state": "MOVING", "x_mm": rng.uniform(0, 500), "y_mm": 0.0, "heading_deg": 0.0,
                 "roll_deg": 0.01, "pitch_deg": -0.02, "battery_v": 25.1, "t_ns": t - 3_000_000}
        msgs.append([b"robot.state", telemetry(seq, t, state)])
    return msgs


def frames(count: int, shape: tuple[int, int], rng: random.Random) -> list[Message]:
    t0 = 1_764_000_000_000_000_000
    return [[b"camera.frame", pack({"v": 1, "seq": i + 1, "dropped": 0, "frame_id": i + 1,
                                    "pixel_format": "Mono8",
                                    "shape": list(shape), "dtype": "|u1", "exposure_us": 2000.0,
                                    "t_ns": t0 + i * 200_000_000 - 7_000_000, "t_sigma_ns": 300_000,
                                    "device_time_ns": None, "host_time_ns": t0 + i * 200_000_000,
                                    "host_monotonic_ns": i * 200_000_000, "incomplete_count": 0}),
             rng.randbytes(shape[0] * shape[1])]  # noise, new in every frame: what compresses least
            for i in range(count)]


def run_recorder(msgs: list[Message], path: Path, compression: str, frames_format: str = "raw") -> None:
    with open(path, "wb") as f:
        rec = Recorder(f, {"bench": "1"}, compression, frames_format=frames_format)
        for m in msgs:
            now = time.time_ns()
            if m[0] == b"camera.frame":
                rec.frame(unpack(m[1]), m[2], now)
            else:
                rec.telemetry(m[0].decode(), unpack(m[1]), now)
        rec.finish()


def run_plain(msgs: list[Message], path: Path) -> None:
    with open(path, "wb") as f:
        for m in msgs:
            f.write(b"".join(m))


def timed(fn: Callable[[], None], repeat: int) -> float:
    runs = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t)
    return statistics.median(runs)


def measure(name: str, msgs: list[Message], session_s: float, compression: str, repeat: int,
            tmp: Path, frames_format: str = "raw") -> dict[str, Any]:
    size = sum(len(p) for m in msgs for p in m)
    rec_s = timed(lambda: run_recorder(msgs, tmp / "r.mcap", compression, frames_format), repeat)
    plain_s = timed(lambda: run_plain(msgs, tmp / "p.bin"), repeat)
    return {"workload": name if frames_format == "raw" else f"{name}, {frames_format}",
            "compression": compression, "messages": len(msgs), "in_mb": size / 1e6,
            "file_mb": (tmp / "r.mcap").stat().st_size / 1e6, "rec_mbs": size / 1e6 / rec_s,
            "plain_mbs": size / 1e6 / plain_s, "ratio": plain_s / rec_s, "msg_per_s": len(msgs) / rec_s,
            "real_time": session_s / rec_s}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=int, default=60, help="length of the simulated session")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    rng = random.Random(21)
    loads = [(f"tracker 1 kHz + robot.state, {a.seconds} s", tracker_session(a.seconds, rng), a.seconds),
             (f"frames 640×480 Mono8, {a.seconds} s at 5 fps", frames(a.seconds * 5, (480, 640), rng),
              a.seconds),
             ("frames 4024×3036 Mono8 (12.2 MP), 20", frames(20, (3036, 4024), rng), 4.0)]
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for name, msgs, session_s in loads:
            for comp in ("zstd", "lz4", "none"):
                rows.append(measure(name, msgs, session_s, comp, a.repeat, Path(d)))
            if name.startswith("frames"):  # CompressedImage: the encoding is the cost (auto: no compression)
                for ff in ("jpeg", "png"):
                    rows.append(measure(name, msgs, session_s, "none", a.repeat, Path(d), ff))
    print(machine())
    print("\n| workload | compression | bus MB in | file MB | recorder MB/s | plain write MB/s "
          "| ratio (goal ≥ 0.8) | messages/s | × the session's rate |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['workload']} | {r['compression']} | {r['in_mb']:.1f} | {r['file_mb']:.1f} "
              f"| {r['rec_mbs']:.0f} | {r['plain_mbs']:.0f} | {r['ratio']:.2f} | {r['msg_per_s']:,.0f} "
              f"| {r['real_time']:,.0f} |")


if __name__ == "__main__":
    main()
