"""``ritactl watch``: a compact live status of the robot, not a flood of raw telemetry.

One status line: device states, the tracker's last point and lock, the robot's pose,
state and tilt, the camera's frame rate and the running job's progress. On a
terminal the line is redrawn in place; otherwise (a log file, a pipe) it is printed
once a second when it changed. Things an operator must see (warnings, prompts,
results, motion faults) are printed as lines of their own. ``--json`` prints every
message as one JSON object per line instead. ``--frames`` watches the image stream.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, TextIO

from daemon.bus.client import Client, Subscriber
from daemon.ctl.exitcodes import Exit
from daemon.bus.protocol import CommandError

NO_FRAMES = "no frames: start streaming with `ritactl camera stream start`"
_LOCK = {"MeasStatus_Ready": "locked", "MeasStatus_Busy": "locked", "MeasStatus_NotReady": "no lock"}


def _fmt(v: Any, spec: str = ".1f") -> str:
    return "?" if v is None else format(v, spec)


@dataclass
class LiveStatus:
    """The latest of everything ``watch`` shows, folded from telemetry messages."""

    devices: dict[str, str] = field(default_factory=dict)
    point: tuple[float, float, float] | None = None
    lock: str = "lock ?"
    robot: dict[str, Any] = field(default_factory=dict)
    fps: float | None = None
    job: dict[str, Any] | None = None
    latch: dict[str, Any] = field(default_factory=dict)
    link: dict[str, Any] = field(default_factory=dict)  # the last camera.link
    _frames: tuple[float, int] | None = None  # (uptime_s, frames sent) of the last health message

    def update(self, topic: str, d: dict[str, Any]) -> str | None:
        """Fold one message in; return a line to print on its own (an event), if any."""
        if topic == "daemon.health":
            self._health(d)
        elif topic == "daemon.state":
            self.devices[d["device"]] = d["state"]
            if d["state"] == "FAULT":
                return f"{d['device']} FAULT: {d.get('reason') or '?'}"
        elif topic == "tracker.point" and d.get("n"):
            self.point = (d["x"][-1], d["y"][-1], d["z"][-1])
            self.lock = "locked"
        elif topic == "tracker.event":
            return self._tracker_event(d)
        elif topic == "robot.state":
            self.robot = d
        elif topic == "robot.latch":
            self.latch = d
            owed = "; the halt is NOT yet acknowledged by the base" if d.get("halt_pending") else ""
            return (f"robot STOP LATCHED by {d.get('by')}: no motion until `ritactl robot release`{owed}"
                    if d.get("latched") else f"robot stop released by {d.get('by')}")
        elif topic == "robot.refused":
            return f"refused: {d.get('message')}"
        elif topic == "robot.event" and d.get("event") in ("FAULT", "HALTED"):
            return f"robot motion {d['event']}: {d.get('reason') or d.get('result') or d} {d.get('text', '')}"
        elif topic.startswith("calib."):
            return self._calib(topic, d)
        elif topic == "log":
            return f"{d.get('level')}: {d.get('message')}"
        elif topic == "camera.link":
            self.link = d
        return None

    def _health(self, d: dict[str, Any]) -> None:
        self.devices = {k: v["state"] for k, v in d["devices"].items()}
        self.latch = d.get("latch") or self.latch
        now = (d["uptime_s"], d["frames"]["sent"])
        if self._frames is not None and now[0] > self._frames[0]:
            self.fps = (now[1] - self._frames[1]) / (now[0] - self._frames[0])
        self._frames = now

    def _tracker_event(self, d: dict[str, Any]) -> str | None:
        if d.get("event") == "status_change" and d.get("change_name") in _LOCK:
            self.lock = _LOCK[d["change_name"]]
        elif d.get("event") in ("error", "stream_error"):
            return f"tracker: {d.get('command_name', 'stream')} {d.get('status_name')}"
        return None

    def _calib(self, topic: str, d: dict[str, Any]) -> str | None:
        job = d.get("job")
        if topic == "calib.progress":
            self.job = d
        elif topic == "calib.prompt":
            return f">>> job {job} asks: {d.get('question')} {d.get('choices')}  (ritactl answer {job} TEXT)"
        elif topic == "calib.result":
            self.job = None
            if d.get("stopped"):
                return f"job {job} STOPPED: {d.get('message')}"
            if d.get("failed"):
                return f"job {job} FAILED: {d.get('message')}"
            return f"job {job} finished: {d.get('procedure')} verdict {d.get('verdict')}"
        return None

    def line(self) -> str:
        dev = self.devices
        p = self.point
        trk = f"({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) mm" if p else "no point yet"
        r = self.robot
        tilt = ("tilt n/a" if r.get("roll_deg") is None and r.get("pitch_deg") is None
                else f"tilt {_fmt(r.get('roll_deg'), '.3f')}/{_fmt(r.get('pitch_deg'), '.3f')}°")
        rob = (f"{r.get('state', '?')} x {_fmt(r.get('x_mm'))} y {_fmt(r.get('y_mm'))} "
               f"hdg {_fmt(r.get('heading_deg'))}° {tilt}") if r else "no state yet"
        cam = f"{self.fps:.1f} fps" if self.fps is not None else "? fps"
        if self.link:  # only sent once a link counter moved: a struggling link
            cam += (f" link: {_fmt(self.link.get('incomplete_frames'), 'd')} incomplete, "
                    f"{_fmt(self.link.get('lost_packets'), 'd')} packets lost, "
                    f"{_fmt(self.link.get('resend_requests'), 'd')} resends")
        stop = " STOP LATCHED" if self.latch.get("latched") else ""
        parts = [f"tracker {dev.get('tracker', '?')} {self.lock} {trk}",
                 f"robot {dev.get('robot', '?')}{stop} {rob}",
                 f"camera {dev.get('camera', '?')} {cam}"]
        if self.job:
            j = self.job
            wait = f" ({j['waiting_for']})" if j.get("waiting_for") else ""
            parts.append(f"job {j.get('job')} {j.get('percent', 0):.0f}% {j.get('step')}{wait}")
        return " | ".join(parts)


class Screen:
    """Status line redrawn in place on a tty; one line per change (at most ``every`` s) otherwise."""

    def __init__(self, out: TextIO, tty: bool, every: float = 1.0) -> None:
        self.out, self.tty, self.every = out, tty, every
        self._shown = ""
        self._next = 0.0

    def event(self, text: str) -> None:
        self.out.write(("\r\x1b[K" if self.tty else "") + text + "\n")
        if self.tty:
            self._shown = ""  # the event overwrote the status line: draw it again below
        self.out.flush()

    def status(self, text: str, now: float) -> None:
        if text == self._shown or now < self._next:
            return
        self._next = now + (0.2 if self.tty else self.every)
        self._shown = text
        if self.tty:  # a wrapped line could not be redrawn in place: cut it to the terminal's width
            width = shutil.get_terminal_size().columns - 1
            self.out.write("\r\x1b[K" + (text if len(text) <= width else text[:max(width - 1, 0)] + "…"))
        else:
            self.out.write(text + "\n")
        self.out.flush()

    def close(self) -> None:
        if self.tty and self._shown:
            self.out.write("\n")


def _snapshot(c: Client, status: LiveStatus,
              echo: Callable[[str, dict[str, Any]], None] | None = None) -> int:
    """Seed the status from the daemon's Clone snapshot; returns its seq (drop updates up to it).

    ``echo`` gets each topic's latest message first (``--json``: the current state, then updates).
    """
    snap = c.call("state")
    for topic, m in sorted(snap.get("latest", {}).items(), key=lambda kv: kv[1].get("seq", 0)):
        status.update(topic, m["data"])
        if echo is not None:
            echo(topic, {**m, "snapshot": True})
    status.devices.update({k: v["state"] for k, v in snap["devices"].items()})
    status.latch = snap.get("latch") or status.latch
    try:  # the lock is only announced on change: ask once
        ts = c.call("tracker.status", timeout=2).get("tracker_status")
        status.lock = {"Ready": "locked", "Busy": "locked", "NotReady": "no lock"}.get(ts, status.lock)
    except CommandError:
        pass  # tracker not connected: its state says so
    return int(snap["seq"])


def _loop(sub: Subscriber, duration: float | None, on_msg: Callable[[str, dict[str, Any]], None],
          on_tick: Callable[[float], None]) -> None:
    end = float("inf") if duration is None else time.monotonic() + duration
    while (now := time.monotonic()) < end:
        msg = sub.recv(min(0.2, max(end - now, 0.0)))
        if msg is not None:
            on_msg(msg[0], msg[1])
        on_tick(time.monotonic())


def watch_status(c: Client, a: argparse.Namespace, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    sub = c.subscriber(a.topic or None)  # subscribed first, then the snapshot (Clone pattern)
    status = LiveStatus()

    def emit(topic: str, m: dict[str, Any]) -> None:
        out.write(json.dumps({"topic": topic, **m}, default=str) + "\n")
        out.flush()

    try:
        seq = _snapshot(c, status, emit if a.json else None)
        if a.json:
            _loop(sub, a.duration, lambda topic, m: emit(topic, m) if m.get("seq", 0) > seq else None,
                  lambda now: None)
            return Exit.OK
        screen = Screen(out, out.isatty())

        def on_status(topic: str, m: dict[str, Any]) -> None:
            if m.get("seq", 0) > seq and (event := status.update(topic, m["data"])):
                screen.event(event)

        screen.status(status.line(), time.monotonic())
        _loop(sub, a.duration, on_status, lambda now: screen.status(status.line(), now))
        screen.close()
        return Exit.OK
    except KeyboardInterrupt:
        return Exit.INTERRUPTED  # the documented code for Ctrl-C, even though it is how a watch ends
    finally:
        sub.close()


def _camera_hint(c: Client) -> str:
    """Why no frames come: streaming off (say how to start it) or the camera's state."""
    try:
        s = c.call("camera.status", timeout=5)
    except CommandError as exc:
        return f"no frames: the camera is not available ({exc.args[0]})"
    return "no frames yet (the camera is streaming)" if s.get("streaming") else NO_FRAMES


def frame_line(n: int, gaps: int, lat: list[float]) -> str:
    lat = sorted(lat)
    p50, p99 = lat[len(lat) // 2], lat[min(len(lat) - 1, int(len(lat) * 0.99))]
    return f"frames {n}/s  missed by this subscriber {gaps}  latency p50 {p50:.1f} ms p99 {p99:.1f} ms"


def watch_frames(c: Client, a: argparse.Namespace, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    sub = c.subscriber(frames=True, hwm=4)
    acc: dict[str, Any] = {"n": 0, "gaps": 0, "last": None, "lat": [], "tick": time.monotonic() + 1.0}

    def on_frame(_: str, h: dict[str, Any]) -> None:
        if acc["last"] is not None and h["seq"] > acc["last"] + 1:
            acc["gaps"] += h["seq"] - acc["last"] - 1
        acc["last"] = h["seq"]
        acc["n"] += 1
        acc["lat"].append((time.time_ns() - h["host_time_ns"]) / 1e6)
        if a.json:
            line = json.dumps({"topic": "camera.frame", **h, "latency_ms": acc["lat"][-1]}, default=str)
            out.write(line + "\n")

    def on_tick(now: float) -> None:
        if now < acc["tick"]:
            return
        acc["tick"] = now + 1.0
        if not a.json:
            out.write((frame_line(acc["n"], acc["gaps"], acc["lat"]) if acc["n"] else _camera_hint(c)) + "\n")
        out.flush()
        acc["n"], acc["lat"] = 0, []

    try:
        _loop(sub, a.duration, on_frame, on_tick)
    except KeyboardInterrupt:
        return Exit.INTERRUPTED
    finally:
        sub.close()
    return Exit.OK


def cmd_watch(c: Client, a: argparse.Namespace) -> int:
    return watch_frames(c, a) if a.frames else watch_status(c, a)


def add_parser(sub: Any) -> None:
    w = sub.add_parser("watch",
                       help="live status: tracker point and lock, robot pose, camera fps, job progress",
                       description="A compact live status (redrawn in place on a terminal, one line per "
                                   "change otherwise). Ctrl-C ends it. "
                                   "--json prints every message instead.")
    w.add_argument("--frames", action="store_true", help="watch the image stream: frame rate, gaps, latency")
    w.add_argument("--topic", action="append", metavar="PREFIX",
                   help="only telemetry topics starting with PREFIX (repeatable; e.g. calib.)")
    w.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    w.set_defaults(fn=cmd_watch)
