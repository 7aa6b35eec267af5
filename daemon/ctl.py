"""ritactl: the operator's client (needs only pyzmq and msgpack; runs on Windows too).

Examples::

    ritactl status
    ritactl watch                 # live telemetry, one summary line per second
    ritactl watch --frames        # frame rate, drops and latency of the image stream
    ritactl capture --label nest-red
    ritactl tracker measure | aim X Y Z | find | stream start --rate 1000 | stream stop | status
    ritactl robot move 200 --speed 50 --yes | turn 90 --yes | stop | status
    ritactl camera capture --out frame.png | stream start | stream stop | status
    ritactl calibrate --reversal | experiment --mark X Y | measure-mark --mark X Y | results
    ritactl jobs | follow JOB | answer JOB TEXT | cancel JOB | resume JOB | recompute DATASET
    ritactl call COMMAND '{"arg": 1}'   # any bus command, JSON args

The daemon is found at --endpoint, else $RITA_ENDPOINT, else ipc:///run/ritad/cmd.
Exit codes: 0 ok, 1 the daemon answered with an error, 2 usage, 3 no answer.
"""
from __future__ import annotations

import argparse
import array
import json
import struct
import sys
import zlib
from pathlib import Path
from typing import Any

from daemon import ctl_fetch, ctl_watch
from daemon.client import Client, ClientTimeout, default_endpoint
from daemon.protocol import CommandError


def write_png(path: Path, pixels: bytes, width: int, height: int, channels: int = 1, bit_depth: int = 8) -> None:
    """Minimal lossless PNG writer (greyscale or RGB), so the laptop needs no imaging library."""
    colour = {1: 0, 3: 2, 4: 6}[channels]
    stride = width * channels * bit_depth // 8
    raw = b"".join(b"\x00" + pixels[y * stride:(y + 1) * stride] for y in range(height))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bit_depth, colour, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(png)
    tmp.replace(path)


def _print(obj: Any, as_json: bool) -> None:
    if as_json:
        print(json.dumps(obj, indent=2, default=str))
    elif isinstance(obj, dict):
        for k, v in obj.items():
            print(f"{k}: {json.dumps(v, default=str) if isinstance(v, (dict, list)) else v}")
    else:
        print(obj)


def cmd_status(c: Client, a: argparse.Namespace) -> int:
    h = c.call("status")
    if a.json:
        _print(h, True)
        return 0
    print(f"ritad {h['version']}  up {h['uptime_s']:.0f} s  alive={h['alive']}")
    for kind, s in h["devices"].items():
        reason = f" - {s['reason']}" if s["reason"] else ""
        print(f"  {kind:8s} {s['state']:12s} reconnects={s['reconnects']} jobs={s['jobs_done']}"
              f"/{s['jobs_failed']} failed{reason}")
    t, f, cm = h["telemetry"], h["frames"], h["commands"]
    print(f"  telemetry sent={t['sent']} dropped={sum(t['dropped'].values())}   frames sent={f['sent']} "
          f"dropped={f['dropped']}   commands={cm['requests']} errors={cm['errors']}")
    return 0


def cmd_capture(c: Client, a: argparse.Namespace) -> int:
    r = c.call("capture", timeout=a.timeout or 90, label=a.label, dataset=a.dataset)
    if a.json:
        _print(r, True)
    else:
        t = r["tracker"]
        print(f"saved {r['path']}")
        print(f"  image {r['header']['shape']} frame {r['header']['frame_id']}; reflector "
              f"({t['x']:.4f}, {t['y']:.4f}, {t['z']:.4f}) mm; robot {r['robot']['state']}")
    return 0


def cmd_device(c: Client, a: argparse.Namespace) -> int:
    dev, verb = a.device, a.verb
    args: dict[str, Any] = {}
    cmd = f"{dev}.{verb}"
    if dev == "tracker" and verb == "aim":
        args = {"x": a.values[0], "y": a.values[1], "z": a.values[2]}
    elif dev == "tracker" and verb == "find" and a.distance is not None:
        args = {"approx_distance_mm": a.distance}
    elif verb == "stream":
        cmd = f"{dev}.stream.{a.action}"
        if dev == "tracker" and a.action == "start" and a.rate:
            args = {"rate_hz": a.rate}
    elif dev == "robot" and verb in ("move", "turn"):
        key = "distance_mm" if verb == "move" else "angle_deg"
        args = {key: a.values[0], "confirm": a.yes, "wait": not a.no_wait}
        if a.speed:
            args["speed_mm_s" if verb == "move" else "speed_deg_s"] = a.speed
    elif dev == "camera" and verb == "capture":
        args = {"pixels": bool(a.out), "save": not a.out}
    result, extra = c.call_raw(cmd, args, timeout=a.timeout or 120)
    if dev == "camera" and verb == "capture" and a.out:
        h = result["header"]
        shape = h["shape"]
        depth = 16 if h["dtype"].endswith("2") else 8
        data = bytes(extra[0].buffer)
        if depth == 16 and h["dtype"].startswith("<"):  # PNG stores 16-bit samples big-endian
            words = array.array("H", data)
            words.byteswap()
            data = words.tobytes()
        write_png(Path(a.out), data, shape[1], shape[0], shape[2] if len(shape) == 3 else 1, depth)
        Path(a.out).with_suffix(".json").write_text(json.dumps(h, indent=2))
        print(f"saved {a.out} (+ .json metadata)")
        return 0
    _print(result, a.json)
    return 0


def cmd_call(c: Client, a: argparse.Namespace) -> int:
    try:
        args = json.loads(a.args) if a.args else {}
    except json.JSONDecodeError as exc:
        print(f"ritactl: ARGS is not valid JSON: {exc}", file=sys.stderr)
        return 2
    _print(c.call(a.command, timeout=a.timeout, **args), True)
    return 0


def _check_params(ap: argparse.ArgumentParser, a: argparse.Namespace, verb: str) -> None:
    """Turn the free positional words into typed values, with usage errors that say what is wrong."""
    a.values, a.action = [], None
    if verb == "stream":
        if len(a.params) != 1 or a.params[0] not in ("start", "stop"):
            ap.error(f"{a.device} stream needs 'start' or 'stop', got {' '.join(a.params) or 'nothing'}")
        a.action = a.params[0]
        return
    want = {"aim": 3, "move": 1, "turn": 1}.get(verb, 0)
    if len(a.params) != want:
        ap.error(f"{a.device} {verb} takes {want} number(s), got {len(a.params)}: {' '.join(a.params)}")
    try:
        a.values = [float(v) for v in a.params]
    except ValueError:
        ap.error(f"{a.device} {verb}: not a number in {' '.join(a.params)}")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="ritactl", description="Operator client for ritad",
                                 epilog="Endpoint: --endpoint, else $RITA_ENDPOINT, else ipc:///run/ritad/cmd")
    ap.add_argument("--endpoint", help=f"daemon command endpoint (now: {default_endpoint()})")
    ap.add_argument("--timeout", type=float, help="seconds to wait for an answer")
    ap.add_argument("--json", action="store_true", help="print raw JSON")
    ap.add_argument("--keys", help="CURVE keys folder for tcp endpoints (default $RITA_KEYS or ~/.config/rita)")
    sub = ap.add_subparsers(dest="verb_", required=True)
    sub.add_parser("status", help="device states at a glance").set_defaults(fn=cmd_status)
    ctl_watch.add_parser(sub)
    cap = sub.add_parser("capture", help="image + tracker point + robot state, saved as a dataset entry")
    cap.add_argument("--label", default="capture")
    cap.add_argument("--dataset", help="dataset folder name (default: today's captures)")
    cap.set_defaults(fn=cmd_capture)
    for dev, verbs in (("tracker", ("measure", "aim", "find", "stream", "status")),
                       ("robot", ("move", "turn", "stop", "status")),
                       ("camera", ("capture", "stream", "status"))):
        p = sub.add_parser(dev, help=f"{dev} commands")
        p.add_argument("verb", choices=verbs)
        p.add_argument("params", nargs="*", help="aim: X Y Z (mm); move: mm; turn: degrees; stream: start|stop")
        p.add_argument("--rate", type=float, help="tracker stream rate (Hz)")
        p.add_argument("--distance", type=float, help="find: approximate distance (mm)")
        p.add_argument("--speed", type=float, help="move: mm/s, turn: deg/s")
        p.add_argument("--yes", action="store_true", help="confirm a motion")
        p.add_argument("--no-wait", action="store_true", help="return once the motion started")
        p.add_argument("--out", help="camera capture: save PNG here (on this computer)")
        p.set_defaults(fn=cmd_device, device=dev)
    from daemon.ctl_calib import add_parsers
    from daemon.ctl_datasets import add_parsers as add_dataset_parsers
    from daemon.ctl_keys import add_parser as add_keys_parser

    add_parsers(sub)
    add_dataset_parsers(sub)
    add_keys_parser(sub)
    ctl_fetch.add_parser(sub)
    call = sub.add_parser("call", help="send any bus command")
    call.add_argument("command")
    call.add_argument("args", nargs="?", help="JSON object of arguments")
    call.set_defaults(fn=cmd_call)
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = build_parser()
    a = ap.parse_args(argv)
    verb = getattr(a, "verb", None)
    if verb is not None:
        _check_params(ap, a, verb)
    if getattr(a, "offline", False):
        return a.fn(None, a)
    from daemon.ctl_keys import client_curve

    endpoint = a.endpoint or default_endpoint()
    try:
        curve = client_curve(endpoint, Path(a.keys) if a.keys else None)
    except (OSError, ValueError) as exc:
        print(f"ritactl: cannot use the CURVE keys: {exc}", file=sys.stderr)
        return 2
    client = Client(endpoint, timeout=a.timeout or 5.0, curve=curve)
    try:
        return a.fn(client, a)
    except ClientTimeout as exc:
        print(f"ritactl: {exc.args[0]}", file=sys.stderr)
        return 3
    except CommandError as exc:
        print(f"ritactl: {exc.args[0]} [{exc.code}]", file=sys.stderr)
        return 1
    finally:
        client.close()


if __name__ == "__main__":
    sys.exit(main())
