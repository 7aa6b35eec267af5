"""``ritactl record``: ritad's telemetry (and frames) to an MCAP file, the way rosbag2 records a session.

It subscribes as ``ritactl watch`` does (same endpoint discovery through ``hello``, same CURVE
keys) and writes each message as it arrives (daemon/ctl/recorder.py; layout: daemon/ctl/mcapfile.py).
The file is written under a hidden ``.NAME.partial`` beside the target and renamed into place once the
MCAP summary is written, so a reader never sees a truncated recording under the real name.
Ctrl-C and ``--duration`` end it the same way; a progress line shows the size and duration. An
error mid-recording (a full disk, a bug) never throws away what was written: the file is finished
if it still can be, kept as ``NAME.partial.mcap`` and named in the error with the reason.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import IO, Any, Callable, Iterator

import zmq

from daemon.bus.client import Client, Subscriber
from daemon.bus.protocol import CommandError, unpack
from daemon.bus.storage import fsync_dir
from daemon.ctl.exitcodes import CtlError, Exit, bad_input
from daemon.ctl.reclimits import DEFAULT_MIN_FREE, Limits
from daemon.ctl.recorder import FRAME_FORMATS, Counts, Recorder, image_encoder
from daemon.ctl.watch import NO_FRAMES, Screen

#: deep enough for many seconds of 1 kHz tracker packets while a chunk is compressed or the disk stalls
TELEMETRY_HWM = 200_000
FRAME_HWM = 4
#: frames written per turn of the loop before telemetry, the clock and Ctrl-C are looked at again
FRAME_BATCH = 2
#: the most the end waits on writing what was queued when the recording was stopped
FINAL_DRAIN_S = 1.0
#: the recording thread's nice value: beside ritad and its live viewers on the same CPUs, the recorder
#: gives way, and drops (and counts) the frames it then has no time for (docs/benchmarks.md, "Recording")
RECORD_NICE = 10
COMPRESSIONS = ("auto", "zstd", "lz4", "none")


def parse_frames(words: list[str] | None) -> int:
    """``--frames off`` → 0, ``--frames every N`` → N (keep one frame in N)."""
    if not words or words == ["off"]:
        return 0
    if len(words) == 2 and words[0] == "every" and words[1].isdigit() and int(words[1]) >= 1:
        return int(words[1])
    raise CtlError(Exit.USAGE, "usage",
                   f"--frames must be 'off' or 'every N' with N >= 1, got {' '.join(words)!r}")


def check_out(out: Path, force: bool) -> Path:
    """The target file, refused when its folder is missing or it exists (unless ``force``)."""
    if out.is_dir():
        raise bad_input(f"--out {out} is a folder: name the .mcap file to write")
    if not out.parent.is_dir():
        raise bad_input(f"--out {out}: the folder {out.parent} does not exist")
    if out.exists() and not force:
        raise bad_input(f"--out {out} exists: choose another name, or --force to replace it")
    return out


@contextmanager
def _stop_on_sigint(stop: threading.Event) -> Iterator[None]:
    """Ctrl-C sets ``stop`` instead of raising, so the file is always finished (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def progress_line(path: Path, seconds: float, size: int, c: Counts, frames: bool) -> str:
    fr = f", {c.frames} frames ({c.frames_missed} dropped)" if frames else ""
    lost = f", {c.missed} telemetry messages MISSED" if c.missed else ""
    return f"recording {path.name}: {seconds:.1f} s, {_mb(size)}, {c.messages} messages{fr}{lost}"


def _drain(sub: Subscriber, rec: Recorder, every: int, until: float, stop: threading.Event | None,
           limit: int) -> None:
    """Write what has arrived: at most ``limit`` messages, and never past ``until``, a stop or a
    limit. Frames that come faster than they are written wait in the socket, which keeps FRAME_HWM
    and drops the rest (counted from the gaps in their seq): nothing queues without bound."""
    for _ in range(limit):
        if rec.ended is not None or time.monotonic() >= until or stop is not None and stop.is_set():
            return
        try:
            frames = sub.sock.recv_multipart(zmq.NOBLOCK, copy=False)
        except zmq.Again:
            return
        now = time.time_ns()
        msg = unpack(frames[1].buffer)
        if frames[0].bytes != b"camera.frame":
            rec.telemetry(frames[0].bytes.decode(), msg, now)
        elif rec.kept_seq is None or not 0 <= int(msg["seq"]) - rec.kept_seq < every:
            # a seq below the last kept one is ritad restarted (its seq begins again): keep it
            rec.frame(msg, frames[2].buffer if len(frames) > 2 else b"", now)
        else:
            rec.note_frame_seen(int(msg["seq"]))


def _record_loop(subs: list[tuple[Subscriber, int]], rec: Recorder, a: argparse.Namespace, path: Path,
                 stop: threading.Event) -> float:
    poller = zmq.Poller()
    for s, _ in subs:
        poller.register(s.sock, zmq.POLLIN)
    screen = Screen(sys.stderr, sys.stderr.isatty(), every=5.0)
    start = time.monotonic()
    end = start + (a.duration if a.duration is not None else float("inf"))
    while not stop.is_set() and (now := time.monotonic()) < end and rec.allowed(0):
        ready = dict(poller.poll(int(min(200.0, max(0.0, (end - now) * 1000)))))
        for s, every in subs:  # a few frames a turn: telemetry and the clock get their turn between
            if s.sock in ready:
                _drain(s, rec, every, end, stop, FRAME_BATCH if every else 2000)
        elapsed = time.monotonic() - start
        screen.status(progress_line(path, elapsed, rec.stream.tell(), rec.counts, len(subs) > 1),
                      time.monotonic())
    # what arrived before the stop belongs to the recording: the queues as they are, within a
    # bounded time (a stream that keeps coming must not hold the end up)
    last = time.monotonic() + FINAL_DRAIN_S
    for s, every in subs:
        _drain(s, rec, every, last, None, FRAME_HWM if every else TELEMETRY_HWM)
    screen.close()
    return time.monotonic() - start


def _give_way() -> None:
    """Lower this thread's CPU priority to RECORD_NICE (Linux: a thread's own; never raised back,
    which is why the recording has a thread of its own). Where that is refused it runs as it is."""
    try:
        me = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, me, max(RECORD_NICE, os.getpriority(os.PRIO_PROCESS, me)))
    except (OSError, AttributeError):
        pass


def _at_low_priority(record: Callable[[], float]) -> float:
    """``record()`` on a thread of its own that gives way to ritad and the live viewers; this thread
    stays free for Ctrl-C, which sets the recording's stop (:func:`_stop_on_sigint`)."""
    done: list[float] = []
    failed: list[BaseException] = []

    def run() -> None:
        _give_way()
        try:
            done.append(record())
        except BaseException as exc:  # handed to the caller's thread, which finishes the file
            failed.append(exc)

    worker = threading.Thread(target=run, name="ritactl-record", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(0.2)
    if failed:
        raise failed[0]
    return done[0]


def _frames_hint(c: Client) -> str | None:
    try:
        return None if c.call("camera.status", timeout=5).get("streaming") else NO_FRAMES
    except CommandError as exc:
        return f"no frames: the camera is not available ({exc.args[0]})"


def sim_metadata(c: Client, hello: dict[str, Any]) -> dict[str, str]:
    """What a recording of a simulator must say about its time: the fakes run their motions and
    measurements faster than real ones (``time_scale`` wall seconds per simulated second, in each
    simulated device's info); the log times stay the host's wall clock, nothing is rescaled."""
    if not hello.get("sim"):
        return {"sim": "false"}
    try:
        devices = c.call("status", timeout=5).get("devices") or {}
    except CommandError as exc:
        return {"sim": "true", "sim_time_scale": f"unknown ({exc.args[0]})"}
    out = {"sim": "true"}
    for kind in ("robot", "tracker"):
        scale = ((devices.get(kind) or {}).get("info") or {}).get("time_scale")
        if isinstance(scale, (int, float)) and scale > 0:
            out[f"sim_time_scale_{kind}"] = f"{scale:g}"
            out[f"sim_speedup_{kind}"] = f"{1 / scale:g}"
    out["sim_note"] = ("simulated devices: log times are the host's wall clock, unscaled; the simulated "
                       "robot's motions take sim_time_scale_robot of the time a real one would "
                       "(sim_speedup_robot times faster), the tracker's measurements sim_time_scale_tracker")
    return out


def cmd_record(c: Client, a: argparse.Namespace) -> int:
    every = parse_frames(a.frames)
    if a.duration is not None and not 0 < a.duration < 1e7:
        raise CtlError(Exit.USAGE, "usage", f"--duration must be more than 0 seconds, got {a.duration:g}")
    if every:
        image_encoder(a.frames_format)  # a missing OpenCV is refused before anything is written
    out = check_out(Path(a.out), a.force)
    limits = Limits.from_options(out.parent, a.min_free, a.max_size)
    tmp = out.parent / f".{out.name}.partial"
    subs = [(c.subscriber(hwm=TELEMETRY_HWM), 0)]  # subscribed before the first message we want
    if every:
        subs.append((c.subscriber(frames=True, hwm=FRAME_HWM), every))
        if (hint := _frames_hint(c)) is not None:
            print(hint, file=sys.stderr, flush=True)
    # auto: frames are nearly all of the bytes and compressing them halves the recorder's speed
    # (bench/bench_record.py); telemetry alone is small and shrinks to 40 % with zstd
    compression = ("none" if every else "zstd") if a.compression == "auto" else a.compression
    hello = c.hello()
    meta = {"hello": json.dumps(hello, default=str), "frames": f"every {every}" if every else "off",
            "compression": compression, "endpoint": c.endpoint, "min_free": str(limits.min_free),
            "max_size": str(limits.max_size or ""), **sim_metadata(c, hello)}
    stop = threading.Event()
    rec: Recorder | None = None
    try:
        with open(tmp, "wb") as f, _stop_on_sigint(stop):
            rec = Recorder(f, meta, compression, limits, a.frames_format)
            try:
                seconds = _at_low_priority(partial(_record_loop, subs, rec, a, out, stop))
                rec.finish(rec.ended or ("interrupted" if stop.is_set() else "duration"))
                f.flush()
                os.fsync(f.fileno())
            except BaseException as exc:
                failed = _keep_partial(rec, f, tmp, out, exc)
                if isinstance(exc, Exception):
                    raise failed from None
                print(f"ritactl: {failed}", file=sys.stderr, flush=True)  # e.g. a second Ctrl-C
                raise
        os.replace(tmp, out)
        fsync_dir(out.parent)
    except BaseException:
        if rec is None:  # nothing recorded yet: no file worth keeping
            tmp.unlink(missing_ok=True)
        raise
    finally:
        for s, _ in subs:
            s.close()
    code = _report(out, seconds, rec.counts, bool(every), a.json, stop.is_set())
    if rec.ended is not None:
        print(f"ritactl: WARNING: the recording ended early: {limits.describe(rec.ended)}; {out} is complete",
              file=sys.stderr, flush=True)
    # the floor is the disk running out (exit 5, as a full disk's error); --max-size is the size asked for
    return Exit.BAD_INPUT if rec.ended == "min_free" else code


def partial_name(out: Path) -> Path:
    """Where a recording an error ended is kept: ``NAME.partial.mcap``, numbered if that exists."""
    stem, suffix = (out.stem, out.suffix) if out.suffix else (out.name, ".mcap")
    for n in range(1, 1000):
        path = out.with_name(f"{stem}.partial{'' if n == 1 else f'-{n}'}{suffix}")
        if not path.exists():
            return path
    return out.with_name(f".{out.name}.partial")  # the hidden file stays where it is


def _keep_partial(rec: Recorder, f: IO[bytes], tmp: Path, out: Path, exc: BaseException) -> CtlError:
    """Finish what was written (if the writer still can), keep it visible and say where and why."""
    why = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    state = "finished (a valid MCAP file)"
    try:
        if rec.finishing:
            raise RuntimeError("the failure was in writing the summary")
        rec.finish("error", why)
        f.flush()
        os.fsync(f.fileno())
    except Exception as again:
        state = (f"NOT finished ({type(again).__name__}: {again}); "
                 f"the messages in its complete chunks can be recovered with mcap's recover tool")
    try:
        f.close()  # now: a buffer that cannot be flushed must not raise again at the end of ``with``
    except OSError:
        pass
    keep = partial_name(out)
    try:
        os.replace(tmp, keep)
    except OSError:
        keep = tmp
    return CtlError(Exit.BAD_INPUT, "record_failed",
                    f"the recording ended on an error after {rec.counts.messages} messages: {why}. What was "
                    f"recorded is kept in {keep}, {state}")


def _report(out: Path, seconds: float, cnt: Counts, frames: bool, as_json: bool, interrupted: bool) -> int:
    size = out.stat().st_size
    if as_json:
        print(json.dumps({"path": str(out), "duration_s": round(seconds, 3), "bytes": size,
                          "messages": cnt.messages, "topics": cnt.topics, "frames": cnt.frames,
                          "missed": cnt.missed, "frames_missed": cnt.frames_missed,
                          "frames_unsupported": cnt.unsupported}), flush=True)
    else:
        fr = f", {cnt.frames} frames ({cnt.frames_missed} dropped)" if frames else ""
        print(f"recorded {out}: {seconds:.1f} s, {_mb(size)}, {cnt.messages} messages on {len(cnt.topics)} "
              f"topics{fr}", flush=True)
    if cnt.missed:
        print(f"ritactl: WARNING: {cnt.missed} telemetry messages were lost before they reached the recorder "
              f"(gaps in seq)", file=sys.stderr, flush=True)
    if cnt.unsupported:
        print(f"ritactl: WARNING: {cnt.unsupported} frames have a pixel format Foxglove cannot show: "
              f"only their headers are in the file", file=sys.stderr, flush=True)
    return Exit.INTERRUPTED if interrupted else Exit.OK


def add_parser(sub: Any) -> None:
    p = sub.add_parser("record", help="record telemetry (and frames) to an MCAP file (Foxglove opens it)",
                       description="Record ritad's telemetry, and frames with --frames, to an MCAP file "
                                   "until Ctrl-C or --duration. "
                                   "The file appears under its name only once complete.")
    p.add_argument("--out", required=True, metavar="FILE.mcap", help="the file to write")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--frames", nargs="+", metavar="every N|off", default=["off"],
                   help="record one camera frame in N ('every 1': all of them), or none (default: off)")
    p.add_argument("--frames-format", choices=FRAME_FORMATS, default="raw",
                   help="frames as Foxglove RawImage (raw: the pixels as they are, default), or "
                        "CompressedImage jpeg (lossy, small) or png (lossless); jpeg and png need OpenCV")
    p.add_argument("--compression", choices=COMPRESSIONS, default="auto", help="MCAP chunk compression "
                   "(default auto: none when frames are recorded, else zstd)")
    p.add_argument("--max-size", metavar="SIZE", help="end the recording before the file passes SIZE (500M)")
    p.add_argument("--min-free", metavar="SIZE", help="end the recording before the disk's free space falls "
                   f"under SIZE (default {DEFAULT_MIN_FREE // 10**9}G)")
    p.add_argument("--force", action="store_true", help="replace FILE.mcap if it exists")
    p.set_defaults(fn=cmd_record)
