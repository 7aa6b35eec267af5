"""Tracker results through the daemon: records/s to a subscriber process, and losses at 1 kHz.

Goals: ≥ 20,000 continuous records decoded and published per second
through ritad to a subscriber in another process; 0 results lost at 1 kHz over 60 s.

Method: ritad runs with a simulated world whose tracker fake lives in the daemon
process (it is a real emScon TCP peer on 127.0.0.1). For throughput the fake floods
MultiMeasResult packets of ``--batch`` records back to back (URL option
``flood_batch``); at 1 kHz it streams in real time at ``--packet-rate`` packets/s (the driver's
``packet_rate``: ES_SP_TcpDataPacketRate, 3-10, which the fake honours). The
subscriber process checks the record ``seq`` (adapter count) and the device times
(1 ms apart, set by the fake) for gaps, so a record lost anywhere between the fake
and the subscriber shows up.

Run: ``.venv/bin/python bench/bench_tracker_daemon.py [--seconds 10] [--loss-seconds 60]``.
Also ``--sub ENDPOINT`` runs the subscriber side (used by this and bench_load.py).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import finish, machine, pct, ritad_toml, serve_subscriber, spawn, start_ritad  # noqa: E402
from daemon.bus.client import Client  # noqa: E402

# --------------------------------------------------------------------------- subscriber process


class TelemetryStats:
    """Counts what a telemetry subscriber sees: socket seq gaps, tracker record gaps, latency."""

    def __init__(self, dt_us: int = 1000) -> None:
        self.dt_us = dt_us
        self.messages = 0
        self.topics: dict[str, int] = {}
        self.sock_seq_prev: int | None = None
        self.sock_seq_gaps = 0  # telemetry messages missed (all topics) between first and last
        self.records = 0
        self.rec_seq_first: int | None = None
        self.rec_seq_next: int | None = None
        self.rec_seq_missing = 0
        self.dev_prev_us: int | None = None
        self.dev_missing = 0  # records missing by device time (1 ms grid of the fake)
        self.first_rx = self.last_rx = 0.0
        self.first_rec_rx = self.last_rec_rx = 0.0
        self.latency_ms: list[float] = []

    def add(self, topic: str, msg: dict[str, Any], rx_ns: int) -> None:
        now = rx_ns / 1e9
        self.messages += 1
        self.topics[topic] = self.topics.get(topic, 0) + 1
        self.first_rx = self.first_rx or now
        self.last_rx = now
        seq = msg.get("seq")
        if self.sock_seq_prev is not None and isinstance(seq, int) and seq > self.sock_seq_prev + 1:
            self.sock_seq_gaps += seq - self.sock_seq_prev - 1
        if isinstance(seq, int):
            self.sock_seq_prev = seq
        if topic == "tracker.point":
            self._point(msg["data"], now, rx_ns)

    def _point(self, d: dict[str, Any], now: float, rx_ns: int) -> None:
        n = int(d["n"])
        self.records += n
        self.first_rec_rx = self.first_rec_rx or now
        self.last_rec_rx = now
        if self.rec_seq_first is None:
            self.rec_seq_first = d["seq"]
        elif d["seq"] != self.rec_seq_next:
            self.rec_seq_missing += d["seq"] - self.rec_seq_next
        self.rec_seq_next = d["seq"] + n
        if len(self.latency_ms) < 200_000:
            self.latency_ms.append((rx_ns - d["host_monotonic_ns"]) / 1e6)
        if d.get("device_time") is None:  # a stationary measurement (tracker.measure), not streamed
            return
        t1, t2 = d["device_time"]
        for a, b in zip(t1, t2, strict=True):
            us = a * 1_000_000 + b
            if self.dev_prev_us is not None:
                step = round((us - self.dev_prev_us) / self.dt_us)
                if step > 1:
                    self.dev_missing += step - 1
            self.dev_prev_us = us

    def result(self) -> dict[str, Any]:
        span = self.last_rec_rx - self.first_rec_rx
        lat = self.latency_ms
        return {"messages": self.messages, "topics": self.topics, "sock_seq_gaps": self.sock_seq_gaps,
                "records": self.records, "rec_seq_first": self.rec_seq_first,
                "rec_seq_end": self.rec_seq_next,
                "rec_seq_missing": self.rec_seq_missing, "dev_missing": self.dev_missing,
                "record_span_s": span, "records_per_s": (self.records / span) if span > 0 else 0.0,
                "latency_p50_ms": pct(lat, 50), "latency_p99_ms": pct(lat, 99)}


def subscriber_main(endpoint: str, topics: list[str], hwm: int, stalled: bool, linger_s: float) -> None:
    """Subscribe, print ``subscribed``, count until stdin closes (plus ``linger_s``), print JSON."""
    from daemon.bus.client import Subscriber
    from daemon.bus.protocol import unpack

    stats = TelemetryStats()
    serve_subscriber(Subscriber(endpoint, topics or None, hwm=hwm),
                     lambda f, rx: stats.add(f[0].bytes.decode(), unpack(f[1].buffer), rx), stats.result,
                     stalled, linger_s)


# --------------------------------------------------------------------------- daemon side


def lock_and_stream(c: Client, rate_hz: float = 1000.0) -> None:
    from fakes.operator import lock_on_robot

    lock_on_robot(c)
    c.call("tracker.stream.start", timeout=30, rate_hz=rate_hz)


def run(tracker_url: str, seconds: float, camera_url: str = "sim:?size=40x30") -> dict[str, Any]:
    """One daemon, one tracker subscriber process, streaming at 1 kHz for ``seconds``."""
    r = start_ritad(ritad_toml(devices={"tracker": tracker_url, "camera": camera_url}))
    ep = r.endpoint
    try:
        with Client(ep, timeout=10) as c:
            c.wait_ready(("tracker",), 180)
            tel = c.hello()["telemetry_endpoints"][0]
            sub = spawn("bench_tracker_daemon.py", "--sub", tel, "--topic", "tracker.point")
            lock_and_stream(c)
            time.sleep(seconds)
            c.call("tracker.stream.stop", timeout=30)
            time.sleep(1.0)
            st = c.call("tracker.status", timeout=30)
            health = c.call("status")
            res = finish(sub)
        res["adapter_points"] = st["counters"]["points"]
        res["telemetry_dropped"] = health["telemetry"]["dropped"].get("tracker.point", 0)
        return res
    finally:
        r.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="flood run length")
    ap.add_argument("--batch", type=int, nargs="+", default=[100, 1000],
                    help="records per packet in the flood runs (one run each)")
    ap.add_argument("--loss-seconds", type=float, default=60.0, help="1 kHz run length")
    ap.add_argument("--packet-rate", type=int, default=10, help="packets/s at 1 kHz (3-10, as the AT901)")
    ap.add_argument("--sub", metavar="ENDPOINT", help="(internal) run as subscriber")
    ap.add_argument("--topic", action="append", default=[])
    ap.add_argument("--hwm", type=int, default=0)
    ap.add_argument("--stalled", action="store_true")
    a = ap.parse_args()
    if a.sub:
        subscriber_main(a.sub, a.topic, a.hwm, a.stalled, linger_s=1.0)
        return
    if any(b <= 0 for b in a.batch) or not (a.seconds > 0 and a.loss_seconds > 0):
        ap.error(f"--batch {a.batch}, --seconds {a.seconds}, --loss-seconds {a.loss_seconds} must all be > 0")
    floods = {b: run(f"sim:?flood_batch={b}&sigma_mm=0.01", a.seconds) for b in a.batch}
    rt = run(f"sim:?packet_rate={a.packet_rate}&sigma_mm=0.01", a.loss_seconds)
    # records the adapter decoded before the subscriber's first one, in gaps, or after its last one
    lost = ((rt["rec_seq_first"] or 0) + rt["rec_seq_missing"] + rt["dev_missing"]
            + max(0, rt["adapter_points"] - rt["records"]))
    print(f"# bench_tracker_daemon\n\nMachine: {machine()}\n")
    print("| metric | value | goal | met |\n|---|---|---|---|")
    for b, flood in floods.items():
        ok = flood["records_per_s"] >= 20000
        print(f"| records/s fake → ritad → subscriber process (ipc), {b} rec/packet, "
              f"{flood['record_span_s']:.1f} s | {flood['records_per_s']:,.0f} "
              f"({flood['records']:,} records; lost {flood['rec_seq_missing'] + flood['dev_missing']:,}, "
              f"publisher dropped {flood['telemetry_dropped']} msgs) | ≥ 20,000 | {'yes' if ok else 'NO'} |")
    print(f"| results lost at 1 kHz over {rt['record_span_s']:.0f} s ({a.packet_rate} packets/s) | "
          f"{lost} of {rt['adapter_points']:,} decoded (subscriber got {rt['records']:,}; seq gaps "
          f"{rt['rec_seq_missing']}, device-time gaps {rt['dev_missing']}) "
          f"| 0 | {'yes' if lost == 0 else 'NO'} |")
    print(f"| latency decode → subscriber at 1 kHz | p50 {rt['latency_p50_ms']:.2f} ms, "
          f"p99 {rt['latency_p99_ms']:.2f} ms | – | – |")


if __name__ == "__main__":
    main()
