"""The tracker's stream (and the inclinometer) along the final straight move of an approach:
the inputs of the tilt and heading-fit compensations (docs/accuracy.md).

The heading-fit compensation (calibration/compensation.py ``fit_heading``) needs the
reflector's path between the two standstill points; the tilt compensation wants the
tilt along it. The move is started without waiting, and the tracker's ``tracker.point``
telemetry is collected on a subscriber. The records' times: the tracker's ``device_time``
(s + µs) per record, put on the host clock by a clock map (daemon/bus/clockmap.py) of the
packets: each packet's last record's device time against its arrival ``host_time_ns``; its
offset, drift and sigma come from the least-delayed packets.

The tilt along the move: from a base that streams its inclinometer (protocol 2, ``robot.incl``
in ``robot.status``'s ``streams``), the ``robot.incl`` samples, subscribed before the move and
already on the host's timeline (ritad maps the base's clock), interpolated to each record's
host time (daemon/bus/timeline.py); from any other base, ``robot.status`` polled while the
move runs (samples with the daemon's host time), as a version-1 base allows. The stop
record's ``tilt_source`` says which.
"""
from __future__ import annotations

import time
from typing import Any, Iterator

import numpy as np

from daemon.bus.client import Subscriber
from daemon.bus.clockmap import ClockMap
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.timeline import TimeSeries
from daemon.worker.job import JobContext
from daemon.worker.motion import confirm_done

#: the most points a stop record keeps (evenly thinned)
MAX_STREAM_POINTS = 200
#: tilt samples during the move below which none are stored: a few single readings, interpolated,
#: are worse than the two standstill means (compute then interpolates those along the move)
MIN_TILT_SAMPLES = 5
#: a subscriber needs a moment to be connected before the first message it should see
SUB_SETTLE_S = 0.02
#: the fewest stream packets per second a tracker sends: ES_SP_TcpDataPacketRate is 3-10 (Leica's
#: ES_C_API_Def.h); the driver asks for 10, a server without the parameter keeps its own
MIN_PACKET_RATE_HZ = 3.0
#: the clock map's bins: at most one packet each at any packet rate; the tracker stamps in µs
CLOCK_BIN_S = 0.01
DEVICE_RESOLUTION_NS = 1000
#: how long to wait after the move for the stream packet that covers its end: several packet periods at
#: the slowest rate, so a packet held up on a busy host still counts
LAST_PACKET_WAIT_S = max(2.0, 6.0 / MIN_PACKET_RATE_HZ)
#: how far past the inclinometer's first or last sample a record may take that sample's tilt (ns):
#: a record at most one output period (0.1 s at 10 Hz) away from the samples
INCL_REACH_NS = 150_000_000
#: the tilt's sources in the stop record (``tilt_source``)
TILT_FROM_INCL, TILT_FROM_STATUS = "robot.incl", "robot.status"


def _device_ns(msg: dict[str, Any]) -> np.ndarray | None:
    """Device time (ns) of each record of one tracker.point message, or None without one."""
    n, dt = int(msg["n"]), msg.get("device_time")
    if not dt or len(dt) != 2 or len(dt[0]) != n:
        return None
    return np.asarray(dt[0], dtype=np.int64) * 1_000_000_000 + np.asarray(dt[1], dtype=np.int64) * 1000


def _host_times(msgs: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray | None]:
    """Each record's host time (ns) and its sigma (ns; None without a device clock).

    The tracker's clock is mapped onto the host's by a clock map of the packets (each
    packet's last record's device time against its arrival), so records are ordered and timed
    by the tracker's clock with its drift corrected (arrival jitter would otherwise interleave
    records of two packets). Without a device clock in every packet, each packet's records are
    put at its arrival, with no sigma.
    """
    clocks = [_device_ns(m) for m in msgs]
    devs = [d for d in clocks if d is not None]
    if len(devs) < len(clocks):
        per_message = [np.full(int(m["n"]), int(m["host_time_ns"]), dtype=np.int64) for m in msgs]
        return np.concatenate(per_message), None
    cm = ClockMap(bin_s=CLOCK_BIN_S, resolution_ns=DEVICE_RESOLUTION_NS)
    for last, rx in sorted((int(d[-1]), int(m["host_time_ns"])) for m, d in zip(msgs, devs)):
        cm.add(last, rx)  # in the device's order: a clock going back would read as a restart
    t, s = cm.map_many([int(x) for x in np.concatenate(devs)])
    return np.asarray(t, dtype=np.int64), np.asarray(s, dtype=np.int64)


def _abs_points(msgs: list[dict[str, Any]], abs_H_trk: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(N, 3) ACS points in time order, their host times (ns) and those times' sigma (ns, None
    without a device clock), good records only."""
    if not msgs:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), None
    t, sigma = _host_times(msgs)
    P = np.concatenate([np.column_stack([m["x"], m["y"], m["z"]]).astype(float) for m in msgs])
    ok = np.concatenate([np.asarray(m.get("status") or [0] * int(m["n"])) == 0 for m in msgs])
    P, t = P[ok], t[ok]
    order = np.argsort(t, kind="stable")
    sigma = None if sigma is None else sigma[ok][order]
    return P[order] @ abs_H_trk[:3, :3].T + abs_H_trk[:3, 3], t[order], sigma


def _datas(sub: Subscriber, wait_s: float) -> Iterator[dict[str, Any]]:
    """The ``data`` of each message ``sub`` receives within ``wait_s`` s."""
    end = time.monotonic() + wait_s
    while time.monotonic() < end:
        got = sub.recv(timeout=min(0.1, max(0.0, end - time.monotonic())))
        data = got[1].get("data") if got is not None and isinstance(got[1], dict) else None
        if isinstance(data, dict):
            yield data


def _collect_until(sub: Subscriber, msgs: list[dict[str, Any]], t_end_ns: int, wait_s: float) -> None:
    """Read tracker.point messages (their ``data``) until one holds a record after ``t_end_ns``.

    A packet's arrival after ``t_end_ns`` is not enough: one sent before the move ended and held
    up on the way (a busy host) arrives late too. Its records' own times, on the host clock
    through the clock map, must reach ``t_end_ns``.
    """
    for data in _datas(sub, wait_s):
        if data.get("n"):
            msgs.append(data)
            if int(data["host_time_ns"]) >= t_end_ns and int(_host_times(msgs)[0].max()) >= t_end_ns:
                return


def _collect_incl(sub: Subscriber, t_end_ns: int, wait_s: float) -> list[dict[str, Any]]:
    """The ``robot.incl`` batches read until one holds a sample at or after ``t_end_ns`` (host timeline)."""
    msgs: list[dict[str, Any]] = []
    for data in _datas(sub, wait_s):
        if data.get("n") and data.get("t_ns"):
            msgs.append(data)
            if max(data["t_ns"]) >= t_end_ns:
                break
    return msgs


def _incl_tilt(msgs: list[dict[str, Any]], t: np.ndarray, t0: int, t1: int
               ) -> tuple[list[list[float]], int] | None:
    """The inclinometer's samples interpolated to the record times ``t`` (host ns): (n × 2 roll,
    pitch; the samples within the move [t0, t1]); None when they do not cover every record, or leave
    a hole longer than ``INCL_REACH_NS`` around one."""
    series = TimeSeries(TILT_FROM_INCL, ("roll_deg", "pitch_deg"))
    for m in msgs:
        for tn, r, p, s in zip(m["t_ns"], m["roll_deg"], m["pitch_deg"], m["t_sigma_ns"]):
            series.add(int(tn), (r, p), int(s))
    try:
        found = [series.at(int(x), reach_ns=INCL_REACH_NS) for x in t]
    except LookupError:
        return None
    if any(a.gap_ns > INCL_REACH_NS for a in found):  # a hole in the samples (a reconnect, lost batches)
        return None  # is not bridged by a straight line: the polled readings are used instead
    at = [a.values for a in found]
    during = sum(1 for m in msgs for tn in m["t_ns"] if t0 <= tn <= t1)
    return [[a["roll_deg"], a["pitch_deg"]] for a in at], during


def _status_tilt(tilt: list[tuple[int, float, float]], t: np.ndarray, t0: int,
                 start_tilt: dict[str, Any] | None) -> list[list[float]]:
    """robot.status readings polled during the move interpolated to the record times, anchored at
    ``start_tilt`` (the standstill reading before it) at the move's start."""
    if start_tilt:
        tilt.insert(0, (t0, float(start_tilt["roll_deg"]), float(start_tilt["pitch_deg"])))
    ts = np.array([s[0] for s in tilt], dtype=float)
    return np.column_stack([np.interp(t, ts, [s[1] for s in tilt]),
                            np.interp(t, ts, [s[2] for s in tilt])]).tolist()


def _thin(n: int, most: int) -> np.ndarray:
    return np.arange(n) if n <= most else np.unique(np.linspace(0, n - 1, most).round().astype(int))


def _done_event(sub: Subscriber, wait_s: float) -> dict[str, Any] | None:
    """The move's DONE event (its ``result`` says whether the base executed all of it), or None."""
    return next((data for data in _datas(sub, wait_s) if data.get("event") == "DONE"), None)


def _drive_polling_tilt(ctx: JobContext, distance_mm: float, speed_mm_s: float, timeout_s: float
                        ) -> tuple[list[tuple[int, float, float]], dict[str, Any]]:
    """Start the move, poll robot.status until the base is idle: the tilt samples (host ns, roll, pitch)
    and the last status (the odometry where the move ended)."""
    ctx.call("robot.move", timeout=60, distance_mm=distance_mm, speed_mm_s=speed_mm_s, confirm=True,
             wait=False)
    samples: list[tuple[int, float, float]] = []
    end = time.monotonic() + timeout_s
    while True:
        st = ctx.call("robot.status", timeout=30)
        if st.get("roll_deg") is not None and st.get("pitch_deg") is not None:
            samples.append((int(st["host_time_ns"]), float(st["roll_deg"]), float(st["pitch_deg"])))
        if st.get("state") == "FAULT":
            raise CommandError(ErrorCode.DEVICE_ERROR, f"robot FAULT during the approach: {st.get('fault')}")
        if st.get("state") == "IDLE":
            return samples, st
        if time.monotonic() > end:
            raise CommandError(ErrorCode.TIMEOUT,
                               f"robot still moving {timeout_s:.0f} s after the approach started")


def _status_before(ctx: JobContext) -> tuple[dict[str, Any] | None, list[str]]:
    """The odometry before the move (how far it went, if cut short) and the base's streams."""
    try:
        start = ctx.call("robot.status", timeout=30)
        return start, start.get("streams") or []
    except CommandError:  # not knowing the base's streams only means polling its status for the tilt
        return None, []


def record_move(ctx: JobContext, distance_mm: float, speed_mm_s: float, abs_H_trk: Any,
                rate_hz: float | None, start_tilt: dict[str, Any] | None = None
                ) -> tuple[dict[str, Any] | None, str]:
    """Drive ``distance_mm`` straight while recording the stream: (the stop record's ``stream``, "").

    When the stream cannot start, nothing has moved yet: (None, why), and the caller drives
    without it.

    ``start_tilt`` (the standstill reading before the move) anchors the tilt before the
    first sample taken while moving; without it the points at the start would get a
    mid-move tilt.
    """
    start, streams = _status_before(ctx)
    sub = ctx.client.subscriber(["tracker.point"])
    esub = ctx.client.subscriber(["robot.event"])  # the move's DONE: was all of it executed?
    isub = ctx.client.subscriber([TILT_FROM_INCL]) if TILT_FROM_INCL in streams else None
    incl: list[dict[str, Any]] = []
    try:
        time.sleep(SUB_SETTLE_S)
        try:
            rate = {} if rate_hz is None else {"rate_hz": rate_hz}
            started = ctx.call("tracker.stream.start", timeout=30, **rate)
        except CommandError as exc:  # the stream only serves heading_fit: the approach goes on without it
            return None, f"the tracker's stream did not start ({exc.args[0]})"
        t0 = time.time_ns()
        msgs: list[dict[str, Any]] = []
        with ctx.afterwards("tracker.stream.stop"):  # also after a STOP, which stays the outcome
            tilt, last = _drive_polling_tilt(ctx, distance_mm, speed_mm_s,
                                             60.0 + 2 * abs(distance_mm) / speed_mm_s)
            t1 = time.time_ns()
            done = _done_event(esub, LAST_PACKET_WAIT_S)
            _collect_until(sub, msgs, t1, LAST_PACKET_WAIT_S)  # the packet holding the move's end
            if isub is not None:
                incl = _collect_incl(isub, t1, LAST_PACKET_WAIT_S)
    finally:
        sub.close()
        esub.close()
        if isub is not None:
            isub.close()
    # cut short, it is not the approach's final move
    confirm_done(ctx, "move", distance_mm, start, done, last)
    P, t, sigma = _abs_points(msgs, np.asarray(abs_H_trk, float))
    keep = np.flatnonzero((t >= t0) & (t <= t1))
    idx = keep[_thin(len(keep), MAX_STREAM_POINTS)]
    P, t = P[idx], t[idx]
    out: dict[str, Any] = {"rate_hz": started.get("rate_hz", rate_hz), "n": len(P), "abs_xyz": P.tolist(),
                           "host_time_ns": t.tolist(), "tilt_samples": len(tilt)}
    if sigma is not None:
        out["t_sigma_ns"] = sigma[idx].tolist()
    from_incl = _incl_tilt(incl, t, t0, t1) if incl and len(P) else None
    if from_incl is not None and from_incl[1] >= MIN_TILT_SAMPLES:
        out.update(tilt_deg=from_incl[0], tilt_samples=from_incl[1], tilt_source=TILT_FROM_INCL)
    elif len(tilt) >= MIN_TILT_SAMPLES and len(P):
        out.update(tilt_deg=_status_tilt(tilt, t, t0, start_tilt), tilt_source=TILT_FROM_STATUS)
    return out, ""
