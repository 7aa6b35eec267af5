"""The approach stream's record times: the tracker's clock mapped onto the host's with its drift.

Synthetic ``tracker.point`` messages (no daemon): 1 kHz records in packets of 10, a tracker
clock 50 ppm slow with an offset, packets arriving 0-5 ms late (seeded).
"""
from __future__ import annotations

import random

import numpy as np

from daemon.worker.stream import _abs_points, _collect_until

HOST0 = 1_760_000_000_000_000_000


def _packets(seconds: float, seed: int = 1) -> tuple[list[dict], np.ndarray]:
    rng = random.Random(seed)
    msgs, truth = [], []
    for i in range(int(seconds * 100)):
        t = [(i * 10 + k + 1) * 1e-3 for k in range(10)]  # true host s of each record
        dev_us = [round(1e6 * (1000.0 + x * (1 - 50e-6))) for x in t]
        msgs.append({"n": 10, "x": [float(i * 10 + k) for k in range(10)], "y": [0.0] * 10, "z": [0.0] * 10,
                     "status": [0] * 10,
                     "device_time": [[u // 10**6 for u in dev_us], [u % 10**6 for u in dev_us]],
                     "host_time_ns": HOST0 + round((t[-1] + min(rng.expovariate(1e3), 5e-3)) * 1e9)})
        truth += [HOST0 + x * 1e9 for x in t]
    rng.shuffle(msgs)  # a subscriber may see packets in any order: the device clock orders them
    return msgs, np.array(truth)


def test_records_mapped_in_order_within_their_sigma():
    msgs, truth = _packets(20.0)
    P, t, sigma = _abs_points(msgs, np.eye(4))
    assert sigma is not None and len(sigma) == len(t) == len(truth)
    idx = P[:, 0].astype(int)  # x is the record's index: its true time
    assert np.all(np.diff(idx) == 1), "records are not in device-time order"
    err = t - truth[idx]
    assert np.percentile(np.abs(err), 99) < 0.5e6, np.percentile(np.abs(err), 99)
    assert np.mean(np.abs(err) <= 3 * sigma) >= 0.99
    # one offset (the old mapping) leaves the drift: 50 ppm over 20 s is 1 ms at the ends
    assert np.abs(err).max() < 0.2e6, np.abs(err).max()


def test_without_device_clock_records_take_their_packets_arrival():
    msgs, _ = _packets(0.1)
    for m in msgs:
        m["device_time"] = None
    P, t, sigma = _abs_points(msgs, np.eye(4))
    assert sigma is None and len(t) == 100
    assert set(t.tolist()) == {m["host_time_ns"] for m in msgs}


class _Sub:
    """A subscriber handing out the given messages in order, then nothing."""

    def __init__(self, msgs: list[dict]) -> None:
        self.msgs = list(msgs)

    def recv(self, timeout: float) -> tuple[str, dict] | None:
        return ("tracker.point", {"data": self.msgs.pop(0)}) if self.msgs else None


def test_a_late_packet_from_before_the_move_end_does_not_end_the_collection():
    # packets every 10 ms arriving up to 5 ms after their last record; the one holding records up to
    # 0.45 s is held up 150 ms on the way, so it arrives after the move's end at 0.5 s
    msgs, _ = _packets(1.0)
    msgs.sort(key=lambda m: m["device_time"][1][-1] + 10**6 * m["device_time"][0][-1])
    late = msgs[44]
    late["host_time_ns"] += 150_000_000
    before = [m for m in msgs if m["host_time_ns"] < late["host_time_ns"]]
    after = sorted((m for m in msgs if m["host_time_ns"] > late["host_time_ns"]),
                   key=lambda m: m["host_time_ns"])
    got: list[dict] = []
    _collect_until(_Sub(before + [late] + after), got, HOST0 + 500_000_000, wait_s=1.0)
    assert got[-1] is not late, "the collection ended on a packet sent before the move's end"
    _, t, _ = _abs_points(got, np.eye(4))
    assert t.max() >= HOST0 + 500_000_000


def test_incl_samples_with_a_hole_are_not_bridged():
    """A reconnect mid-move stops the base's samples for a while: the tilt is not a straight line
    across it."""
    from daemon.worker.stream import INCL_REACH_NS, _incl_tilt

    def batch(ts):
        return {"n": len(ts), "t_ns": ts, "t_sigma_ns": [1000] * len(ts), "roll_deg": [0.1] * len(ts),
                "pitch_deg": [0.2] * len(ts)}

    dense = list(range(0, 1_000_000_000, 2_000_000))
    records = np.arange(10_000_000, 990_000_000, 1_000_000)
    got = _incl_tilt([batch(dense)], records, 0, 1_000_000_000)
    assert got is not None and got[1] == len(dense)
    holed = [t for t in dense if not 300_000_000 < t < 300_000_000 + 2 * INCL_REACH_NS]
    assert _incl_tilt([batch(holed)], records, 0, 1_000_000_000) is None


def test_three_packets_per_second_are_mapped_within_their_sigma():
    """ES_SP_TcpDataPacketRate may be as low as 3/s: 333 records a packet at 1 kHz, still mapped in order."""
    from daemon.worker.stream import LAST_PACKET_WAIT_S, MIN_PACKET_RATE_HZ
    rng = random.Random(3)
    msgs, truth = [], []
    for i in range(6):  # a 2 s move at 3 packets/s
        t = [(i * 333 + k + 1) * 1e-3 for k in range(333)]
        dev_us = [round(1e6 * (1000.0 + x * (1 - 50e-6))) for x in t]
        msgs.append({"n": 333, "x": [float(i * 333 + k) for k in range(333)], "y": [0.0] * 333,
                     "z": [0.0] * 333, "status": [0] * 333,
                     "device_time": [[u // 10**6 for u in dev_us], [u % 10**6 for u in dev_us]],
                     "host_time_ns": HOST0 + round((t[-1] + min(rng.expovariate(1e3), 5e-3)) * 1e9)})
        truth += [HOST0 + x * 1e9 for x in t]
    P, t, sigma = _abs_points(msgs, np.eye(4))
    idx = P[:, 0].astype(int)
    assert sigma is not None and np.all(np.diff(idx) == 1)
    err = t - np.array(truth)[idx]
    assert np.all(np.abs(err) <= 3 * sigma) and np.abs(err).max() < 1e6
    assert LAST_PACKET_WAIT_S >= 6 / MIN_PACKET_RATE_HZ  # a held-up packet at the slowest rate still counts
