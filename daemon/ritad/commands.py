"""Bus command handlers: thin glue from requests to device jobs and storage.

Each handler group gets what it uses: a device's commands its rig (daemon/ritad/rigs.py), the
others the narrow ``Services`` (daemon/ritad/services.py), never the daemon. ``build_handlers``
wraps every handler with the daemon's command table's validator, so a
handler reads ``req.args`` already checked and defaulted (``bad_args`` names a bad one)
and only checks what the table cannot: limits from the config.
A handler answers at once or returns a Future completed in a device runner or the
storage thread. Motions require ``confirm: true``; ``robot.stop`` latches and
requests the halt of the robot's motion gate (daemon/ritad/stop_latch.py): no motion until ``robot.release``.
"""
from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
from concurrent.futures import Future, InvalidStateError
from typing import Any, Callable

from daemon.bus.command_table import check_args, help_entry
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.storage import read_results, tracker_point_dict
from daemon.ritad import files, plates
from daemon.ritad.calib_jobs import CalibJobs
from daemon.ritad.commission import commission_handlers
from daemon.ritad.futures import chain, gather
from daemon.ritad.key_admin import key_handlers
from daemon.ritad.server import Handler, Reply, Request
from daemon.ritad.rigs import CameraRig, Rigs, RobotRig, TrackerRig
from daemon.ritad.services import Reports, Services
from daemon.ritad.timelines import COVER_WAIT_S, Timelines, frame_time
from daemon.ritad.timeouts import Timeouts
from drivers.base import DeviceError, Frame, Robot, Tracker, TrackerPoint


def _point_dict(p: TrackerPoint, abs_H_trk: list[list[float]]) -> dict[str, Any]:
    return tracker_point_dict(p.to_dict(), abs_H_trk)  # abs_xyz + abs_H_trk: datasets cross-check them


def _then(fut_of: Callable[[], Any], result: Any) -> Handler:
    """A handler that runs a device job and answers ``result`` when it is done."""
    return lambda req: chain(fut_of(), lambda _: result)


def _daemon(s: Services, reports: Reports) -> dict[str, Handler]:
    return {"ping": lambda req: {"pong": True, "t_ns": time.time_ns()},
            "help": lambda req: {"commands": {c.name: help_entry(c) for c in s.table.values()}},
            "hello": lambda req: reports.hello(), "status": lambda req: reports.health(),
            "state": lambda req: reports.state(),
            "data.dir": lambda req: {"data_dir": str(s.data_dir.resolve())},
            "calib.results": lambda req: read_results(s.data_dir)}


def _tracker(trk: TrackerRig) -> dict[str, Handler]:
    def measure(req: Request) -> Any:
        return chain(trk.job(lambda t: t.measure(), timeout=60), lambda p: _point_dict(p, trk.abs_H_trk))

    def aim(req: Request) -> Any:
        xyz = tuple(req.args[k] for k in "xyz")
        return chain(trk.job(lambda t: t.aim(xyz), timeout=60), lambda _: {"aimed": list(xyz)})

    def find(req: Request) -> Any:
        dist = req.args["approx_distance_mm"]
        return chain(trk.job(lambda t: t.find_reflector(dist), timeout=60), lambda _: {"locked": True})

    def stream_start(req: Request) -> Any:
        rate = req.args["rate_hz"] or trk.stream_rate_hz
        # the reply states the rate the tracker streams, which it may have clamped to its maximum
        return chain(trk.job(lambda t: t.start_stream(rate)),
                     lambda streamed: {"streaming": True, "rate_hz": streamed})

    return {"tracker.measure": measure, "tracker.aim": aim, "tracker.find": find,
            "tracker.stream.start": stream_start,
            "tracker.stream.stop": _then(lambda: trk.job(lambda t: t.stop_stream()), {"streaming": False}),
            "tracker.readback": lambda req: trk.job(lambda t: t.readback()),
            "tracker.status": lambda req: trk.status(lambda t: t.status())}


def _camera(cam: CameraRig, s: Services) -> dict[str, Handler]:
    def capture(req: Request) -> Any:
        want_pixels = req.args["pixels"]
        save = not want_pixels if req.args["save"] is None else req.args["save"]

        def finish(frame: Frame) -> Any:
            result: dict[str, Any] = {"header": frame.header()}
            if save:
                result["path"] = str(s.save_capture({"camera": frame}, req.args["label"]))
            return Reply(result, [frame.pixels]) if want_pixels else result

        return chain(cam.trigger(), finish, s.storage if save else None)

    return {"camera.capture": capture,
            "camera.stream.start": _then(lambda: cam.job(lambda c: c.start_stream()), {"streaming": True}),
            "camera.stream.stop": _then(lambda: cam.job(lambda c: c.stop_stream()), {"streaming": False}),
            "camera.status": lambda req: cam.status(lambda c: c.status())}


def _who(req: Request) -> str:
    """The sender as logs and the latch name it: the key's name (or the local peer) and its role."""
    return f"{req.peer.split(' (', 1)[0]} ({req.role})"


def _check_motion(req: Request, amount: str, limit: float, speed: str, max_speed: float) -> None:
    """Config limits (the table's ranges cannot know them), then the confirmation."""
    a, v = req.args[amount], req.args[speed]
    if abs(a) > limit:
        raise CommandError(ErrorCode.BAD_ARGS,
                           f"{req.cmd}: |{amount}|={abs(a):g} exceeds the configured limit {limit:g}")
    if v > max_speed:
        raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: {speed}={v:g} must be in (0, {max_speed:g}] "
                                               f"(the configured limit)")
    if req.args["confirm"] is not True:
        raise CommandError(ErrorCode.CONFIRM_REQUIRED,
                           f"{req.cmd} moves the robot: send it again with confirm=true to confirm "
                           f"(ritactl: add --yes)")


def _robot(rob: RobotRig, calib: CalibJobs) -> dict[str, Handler]:
    latch, limits = rob.latch, rob.limits

    def motion(req: Request, amount: str, speed: str, fn: Callable[[Robot, float, float], Any]) -> Any:
        a, v = req.args[amount], req.args[speed]
        timeout = req.args["timeout_s"] or 60.0 + 2 * abs(a) / v  # the table's default_text says the same

        def guarded(robot: Robot) -> Any:  # again in the owner thread: a STOP may have come while queued
            latch.guard(req.cmd, _who(req))
            return fn(robot, a, v)

        return rob.motions.start(guarded, req.args["wait"], timeout)

    def move(req: Request) -> Any:
        _check_motion(req, "distance_mm", limits.max_distance_mm, "speed_mm_s", limits.max_speed_mm_s)
        return motion(req, "distance_mm", "speed_mm_s", lambda r, a, v: r.move(a, v))

    def turn(req: Request) -> Any:
        _check_motion(req, "angle_deg", 360.0, "speed_deg_s", limits.max_turn_speed_deg_s)
        return motion(req, "angle_deg", "speed_deg_s", lambda r, a, v: r.turn(a, v))

    def stop(req: Request) -> Any:
        """Latch and request the halt first (this thread serves every request in order: no motion slips in
        between), then stop the jobs. Accepted whatever the robot's state: the gate sends the halt as soon
        as the base answers; the reply says whether the base has acknowledged it yet."""
        who = _who(req)
        halted, persisted = latch.engage(who)
        stopped = calib.stop_moving_jobs(who)
        rob.motions.abort(latch.message("the motion"))
        return halt_reply(halted, persisted, stopped, rob.halt_wait_s, rob.timeouts)

    def release(req: Request) -> Any:
        return {"released": True, "was_latched": latch.release(_who(req))}

    return {"robot.move": move, "robot.turn": turn, "robot.stop": stop, "robot.release": release,
            "robot.status": lambda req: rob.status(_robot_status)}


def _robot_status(robot: Robot) -> dict[str, Any]:
    return {**robot.status().to_dict(), "streams": robot.streams()}


def halt_reply(halted: Future, persisted: Future, jobs_stopped: list[str], wait_s: float,
               timeouts: Timeouts) -> Future:
    """The STOP's reply once the latch is on disk and the base acknowledged the halt, or after ``wait_s``
    without both (link down, base off, a slow disk): latched all the same, the halt still owed."""
    out: Future = Future()
    expired = threading.Event()  # set in the timeouts' thread, read in the callbacks' threads

    def answer(*_: Any) -> None:
        acked = halted.done()
        if out.done() or not (acked and persisted.done() or expired.is_set()):
            return
        reply: dict[str, Any] = {"stopped": acked, "latched": True, "jobs_stopped": jobs_stopped}
        if not acked:
            reply["message"] = "latched; the halt is sent as soon as the base answers"
        with contextlib.suppress(InvalidStateError):  # the timer and the halt may answer together
            out.set_result(reply)

    def expire() -> None:
        expired.set()
        answer()

    halted.add_done_callback(answer)
    persisted.add_done_callback(answer)
    pending = timeouts.call_later(wait_s, expire)
    out.add_done_callback(lambda _: pending.cancel())
    return out


def _capture(rigs: Rigs, timelines: Timelines, s: Services) -> dict[str, Handler]:
    def capture(req: Request) -> Any:
        label, dataset = req.args["label"], req.args["dataset"]
        parts = {"camera": rigs.camera.trigger(),
                 "tracker": rigs.tracker.job(_standstill_point, timeout=60),
                 "robot": rigs.robot.job(lambda r: r.status())}
        return chain(gather(parts), lambda res: _captured(res, label, dataset, rigs.tracker, timelines, s),
                     s.storage)

    return {"capture": capture}


def _standstill_point(tracker: Tracker) -> TrackerPoint | None:
    """The capture's stationary measurement; None while the tracker streams (at_exposure has its point)."""
    try:
        return tracker.measure()
    except DeviceError as exc:
        if exc.code == "tracker_streaming":
            return None
        raise


def _captured(res: dict[str, Any], label: str, dataset: str | None, trk: TrackerRig, timelines: Timelines,
              s: Services) -> dict[str, Any]:
    """Store a capture with where every stream was at the frame's exposure (in the storage thread)."""
    header = res["camera"].header()
    when = frame_time(header)
    res["at_exposure"] = ({"error": "the frame has no exposure time on the host's timeline (t_ns)"}
                          if when is None else timelines.at(when[0], COVER_WAIT_S))
    return {"path": str(s.save_capture(res, label, dataset)), "header": header,
            "tracker": None if res["tracker"] is None else _point_dict(res["tracker"], trk.abs_H_trk),
            "robot": res["robot"].to_dict(),
            "at_exposure": res["at_exposure"]}


def _files(s: Services) -> dict[str, Handler]:
    """ritactl fetch: the work runs in the storage thread, so a slow disk never holds up the bus."""
    root, private = s.data_dir, s.private_dirs

    def read(req: Request) -> Any:
        a = req.args

        def chunk() -> Reply:
            meta, data = files.read_chunk(root, a["path"], a["offset"], a["length"], private)
            return Reply(meta, [data])

        return s.storage.submit(chunk)

    return {"files.list": lambda req: s.storage.submit(
                files.list_files, root, req.args["path"] or "", private),
            "files.read": read,
            "files.hash": lambda req: s.storage.submit(
                files.hash_file, root, req.args["path"], req.args["length"], private)}


def _plates(s: Services) -> dict[str, Handler]:
    """A plate surveyed on the laptop into the robot's calibration folder (checked, atomic, nothing lost)."""
    return {"calib.plate.upload": lambda req: s.storage.submit(
        plates.store_plate, s.data_dir, req.args["plate"], req.args["name"], _who(req))}


def _keys(s: Services) -> dict[str, Handler]:
    return key_handlers(s.auth_dir, lambda fn: s.storage.submit(fn))  # admin: the allow-list over the bus


def _frames(cam: CameraRig, s: Services) -> dict[str, Handler]:
    """Live view and detection on the newest streamed frame."""
    from daemon.ritad.detect import detect_handlers
    from daemon.ritad.preview import preview_handlers

    return {**preview_handlers(cam.latest), **detect_handlers(cam.latest, s.data_dir, s.private_dirs)}


def validated(cmd: str, handler: Handler, s: Services) -> Handler:
    """``handler`` seeing ``req.args`` checked and defaulted by the command table;
    motions refused when latched."""
    declared = s.table[cmd]

    def run(req: Request) -> Any:
        args = check_args(declared, req.args)
        if declared.motion == "moves":  # robot.move and robot.turn are also guarded in the runner
            s.latch.guard(cmd, _who(req))
        return handler(dataclasses.replace(req, args=args))

    return run


def build_handlers(s: Services, rigs: Rigs, reports: Reports, timelines: Timelines,
                   plugins: dict[str, Handler] | None = None) -> dict[str, Handler]:
    """Every command of the daemon's table (the plugins' too), validated; each group gets only what it
    uses. A table entry without a handler (or the reverse) is a bug."""
    raw: dict[str, Handler] = {**s.calib.handlers(), **_daemon(s, reports), **_tracker(rigs.tracker),
                               **_camera(rigs.camera, s), **_robot(rigs.robot, s.calib),
                               **_capture(rigs, timelines, s), **_files(s), **_plates(s), **_keys(s),
                               **_frames(rigs.camera, s), **commission_handlers(rigs.robot)}
    for name, handler in (plugins or {}).items():
        if name in raw:
            raise RuntimeError(f"plugin handler {name!r} would replace a product command")
        raw[name] = handler
    if set(raw) != set(s.table):
        raise RuntimeError(f"handlers and command table differ: {sorted(set(raw) ^ set(s.table))}")
    return {name: validated(name, h, s) for name, h in raw.items()}
