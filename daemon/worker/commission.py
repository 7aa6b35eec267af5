"""``ritactl commission``'s run: the raw evidence of every device assumption the docs call unverified.

Each device's part is one step (a resume skips what is stored) that gathers what the devices say and do
over the bus: the tracker's read-back state and a stream of its records, the camera's status before and
after a stream of frames and a few software-triggered captures, the base's answers to the conformance
kit's checks (run by ritad on its own port: ``robot.commission``). The verdicts are the computation's
(daemon/compute/commission.py), from these stored observations only, so ``ritactl recompute`` judges a
stored run again. A device that is not READY, or that fails mid-way, is recorded with the reason and the
other devices are still checked.
"""
from __future__ import annotations

import time
from typing import Any, Callable

from daemon.bus.client import Subscriber
from daemon.bus.protocol import CommandError
from daemon.worker.job import JobContext, Stopped

#: a subscriber needs a moment to be connected before the first message it should see
SUB_SETTLE_S = 0.05
#: software-triggered captures timed against the camera's stamp (the latch check), this far apart (s): the
#: unit check compares the stamps' advance with the host's over their span
CAPTURES, CAPTURE_GAP_S = 5, 0.25
#: the devices a run may check, in the order they are checked; the base's motion comes last
DEVICES = ("tracker", "camera", "base")
#: the base's device name in ritad
RITAD_NAME = {"tracker": "tracker", "camera": "camera", "base": "robot"}


def wanted_devices(text: str) -> tuple[str, ...]:
    """``all`` or a comma list of DEVICES; anything else is a ValueError naming it."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    if names == ["all"]:
        return DEVICES
    bad = [n for n in names if n not in DEVICES]
    if bad or not names:
        raise ValueError(f"devices {text!r}: give all or a comma list of {', '.join(DEVICES)}")
    return tuple(d for d in DEVICES if d in names)


def _records(sub: Subscriber, seconds: float) -> list[dict[str, Any]]:
    """The tracker.point packets read for ``seconds``: arrival (host ns), each record's device time (µs)."""
    out: list[dict[str, Any]] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        got = sub.recv(timeout=min(0.1, max(0.0, end - time.monotonic())))
        data = got[1].get("data") if got and isinstance(got[1], dict) else None
        if not (isinstance(data, dict) and data.get("n")):
            continue
        dt = data.get("device_time")
        device_us = [int(s) * 1_000_000 + int(u) for s, u in zip(*dt)] if dt and len(dt) == 2 else None
        out.append({"host_time_ns": int(data["host_time_ns"]), "n": int(data["n"]), "device_us": device_us})
    return out


def _lock(ctx: JobContext, status: dict[str, Any]) -> None:
    """The tracker locked onto a reflector: aim and find at the given position, else the operator locks it."""
    if status.get("tracker_status") == "Ready":
        return
    approx = ctx.params.reflector_approx_trk
    if approx is not None:
        ctx.call("tracker.aim", timeout=60, x=approx[0], y=approx[1], z=approx[2])
        ctx.call("tracker.find", timeout=60)
        return
    ctx.ask("the tracker has no reflector locked: lock it onto the robot's reflector (or any one in view), "
            "then answer 'ok'", ["ok"])


def tracker_obs(ctx: JobContext) -> dict[str, Any]:
    """Read-back state, then ``duration_s`` of the stream at the asked rate, then the clock map's figures."""
    _lock(ctx, ctx.call("tracker.status"))
    readback = ctx.call("tracker.readback")
    sub = ctx.client.subscriber(["tracker.point"])
    try:
        time.sleep(SUB_SETTLE_S)
        # the reply says the rate streamed: above the tracker's max_data_rate it is clamped (docs/emscon.md)
        rate = ctx.call("tracker.stream.start", rate_hz=ctx.params.tracker_rate_hz)["rate_hz"]
        with ctx.afterwards("tracker.stream.stop"):
            packets = _records(sub, ctx.params.duration_s)
    finally:
        sub.close()
    status = ctx.call("tracker.status")
    return {"readback": readback, "rate_hz": float(rate), "duration_s": ctx.params.duration_s,
            "packets": packets, "clock": status.get("clock"), "counters": status.get("counters"),
            "stream_interrupted": status.get("stream_interrupted")}


def _capture(ctx: JobContext) -> dict[str, Any]:
    """One software-triggered frame's header, with the host's clock read just before the call and after it."""
    before = time.time_ns()
    header = ctx.call("camera.capture", timeout=60, pixels=False, save=False)["header"]
    return {"call_ns": before, "reply_ns": time.time_ns(),
            **{k: header.get(k) for k in ("device_time_ns", "exposure_us", "t_ns", "t_source", "host_time_ns",
                                           "pixel_format", "incomplete_count")}}


def camera_obs(ctx: JobContext) -> dict[str, Any]:
    """Status, ``duration_s`` of free-running frames, status again; then a few captures timed by the host."""
    before = ctx.call("camera.status")
    ctx.call("camera.stream.start")
    with ctx.afterwards("camera.stream.stop"):
        time.sleep(ctx.params.duration_s)
    after = ctx.call("camera.status")
    captures = []
    for _ in range(CAPTURES):
        captures.append(_capture(ctx))
        time.sleep(CAPTURE_GAP_S)
    return {"status_before": before, "status_after": after, "duration_s": ctx.params.duration_s,
            "captures": captures, "status_end": ctx.call("camera.status")}


def base_obs(ctx: JobContext) -> dict[str, Any]:
    """The conformance kit's checks of the clock, the round trip and (allowed) the watchdog and braking, run
    by ritad on its port; the base's clock as ritad mapped it since it connected."""
    result = ctx.call("robot.commission", timeout=120 + 2 * ctx.params.duration_s,
                      allow_motion=ctx.params.allow_motion, clock_s=ctx.params.duration_s,
                      confirm=ctx.params.allow_motion)
    status = ctx.call("robot.status")
    return {**result, "clock": status.get("clock")}


#: what each device's step waits for, as the progress line says it
WAITING = {"tracker": "the tracker's stream ({s:g} s)", "camera": "the camera's frames ({s:g} s), 5 captures",
           "base": "the base's checks on its port (its clock {s:g} s)"}
OBSERVE: dict[str, Callable[[JobContext], dict[str, Any]]] = {
    "tracker": tracker_obs, "camera": camera_obs, "base": base_obs}


def run_commission(ctx: JobContext) -> None:
    """Every wanted device in turn; a device that is not READY, or refuses, is recorded with the reason."""
    wanted = wanted_devices(ctx.params.devices)
    ctx.obs.setdefault("devices", list(wanted))
    ctx.obs.setdefault("allow_motion", bool(ctx.params.allow_motion))
    for i, name in enumerate(wanted):
        if ctx.done(name):
            continue
        waiting = WAITING[name].format(s=ctx.params.duration_s)
        ctx.progress(f"check the {name}", 5 + 85 * i / len(wanted), waiting)
        health = ctx.call("status")["devices"].get(RITAD_NAME[name], {})
        obs: dict[str, Any] = {"state": health.get("state"), "reason": health.get("reason", ""),
                               "info": health.get("info") or {}}
        if health.get("state") not in ("READY", "BUSY"):
            why = health.get("reason") or "no reason given"
            obs["error"] = f"{RITAD_NAME[name]} is {health.get('state')}: {why}"
        else:
            try:
                obs.update(OBSERVE[name](ctx))
            except Stopped:
                raise
            except (CommandError, TimeoutError) as exc:
                obs["error"] = f"{exc.args[0] if exc.args else exc}"
        ctx.obs[name] = obs
        ctx.mark_done(name)
    ctx.progress("judge the checks", 92, "")
