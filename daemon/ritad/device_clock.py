"""A device clock's mapping onto the host's as ritad keeps it for a device's status, and camera frame times.

The mapping itself is the bus library's (daemon/bus/clockmap.py, docs/architecture.md "Time").
This holder feeds it from the device's time-stamped telemetry, in the thread that emits it
(the adapter's reader), and hands its status to the command that reads it in another: so
both go through one lock. The tracker's stream packets feed it (each packet's last record's
device time against the host time it arrived); the robot base's sample batches
(``robot.odometry``, ``robot.incl``: every sample's ``t_us`` against the host time its line
was read) feed it and get each sample's host-timeline ``t_ns`` and ``t_sigma_ns`` back, as do
its STATUS polls with a ``t_us`` (``robot.state``); a device without a clock in its telemetry
shows a map with no samples.

Camera frames (:meth:`DeviceClock.stamp_frame`) get their exposure's mid-time on the host's
clock, ``t_ns``, with ``t_sigma_ns`` and ``t_source``. The frame's device time is taken as the
exposure's start (docs/architecture.md "Time" says why), so the exposure ends at device time
``d + exposure``; its last packet cannot arrive before that plus the payload's time on the wire,
``transfer_ns``. Every frame with a device time feeds the map with (exposure end, arrival −
transfer), whatever the source, so a camera that loses PTP falls back on a map already warm.

* ``ptp``: the camera's PTP port was ``Slave`` (locked to a master) when last polled. Its
  clock then counts PTP time, TAI: ``t = d − TAI_MINUS_UTC + exposure/2``; sigma is the offset
  from master's magnitude plus ``PTP_FLOOR_NS``. This assumes the host's clock is disciplined
  to the same master (docs/operations.md, "Camera time and PTP").
* ``clockmap``: a device time without locked PTP: the map's ``t`` of ``d + exposure/2``.
* ``host``: no device time (a camera without timestamps): arrival − transfer − exposure/2,
  sigma ``HOST_SIGMA_NS``; late by whatever latency the frame met.
"""
from __future__ import annotations

import math
import threading
from typing import Any

from daemon.bus.clockmap import TAI_MINUS_UTC_S, ClockMap
from drivers.base import Frame

#: the tracker stamps its records in µs (and the robot base its samples)
TRACKER_RESOLUTION_NS = 1000
#: the robot base's telemetry that carries its clock: sample batches, and the STATUS polls
ROBOT_CLOCKED = ("robot.odometry", "robot.incl", "robot.state")
#: PTP ports whose clock follows a master (IEEE 1588 port states; LUCID's PtpStatus names)
PTP_LOCKED = frozenset({"Slave"})
#: what a locked PTP port is known to, beyond its offset from master: the host's own servo to the
#: same master and the timestamp's latching (docs/operations.md, "Camera time and PTP")
PTP_FLOOR_NS = 1000
#: a frame timed by its arrival: the latency left after the transfer is unknown (the map's prior)
HOST_SIGMA_NS = 5_000_000
TAI_MINUS_UTC_NS = TAI_MINUS_UTC_S * 1_000_000_000
#: PTP's mapping and the clock map's disagreeing by more than this (the map sits above by the
#: frames' least latency beyond their transfer, ms) means the host is not on the camera's PTP time
PTP_MAP_DISAGREE_NS = 500_000_000


def ptp_locked(ptp: dict[str, Any] | None) -> bool:
    """Whether a camera's PTP state (``ptp`` of its status) says its clock is on the master's time."""
    return bool(ptp and ptp.get("enabled") and not ptp.get("error") and ptp.get("status") in PTP_LOCKED)


def _fallback_note(ptp: dict[str, Any] | None) -> str | None:
    if not ptp or not ptp.get("enabled") or ptp_locked(ptp):
        return None
    if ptp.get("error"):
        return f"PTP state unreadable ({ptp['error']}); frames are timed by the clock map"
    return f"PTP enabled but {ptp.get('status')}, not locked to a master; frames are timed by the clock map"


class DeviceClock:
    """A :class:`ClockMap` shared between the emitting thread and the status reader."""

    def __init__(self, resolution_ns: float = TRACKER_RESOLUTION_NS) -> None:
        self._map = ClockMap(resolution_ns=resolution_ns)
        self._lock = threading.Lock()
        self._source: str | None = None  # of the newest frame; None: the map's (tracker) or no frame yet
        self._ptp: dict[str, Any] | None = None
        self._sigma_ns: int | None = None

    def observe_tracker_packet(self, payload: Any) -> None:
        """A ``tracker.point`` packet; one without device time (or malformed) adds nothing."""
        times = _device_times(payload)
        if not times:
            return
        try:
            host_ns = int(payload["host_time_ns"])
        except (TypeError, KeyError, ValueError, OverflowError):
            return
        with self._lock:
            self._add(times[-1], host_ns)

    def observe_robot(self, topic: str, payload: Any) -> Any:
        """The robot base's telemetry of ``topic`` (one of ROBOT_CLOCKED) fed to the map; it comes back
        with the host-timeline ``t_ns`` and ``t_sigma_ns`` of each sample (a batch
        ``{t_us: [...], host_time_ns: [...], ...}``: lists; a ``robot.state``, a STATUS poll with the
        base's ``t_us``: one each). A malformed payload adds nothing and is returned unchanged."""
        batch = topic != "robot.state"
        try:
            t_us, host = (payload["t_us"], payload["host_time_ns"]) if batch else \
                ([payload["t_us"]], [payload["host_time_ns"]])
            device_ns, host_ns = [int(t) * 1000 for t in t_us], [int(h) for h in host]
        except (TypeError, KeyError, ValueError, OverflowError):
            return payload
        if not device_ns or len(device_ns) != len(host_ns):
            return payload
        with self._lock:
            try:
                for d, h in sorted(zip(device_ns, host_ns)):  # in the device's order
                    self._map.add(d, h)
                t, sigma = self._map.map_many(device_ns)
            except (ValueError, OverflowError):  # a sample the map cannot take must not stop the publishing
                return payload
        return ({**payload, "t_ns": t, "t_sigma_ns": sigma} if batch
                else {**payload, "t_ns": t[0], "t_sigma_ns": sigma[0]})

    def _add(self, device_ns: int, host_ns: int) -> bool:
        try:
            self._map.add(device_ns, host_ns)
            return True
        except (ValueError, OverflowError):  # a sample the map cannot take must not stop the publishing
            return False

    def stamp_frame(self, frame: Frame) -> Frame:
        """Set the frame's ``t_ns``, ``t_sigma_ns`` and ``t_source`` (module docstring); returns it."""
        exposure_us = frame.exposure_us if frame.exposure_us and math.isfinite(frame.exposure_us) else 0.0
        exposure_ns = int(round(exposure_us * 1000.0))  # a NaN chunk value must not stop the frame
        arrived = int(frame.host_time_ns) - max(0, int(frame.transfer_ns))
        d = frame.device_time_ns
        with self._lock:
            if d is None:
                t, sigma, source = arrived - exposure_ns // 2, HOST_SIGMA_NS, "host"
            elif ptp_locked(frame.ptp):
                self._add(d + exposure_ns, arrived)
                offset = (frame.ptp or {}).get("offset_from_master_ns")
                t, source = d - TAI_MINUS_UTC_NS + exposure_ns // 2, "ptp"
                sigma = abs(int(offset or 0)) + PTP_FLOOR_NS
            elif self._add(d + exposure_ns, arrived):
                (t, sigma), source = self._map.map(d + exposure_ns // 2), "clockmap"
            else:
                t, sigma, source = arrived - exposure_ns // 2, HOST_SIGMA_NS, "host"
            self._source, self._ptp, self._sigma_ns = source, frame.ptp, sigma
        frame.t_ns, frame.t_sigma_ns, frame.t_source = t, sigma, source
        return frame

    def map_packet(self, payload: Any) -> list[tuple[int, int]] | None:
        """Each record of a ``tracker.point`` packet on the host's timeline: (t_ns, t_sigma_ns);
        None without device times or before the map has a sample."""
        times = _device_times(payload)
        if not times:
            return None
        with self._lock:
            try:
                return [self._map.map(d) for d in times]
            except (ValueError, OverflowError):
                return None

    def status(self) -> dict[str, Any]:
        """``source`` and the mapping's offset, drift, sigma, samples and window (ClockMap.status);
        for a camera also ``ptp`` (its state at the newest frame) and ``note`` (why PTP is not used)."""
        with self._lock:
            st = self._map.status()
            if self._source is None:  # the tracker's, or a camera before its first frame
                return {"source": "clockmap" if st["samples"] else None, **st}
            out = {"source": self._source, **st, "ptp": self._ptp, "note": _fallback_note(self._ptp)}
            if self._source == "ptp":
                out.update(offset_ns=-TAI_MINUS_UTC_NS, drift_ppm=0.0, sigma_ns=self._sigma_ns,
                           clockmap={k: st[k] for k in ("offset_ns", "drift_ppm", "sigma_ns")})
                gap_ns = None if st["offset_ns"] is None else st["offset_ns"] + TAI_MINUS_UTC_NS
                if gap_ns is not None and abs(gap_ns) > PTP_MAP_DISAGREE_NS:
                    out["note"] = (f"PTP time and the clock map disagree by {gap_ns / 1e9:+.3f} s: is the "
                                   "host's clock on the camera's PTP master? (docs/operations.md)")
            elif self._source == "host":
                out.update(sigma_ns=self._sigma_ns,
                           note="the camera gives no device time; frames are timed by their arrival")
            return out


def _device_times(payload: Any) -> list[int] | None:
    """A packet's records' device times (ns; the tracker stamps s + µs), None when it has none."""
    dt = payload.get("device_time") if isinstance(payload, dict) else None
    try:
        return [int(s) * 1_000_000_000 + int(us) * 1000
                for s, us in zip(dt[0], dt[1], strict=True)]  # type: ignore[index]
    except (TypeError, IndexError, KeyError, ValueError, OverflowError):
        return None
