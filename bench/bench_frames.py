"""Full-size camera frames through the daemon to a subscriber in another process.

Goals: ≥ 60 frames/s sustained of 4024×3036 Mono8; 0 frames dropped
at 10 fps; acquisition → subscriber latency p99 ≤ 30 ms. Also reported: daemon CPU
time per frame (utime+stime from /proc/<pid>/stat over the run) and peak RSS (VmHWM).

Method: ritad runs the simulated camera with ``size=full&prerender=2&fps=F`` (two
rendered frames cycled, so rendering costs nothing per frame; each frame is still a
fresh 12 MB array the daemon owns). A subscriber process on the ipc frame endpoint
rebuilds each image with ``np.frombuffer`` and records the header ``seq`` (gaps =
frames dropped at the PUB socket), ``dropped`` (dropped before it), ``frame_id``
(gaps = frames the camera produced that never reached the publisher) and the
latency from ``host_monotonic_ns`` (acquisition, same host clock) to its receive.
The daemon's CPU figure includes its idle tracker and robot fakes.

Run: ``.venv/bin/python bench/bench_frames.py [--seconds 20] [--max-fps 200]``.
Also ``--sub ENDPOINT`` runs the subscriber side (used by this and bench_load.py).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import (  # noqa: E402
    cpu_seconds, finish, machine, pct, ritad_toml, serve_subscriber, spawn, start_ritad, vm_kib)
from daemon.bus.client import Client  # noqa: E402

# --------------------------------------------------------------------------- subscriber process


class FrameStats:
    """What a frame subscriber sees: header seq gaps, frame id gaps, latency."""

    def __init__(self) -> None:
        self.frames = 0
        self.seq_prev: int | None = None
        self.seq_gaps = 0
        self.id_prev: int | None = None
        self.id_gaps = 0
        self.dropped_first: int | None = None
        self.dropped_last = 0
        self.first_rx = self.last_rx = 0.0
        self.lat_acq_ms: list[float] = []
        self.lat_pub_ms: list[float] = []
        self.bad_shape = 0
        self.checksum = 0

    def add(self, h: dict[str, Any], pixels: memoryview, rx_ns: int) -> None:
        import numpy as np

        img = np.frombuffer(pixels, np.dtype(h["dtype"]))
        if img.size != h["shape"][0] * h["shape"][1]:
            self.bad_shape += 1
        else:
            img = img.reshape(h["shape"])
            self.checksum += int(img[::512, ::512].sum())  # touch the pixels, as a real consumer would
        self.frames += 1
        now = rx_ns / 1e9
        self.first_rx = self.first_rx or now
        self.last_rx = now
        if self.seq_prev is not None and h["seq"] > self.seq_prev + 1:
            self.seq_gaps += h["seq"] - self.seq_prev - 1
        self.seq_prev = h["seq"]
        if self.id_prev is not None and h["frame_id"] > self.id_prev + 1:
            self.id_gaps += h["frame_id"] - self.id_prev - 1
        self.id_prev = h["frame_id"]
        if self.dropped_first is None:
            self.dropped_first = h["dropped"]
        self.dropped_last = h["dropped"]
        self.lat_acq_ms.append((rx_ns - h["host_monotonic_ns"]) / 1e6)
        self.lat_pub_ms.append((rx_ns - h["publish_monotonic_ns"]) / 1e6)

    def result(self) -> dict[str, Any]:
        span = self.last_rx - self.first_rx
        return {"frames": self.frames, "span_s": span,
                "fps": (self.frames - 1) / span if span > 0 else 0.0,
                "seq_gaps": self.seq_gaps, "frame_id_gaps": self.id_gaps,
                "dropped_before_socket": self.dropped_last - (self.dropped_first or 0),
                "bad_shape": self.bad_shape,
                "lat_p50_ms": pct(self.lat_acq_ms, 50), "lat_p99_ms": pct(self.lat_acq_ms, 99),
                "lat_max_ms": max(self.lat_acq_ms, default=float("nan")),
                "pub_lat_p50_ms": pct(self.lat_pub_ms, 50), "pub_lat_p99_ms": pct(self.lat_pub_ms, 99)}


def subscriber_main(endpoint: str, hwm: int, stalled: bool, linger_s: float = 1.0) -> None:
    """Subscribe to frames, print ``subscribed``, count until stdin closes, print JSON."""
    from daemon.bus.client import Subscriber
    from daemon.bus.protocol import unpack

    stats = FrameStats()
    serve_subscriber(Subscriber(endpoint, ["camera.frame"], hwm=hwm),
                     lambda f, rx: stats.add(unpack(f[1].buffer), f[2].buffer, rx),
                     stats.result, stalled, linger_s)


# --------------------------------------------------------------------------- daemon side


def run(fps: float, seconds: float) -> dict[str, Any]:
    """One daemon with a full-size prerendered camera at ``fps``; one frame subscriber process."""
    cam = f"sim:?size=full&prerender=2&fps={fps:g}"
    r = start_ritad(ritad_toml(devices={"camera": cam}), timeout=120)
    proc, ep = r.proc, r.endpoint
    try:
        with Client(ep, timeout=30) as c:
            c.wait_ready(("camera",), 300)
            sub = spawn("bench_frames.py", "--sub", c.hello()["frame_endpoints"][0])
            c.call("camera.stream.start")
            time.sleep(1.0)  # the first frames include start-up; measure the steady state
            cpu0, t0 = cpu_seconds(proc.pid), time.monotonic()
            cam0 = c.call("camera.status")["frames"]
            time.sleep(seconds)
            cpu1, t1 = cpu_seconds(proc.pid), time.monotonic()
            cam1 = c.call("camera.status")["frames"]
            c.call("camera.stream.stop")
            time.sleep(0.5)
            health = c.call("status")
            hwm = vm_kib(proc.pid, "VmHWM")
            res = finish(sub)
        res.update(cpu_per_frame_ms=(cpu1 - cpu0) / max(1, cam1 - cam0) * 1e3,
                   cpu_util=(cpu1 - cpu0) / (t1 - t0), camera_fps=(cam1 - cam0) / (t1 - t0),
                   vmhwm_mib=hwm / 1024, daemon_frames=health["frames"])
        return res
    finally:
        r.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="length of each measured run")
    ap.add_argument("--max-fps", type=float, default=200.0,
                    help="camera rate asked for in the throughput run")
    ap.add_argument("--sub", metavar="ENDPOINT", help="(internal) run as frame subscriber")
    ap.add_argument("--hwm", type=int, default=0)
    ap.add_argument("--stalled", action="store_true")
    a = ap.parse_args()
    if a.sub:
        subscriber_main(a.sub, a.hwm, a.stalled)
        return
    fast = run(a.max_fps, a.seconds)
    slow = run(10.0, a.seconds)
    print(f"# bench_frames\n\nMachine: {machine()}\n")
    print("| metric | value | goal | met |\n|---|---|---|---|")
    print(f"| sustained frames/s, 4024×3036 Mono8, camera asked for {a.max_fps:g} fps, "
          f"{fast['span_s']:.0f} s | {fast['fps']:.1f} at the subscriber (camera produced "
          f"{fast['camera_fps']:.1f}/s; PUB seq gaps {fast['seq_gaps']}) | ≥ 60 | "
          f"{'yes' if fast['fps'] >= 60 else 'NO'} |")
    lost = slow["seq_gaps"] + slow["frame_id_gaps"] + slow["dropped_before_socket"] + slow["bad_shape"]
    print(f"| frames dropped at 10 fps over {slow['span_s']:.0f} s | {lost} of {slow['frames']} "
          f"(seq gaps {slow['seq_gaps']}, frame-id gaps {slow['frame_id_gaps']}, dropped before socket "
          f"{slow['dropped_before_socket']}) | 0 | {'yes' if lost == 0 else 'NO'} |")
    print(f"| latency acquisition → subscriber at 10 fps | p50 {slow['lat_p50_ms']:.1f} ms, "
          f"p99 {slow['lat_p99_ms']:.1f} ms (max {slow['lat_max_ms']:.1f}) | p99 ≤ 30 ms | "
          f"{'yes' if slow['lat_p99_ms'] <= 30 else 'NO'} |")
    print(f"| of which publish → subscriber (zmq ipc transport) at 10 fps "
          f"| p50 {slow['pub_lat_p50_ms']:.1f} ms, "
          f"p99 {slow['pub_lat_p99_ms']:.1f} ms | – | – |")
    print(f"| latency acquisition → subscriber at {fast['fps']:.0f} fps | p50 {fast['lat_p50_ms']:.1f} ms, "
          f"p99 {fast['lat_p99_ms']:.1f} ms | – | – |")
    for r, label in ((slow, "10 fps"), (fast, f"{fast['camera_fps']:.0f} fps")):
        print(f"| daemon CPU per frame at {label} (utime+stime / frames) | {r['cpu_per_frame_ms']:.1f} ms "
              f"({r['cpu_util'] * 100:.0f} % of one core) | – | – |")
    print(f"| daemon peak RSS (VmHWM), 10 fps run / max-rate run | {slow['vmhwm_mib']:.0f} MiB / "
          f"{fast['vmhwm_mib']:.0f} MiB | – | – |")


if __name__ == "__main__":
    main()
