"""ritad under load: tracker at 1 kHz + full-size frames at 10 fps + three subscribers, one stalled.

Goals: command round trip p99 ≤ 50 ms under load; daemon
RSS bounded over the run; 0 tracker results lost for the on-robot ipc subscriber;
drops counted per subscriber.

Method: ritad with the simulated world, endpoints on ipc (on-robot clients) and tcp
127.0.0.1 (laptop clients). Separate processes: the "worker" subscribes to all
telemetry over ipc; the "viewer" subscribes to frames over tcp; the "stalled"
client subscribes to telemetry and frames over tcp and never reads until the end
(then it drains what it has, so its own gaps show what it lost); the "operator"
sends ``ping`` and ``status`` every 50 ms over tcp and times each round trip. This
process samples the daemon's RSS every 5 s.

Run: ``.venv/bin/python bench/bench_load.py [--duration 300]`` (``--duration 30`` for a quick run).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_frames import FrameStats  # noqa: E402
from bench.bench_tracker_daemon import TelemetryStats, lock_and_stream  # noqa: E402
from bench.common import (  # noqa: E402
    cpu_seconds, finish, machine, pct, pick, ritad_toml, spawn, start_ritad, vm_kib)
from daemon.bus.client import Client  # noqa: E402
from daemon.bus.protocol import CommandError  # noqa: E402

CONFIG = ritad_toml(tcp=True, insecure_tcp=True,  # loopback only: the benchmark measures the plain bus
                    devices={"tracker": "sim:?packet_rate=10&sigma_mm=0.01",
                             "camera": "sim:?size=full&prerender=2&fps=10"})


# --------------------------------------------------------------------------- helper processes


def _wait_stdin(poll_s: float) -> bool:
    """True once the parent wrote to (or closed) our stdin."""
    import select

    ready, _, _ = select.select([sys.stdin], [], [], poll_s)
    return bool(ready)


def operator_main(endpoint: str, period_s: float) -> None:
    """Every ``period_s``: one ``ping`` and one ``status``; round trips in ms; JSON at the end."""
    rts: dict[str, list[float]] = {"ping": [], "status": []}
    errors = 0
    with Client(endpoint, timeout=5) as c:
        c.call("ping")
        print("subscribed", flush=True)
        next_t = time.monotonic()
        while not _wait_stdin(max(0.0, next_t - time.monotonic())):
            next_t += period_s
            for cmd in ("ping", "status"):
                t = time.perf_counter()
                try:
                    c.call(cmd)
                except CommandError:  # a timeout or error reply counts, and the run goes on
                    errors += 1
                    continue
                rts[cmd].append((time.perf_counter() - t) * 1e3)
    print(json.dumps({"rt": rts, "errors": errors}), flush=True)


def stalled_main(tel_ep: str, frame_ep: str) -> None:
    """Subscribe to everything and read nothing until told; then drain and report the gaps."""
    import zmq

    from daemon.bus.client import Subscriber
    from daemon.bus.protocol import unpack

    # a small frame RCVHWM keeps this process from queueing gigabytes on the shared machine;
    # once it is full the daemon's PUB has to drop for this peer, which is what we test
    tel = Subscriber(tel_ep, None)
    frm = Subscriber(frame_ep, ["camera.frame"], hwm=4)
    print("subscribed", flush=True)
    while not _wait_stdin(1.0):
        pass
    ts, fs = TelemetryStats(), FrameStats()
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        for sock, fn in ((tel.sock, "t"), (frm.sock, "f")):
            try:
                parts = sock.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                continue
            rx = time.monotonic_ns()
            if fn == "t":
                ts.add(parts[0].bytes.decode(), unpack(parts[1].buffer), rx)
            else:
                fs.add(unpack(parts[1].buffer), parts[2].buffer, rx)
        time.sleep(0.0005)
    print(json.dumps({"telemetry": ts.result(), "frames": fs.result()}), flush=True)


# --------------------------------------------------------------------------- the run


def run(duration: float, sample_s: float = 5.0) -> dict[str, Any]:
    r = start_ritad(CONFIG, timeout=120)
    proc, ep = r.proc, r.endpoint
    try:
        with Client(ep, timeout=30) as c:
            c.wait_ready(("tracker", "camera", "robot"), 300)
            hello = c.hello()
            tel, frm, cmd = hello["telemetry_endpoints"], hello["frame_endpoints"], hello["command_endpoints"]
            worker = spawn("bench_tracker_daemon.py", "--sub", pick(tel, "ipc://"))
            viewer = spawn("bench_frames.py", "--sub", pick(frm, "tcp://"))
            stalled = spawn("bench_load.py", "--stalled", pick(tel, "tcp://"), pick(frm, "tcp://"))
            lock_and_stream(c, 1000.0)
            c.call("camera.stream.start")
            operator = spawn("bench_load.py", "--operator", pick(cmd, "tcp://"))
            t0, cpu0 = time.monotonic(), cpu_seconds(proc.pid)
            rss: list[tuple[float, float]] = []
            while (t := time.monotonic() - t0) < duration:
                rss.append((t, vm_kib(proc.pid, "VmRSS") / 1024))
                time.sleep(min(sample_s, max(0.0, duration - t)))
            rss.append((time.monotonic() - t0, vm_kib(proc.pid, "VmRSS") / 1024))
            cpu = (cpu_seconds(proc.pid) - cpu0) / (time.monotonic() - t0)
            op = finish(operator)
            c.call("camera.stream.stop")
            c.call("tracker.stream.stop", timeout=30)
            time.sleep(1.0)
            st = c.call("tracker.status", timeout=30)
            health = c.call("status")
            hwm = vm_kib(proc.pid, "VmHWM") / 1024
            res = {"worker": finish(worker), "viewer": finish(viewer), "stalled": finish(stalled),
                   "operator": op, "rss": rss, "vmhwm_mib": hwm, "cpu_util": cpu,
                   "adapter_points": st["counters"]["points"], "health": health}
        return res
    finally:
        r.stop()


def report(r: dict[str, Any], duration: float) -> None:
    op, w, v, s = r["operator"], r["worker"], r["viewer"], r["stalled"]
    print(f"# bench_load ({duration:.0f} s)\n\nMachine: {machine()}\n")
    print("| metric | value | goal | met |\n|---|---|---|---|")
    for cmd in ("ping", "status"):
        rt = op["rt"][cmd]
        p99 = pct(rt, 99)
        print(f"| `{cmd}` round trip under load, tcp, every 50 ms (n={len(rt)}, errors {op['errors']}) | "
              f"p50 {pct(rt, 50):.2f} ms, p99 {p99:.2f} ms, max {max(rt, default=float('nan')):.1f} ms | "
              f"p99 ≤ 50 ms | {'yes' if p99 <= 50 and not op['errors'] else 'NO'} |")
    rss = [m for _, m in r["rss"]]
    half = len(rss) // 2
    first, second = max(rss[: max(1, half)]), max(rss[half:])
    bounded = second <= first * 1.05 + 16  # the second half never climbs above the first (+5 %, +16 MiB)
    print(f"| daemon RSS, sampled every 5 s ({len(rss)} samples) | start {rss[0]:.0f} MiB, max 1st half "
          f"{first:.0f}, max 2nd half {second:.0f}, end {rss[-1]:.0f} MiB; VmHWM {r['vmhwm_mib']:.0f} MiB | "
          f"bounded | {'yes' if bounded else 'NO'} |")
    lost = ((w["rec_seq_first"] or 0) + w["rec_seq_missing"] + w["dev_missing"]
            + max(0, r["adapter_points"] - w["records"]))
    print(f"| tracker results lost, on-robot ipc subscriber | {lost} of {r['adapter_points']:,} "
          f"(seq gaps {w['rec_seq_missing']}, device-time gaps {w['dev_missing']}) | 0 | "
          f"{'yes' if lost == 0 else 'NO'} |")
    print(f"| drops, worker (ipc, all telemetry) | {w['sock_seq_gaps']} telemetry messages of "
          f"{w['messages']:,} | – | – |")
    print(f"| drops, viewer (tcp, frames) | {v['seq_gaps']} frames (+{v['dropped_before_socket']} before the "
          f"socket) of {v['frames']}; "
          f"latency p50 {v['lat_p50_ms']:.1f} / p99 {v['lat_p99_ms']:.1f} ms | – | – |")
    st, sf = s["telemetry"], s["frames"]
    # what it missed: messages the worker (all telemetry) and frames the viewer received that it never got
    print(f"| drops, stalled client (tcp, reads nothing until the streams stop) | telemetry: got "
          f"{st['messages']:,} of {w['messages']:,}; frames: got {sf['frames']} of {v['frames']} | "
          f"only the stalled client loses "
          f"| {'yes' if not w['sock_seq_gaps'] and not v['seq_gaps'] else 'NO'} |")
    h = r["health"]
    print(f"| daemon-side drop counters | telemetry {h['telemetry']['dropped'] or 0}, frames "
          f"{h['frames']['dropped']} | – | – |")
    print(f"| daemon CPU over the run | {r['cpu_util'] * 100:.0f} % of one core | – | – |")
    step = max(1, len(r["rss"]) // 10)
    print("\nRSS samples (s: MiB): " + ", ".join(f"{t:.0f}: {m:.0f}" for t, m in r["rss"][::step]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=300.0, help="seconds under load")
    ap.add_argument("--operator", metavar="ENDPOINT", help="(internal) command round-trip client")
    ap.add_argument("--stalled", nargs=2, metavar=("TELEMETRY", "FRAMES"), help="(internal) stalled client")
    ap.add_argument("--json", type=Path, help="also write the raw results here")
    a = ap.parse_args()
    if a.operator:
        operator_main(a.operator, 0.05)
        return
    if a.stalled:
        stalled_main(*a.stalled)
        return
    if not a.duration > 0:
        ap.error(f"--duration {a.duration} must be > 0")
    r = run(a.duration)
    if a.json:
        a.json.write_text(json.dumps(r))
    report(r, a.duration)


if __name__ == "__main__":
    main()
