"""Bus command handlers: thin glue from requests to device jobs and storage.

Every handler validates its args (``need``/``opt`` raise ``bad_args`` naming the
argument) and either answers at once or returns a Future that completes in a
device runner or the storage thread. Motion commands require ``confirm: true``;
``robot.stop`` is urgent (jumps every queue) and needs no confirmation.
"""
from __future__ import annotations

import math
import time
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from daemon.ritad import files
from daemon.ritad.key_admin import key_handlers
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.server import Reply, Request
from daemon.bus.storage import tracker_point_dict
from drivers.base import Frame, TrackerPoint

if TYPE_CHECKING:
    from daemon.ritad.main import Daemon

_MISSING = object()


def need(req: Request, name: str, kind: type | tuple[type, ...], default: Any = _MISSING) -> Any:
    """Typed argument; ints are accepted for floats; a bad or missing one is ``bad_args``."""
    if name not in req.args:
        if default is _MISSING:
            raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: missing argument {name!r}")
        return default
    value = req.args[name]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if float in kinds and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        names = "/".join(k.__name__ for k in kinds)
        raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: argument {name!r} must be {names}, got {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: argument {name!r} must be finite, got {value!r}")
    return value


def chain(fut: Future, fn: Callable[[Any], Any], executor: Executor | None = None) -> Future:
    """A future of ``fn(result)``; errors pass through.

    ``fn`` runs in the thread that completed ``fut`` (a device runner) unless an
    ``executor`` is given: slow work such as writing files goes there, so it never
    holds up a device.
    """
    out: Future = Future()

    def run(result: Any) -> None:
        try:
            out.set_result(fn(result))
        except BaseException as e:  # noqa: BLE001 - handed to the client as an error reply
            out.set_exception(e)

    def done(f: Future) -> None:
        exc = f.exception()
        if exc is not None:
            out.set_exception(exc)
        elif executor is None:
            run(f.result())
        else:
            executor.submit(run, f.result())

    fut.add_done_callback(done)
    return out


def gather(futures: dict[str, Future]) -> Future:
    """A future of ``{name: result}`` once all are done; the first error wins."""
    out: Future = Future()
    remaining = [len(futures)]

    def done(_: Future) -> None:
        remaining[0] -= 1
        if remaining[0]:
            return
        for f in futures.values():
            if f.exception() is not None:
                out.set_exception(f.exception())
                return
        out.set_result({k: f.result() for k, f in futures.items()})

    if not futures:
        out.set_result({})
    for f in futures.values():
        f.add_done_callback(done)
    return out


def _point_dict(p: TrackerPoint, abs_H_trk: list[list[float]]) -> dict[str, Any]:
    return tracker_point_dict(p.to_dict(), abs_H_trk)  # abs_xyz + abs_H_trk: datasets cross-check them


def build_handlers(d: "Daemon") -> dict[str, Callable[[Request], Any]]:
    cfg = d.config
    H_trk = cfg.tracker.abs_H_trk

    def ping(req: Request) -> Any:
        return {"pong": True, "t_ns": time.time_ns()}

    def help_(req: Request) -> Any:
        return {"commands": sorted(handlers)}

    def hello(req: Request) -> Any:
        return d.hello()

    def status(req: Request) -> Any:
        return d.health()

    def state(req: Request) -> Any:
        snap = d.telemetry.snapshot()
        return {**snap, "devices": {k: r.snapshot() for k, r in d.runners.items()}}

    # ---------------------------------------------------------------- tracker
    def tracker_measure(req: Request) -> Any:
        return chain(d.job("tracker", lambda t: t.measure(), timeout=60), lambda p: _point_dict(p, H_trk))

    def tracker_aim(req: Request) -> Any:
        xyz = tuple(need(req, k, float) for k in ("x", "y", "z"))
        return chain(d.job("tracker", lambda t: t.aim(xyz), timeout=60), lambda _: {"aimed": list(xyz)})

    def tracker_find(req: Request) -> Any:
        dist = need(req, "approx_distance_mm", (float, type(None)), None)
        return chain(d.job("tracker", lambda t: t.find_reflector(dist), timeout=60), lambda _: {"locked": True})

    def tracker_stream_start(req: Request) -> Any:
        rate = need(req, "rate_hz", float, cfg.tracker.stream_rate_hz)
        if not 0 < rate <= 10000:
            raise CommandError(ErrorCode.BAD_ARGS, f"tracker.stream.start: rate_hz={rate} out of range (0, 10000]")
        return chain(d.job("tracker", lambda t: t.start_stream(rate)), lambda _: {"streaming": True, "rate_hz": rate})

    def tracker_stream_stop(req: Request) -> Any:
        return chain(d.job("tracker", lambda t: t.stop_stream()), lambda _: {"streaming": False})

    def tracker_status(req: Request) -> Any:
        return d.job("tracker", lambda t: t.status())

    # ---------------------------------------------------------------- camera
    def camera_capture(req: Request) -> Any:
        want_pixels = need(req, "pixels", bool, False)
        save = need(req, "save", bool, not want_pixels)

        def finish(frame: Frame) -> Any:
            result: dict[str, Any] = {"header": frame.header()}
            if save:
                result["path"] = str(d.save_capture({"camera": frame}, need(req, "label", str, "frame")))
            return Reply(result, [frame.pixels]) if want_pixels else result

        return chain(d.job("camera", lambda c: c.trigger(), timeout=30), finish, d.storage if save else None)

    def camera_stream_start(req: Request) -> Any:
        return chain(d.job("camera", lambda c: c.start_stream()), lambda _: {"streaming": True})

    def camera_stream_stop(req: Request) -> Any:
        return chain(d.job("camera", lambda c: c.stop_stream()), lambda _: {"streaming": False})

    def camera_status(req: Request) -> Any:
        return d.job("camera", lambda c: c.status())

    # ---------------------------------------------------------------- robot
    def _confirm(req: Request) -> None:
        if need(req, "confirm", bool, False) is not True:
            raise CommandError(ErrorCode.CONFIRM_REQUIRED,
                               f"{req.cmd} moves the robot: resend with confirm=true (ritactl: --yes)")

    def robot_move(req: Request) -> Any:
        dist = need(req, "distance_mm", float)
        speed = need(req, "speed_mm_s", float, 50.0)
        if abs(dist) > cfg.robot.max_distance_mm:
            raise CommandError(ErrorCode.BAD_ARGS, f"robot.move: |distance_mm|={abs(dist)} exceeds the "
                                                   f"configured limit {cfg.robot.max_distance_mm}")
        if not 0 < speed <= cfg.robot.max_speed_mm_s:
            raise CommandError(ErrorCode.BAD_ARGS, f"robot.move: speed_mm_s={speed} must be in "
                                                   f"(0, {cfg.robot.max_speed_mm_s}]")
        _confirm(req)
        return d.motion(lambda r: r.move(dist, speed), need(req, "wait", bool, True),
                        need(req, "timeout_s", float, 60.0 + 2 * abs(dist) / speed))

    def robot_turn(req: Request) -> Any:
        angle = need(req, "angle_deg", float)
        speed = need(req, "speed_deg_s", float, 20.0)
        if abs(angle) > 360:
            raise CommandError(ErrorCode.BAD_ARGS, f"robot.turn: angle_deg={angle} must be within ±360")
        if not 0 < speed <= cfg.robot.max_turn_speed_deg_s:
            raise CommandError(ErrorCode.BAD_ARGS, f"robot.turn: speed_deg_s={speed} must be in "
                                                   f"(0, {cfg.robot.max_turn_speed_deg_s}]")
        _confirm(req)
        return d.motion(lambda r: r.turn(angle, speed), need(req, "wait", bool, True),
                        need(req, "timeout_s", float, 60.0 + 2 * abs(angle) / speed))

    def robot_stop(req: Request) -> Any:
        return chain(d.job("robot", lambda r: r.stop(), urgent=True), lambda _: {"stopped": True})

    def robot_status(req: Request) -> Any:
        return chain(d.job("robot", lambda r: r.status()), lambda s: s.to_dict())

    # ---------------------------------------------------------------- composite
    def capture(req: Request) -> Any:
        label = need(req, "label", str, "capture")
        dataset = need(req, "dataset", (str, type(None)), None)
        parts = {"camera": d.job("camera", lambda c: c.trigger(), timeout=30),
                 "tracker": d.job("tracker", lambda t: t.measure(), timeout=60),
                 "robot": d.job("robot", lambda r: r.status())}
        return chain(gather(parts), lambda res: {"path": str(d.save_capture(res, label, dataset)),
                                                 "header": res["camera"].header(),
                                                 "tracker": _point_dict(res["tracker"], H_trk),
                                                 "robot": res["robot"].to_dict()}, d.storage)

    def sim_truth(req: Request) -> Any:
        if d.world is None:
            raise CommandError(ErrorCode.NOT_FOUND, "sim.truth: this daemon runs no simulated world")
        truth = d.world.truth()
        size = d.runners["camera"].info.get("size") or list(d.world.params.reduced_size)
        truth["camera_model"] = {"K": d.world.camera_matrix(tuple(size)).tolist(),
                                 "dist": d.world.dist_coeffs().tolist(), "size": list(size)}
        truth["plate"] = d.world.plate().to_dict()
        return truth

    def sim_place_robot_on_plate(req: Request) -> Any:
        """Simulation only: put the robot on the plate with the target in view (an operator's job)."""
        if d.world is None:
            raise CommandError(ErrorCode.NOT_FOUND, f"{req.cmd}: this daemon runs no simulated world")
        heading = need(req, "heading_deg", float, d.world.plate_yaw_deg + 60.0)
        if abs(heading) > 360.0:
            raise CommandError(ErrorCode.BAD_ARGS, f"{req.cmd}: heading_deg={heading} must be within ±360")
        pose = d.world.pose_with_target_in_view(heading)
        d.world.set_robot(pose)
        return {"x_mm": pose.x_mm, "y_mm": pose.y_mm, "heading_deg": pose.heading_deg}

    def calib_results(req: Request) -> Any:
        from daemon.bus.storage import read_results

        return read_results(Path(cfg.daemon.data_dir))

    def data_dir(req: Request) -> Any:
        return {"data_dir": str(Path(cfg.daemon.data_dir).resolve())}

    # ---------------------------------------------------------------- files (ritactl fetch)
    # file work runs in the storage thread: a slow disk never holds up the bus or a device
    root = Path(cfg.daemon.data_dir)
    auth_top = Path(cfg.security.authorized_keys_dir)
    private = (*files.PRIVATE_DIRS, *(() if auth_top.is_absolute() else auth_top.parts[:1]))

    def files_list(req: Request) -> Any:
        path = need(req, "path", str, "")
        return d.storage.submit(files.list_files, root, path, private)

    def files_read(req: Request) -> Any:
        path, offset = need(req, "path", str), need(req, "offset", int, 0)
        length = need(req, "length", int, files.CHUNK_MAX)

        def read() -> Reply:
            meta, data = files.read_chunk(root, path, offset, length, private)
            return Reply(meta, [data])

        return d.storage.submit(read)

    def files_hash(req: Request) -> Any:
        path, length = need(req, "path", str), need(req, "length", (int, type(None)), None)
        return d.storage.submit(files.hash_file, root, path, length, private)

    handlers: dict[str, Callable[[Request], Any]] = {
        "ping": ping, "help": help_, "hello": hello, "status": status, "health": status, "state": state,
        "tracker.measure": tracker_measure, "tracker.aim": tracker_aim, "tracker.find": tracker_find,
        "tracker.stream.start": tracker_stream_start, "tracker.stream.stop": tracker_stream_stop,
        "tracker.status": tracker_status,
        "camera.capture": camera_capture, "camera.stream.start": camera_stream_start,
        "camera.stream.stop": camera_stream_stop, "camera.status": camera_status,
        "robot.move": robot_move, "robot.turn": robot_turn, "robot.stop": robot_stop, "robot.status": robot_status,
        "capture": capture, "sim.truth": sim_truth, "sim.place_robot_on_plate": sim_place_robot_on_plate, "data.dir": data_dir, "calib.results": calib_results,
        "files.list": files_list, "files.read": files_read, "files.hash": files_hash,
        **d.calib.handlers(),
        **key_handlers(auth_top if auth_top.is_absolute() else root / auth_top, lambda fn: d.storage.submit(fn)),
    }
    return handlers
