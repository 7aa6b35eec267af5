"""The bus commands, declared once: arguments (type, range, unit, default), role, help, CLI shape.

The table drives: the daemon's argument validation (``validate``: handlers receive checked,
defaulted args), the ``help`` command (``help_entry``), ritactl's per-device subcommands
(``daemon/ctl/device.py``), the bus fuzzer's argument generator and the command table in
docs/protocol.md (``python -m daemon.bus.command_table --markdown``; a test compares).
Stdlib and msgpack only, so the laptop client imports it without numpy or OpenCV.

Arguments are :class:`daemon.bus.args.Arg` (type, range, unit, default, CLI shape); the
procedures ``calib.start`` runs are declared in daemon/bus/procedures.py.
"""
from __future__ import annotations

import copy
import dataclasses
import json
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Iterator, Mapping

from daemon.bus.args import POS, REQUIRED, Arg, BadValue
from daemon.bus.procedures import PROCEDURES
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.names import ROLES



@dataclass(frozen=True)
class Command:
    name: str
    help: str
    role: str = "viewer"
    args: tuple[Arg, ...] = ()
    result: str = ""
    cli: tuple[str, ...] = ()      # words of a generated ritactl subcommand, e.g. ("tracker", "aim")
    verb: str = ""                 # or: the hand-written ritactl verb that sends it
    worker_only: bool = False
    #: "moves": drives something physical (logged with the caller, refused while the stop is latched);
    #: "stops": halts it (logged, never refused)
    motion: str = ""
    #: read that pages, ritactl and the worker poll: logged at DEBUG, not INFO
    polled: bool = False
    #: who declares it: "" for the product, else the plugin's name (daemon/ritad/plugins.py)
    plugin: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


_CONFIRM = Arg("confirm", "bool", "confirm that the robot may move", default=False, cli="--yes")
_WAIT = Arg("wait", "bool", "return once the motion started instead of at its end", default=True,
            cli="--no-wait")


def _motion_timeout(how_far: str, speed: str) -> Arg:
    return Arg("timeout_s", "float", "give up on the motion after this long", unit="s", lo=0, lo_open=True,
               default_text=f"60 + 2 × |{how_far}| / {speed}")


def _job(help_: str = "job id") -> Arg:
    return Arg("job", "str", help_, default=REQUIRED, cli=POS, metavar="JOB")


_KEY_NAME = Arg("name", "str", "the key's name in the allow-list", default=REQUIRED)

TABLE: tuple[Command, ...] = (
    Command("ping", "liveness check", result="{pong, t_ns}", polled=True),
    Command("help", "list the commands", result="{commands: {name: {help, role, result, worker_only, args: "
            "[{name, type, unit, range, choices, required, default, help}]}}}", polled=True),
    Command("hello", "who is this daemon: version, schema, endpoints",
            result="name, version, schema, pid, sim, endpoints, device URLs", polled=True),
    Command("status", "device states at a glance", verb="status", result="the daemon.health payload",
            polled=True),
    Command("state", "Clone snapshot for late joiners", verb="watch",
            result="{seq, latest: {topic: {seq, t_ns, data}}, devices}", polled=True),
    Command("tracker.measure", "one stationary point of the locked reflector", "operator",
            cli=("tracker", "measure"),
            result="stationary point: x y z (mm, tracker frame), abs_xyz (ACS via tracker.abs_H_trk), "
                   "abs_H_trk (the 4×4 used), std, environment, tracker status, host_time_ns, "
                   "host_monotonic_ns",
            polled=True),
    Command("tracker.aim", "turn the tracker head to a point", "operator", cli=("tracker", "aim"), args=tuple(
        Arg(k, "float", f"{k.upper()} of the point, tracker frame", unit="mm", default=REQUIRED, cli=POS,
            metavar=k.upper()) for k in "xyz"), result="{aimed}", motion="moves"),
    Command("tracker.find", "search and lock the reflector near where the tracker points", "operator",
            cli=("tracker", "find"), result="{locked: true}; tracker_<Status> when nothing is found", args=(
                Arg("approx_distance_mm", "float", "approximate distance to the reflector", unit="mm", lo=0,
                    lo_open=True, default_text="the tracker's own search", cli="--distance", metavar="MM"),),
            motion="moves"),
    Command("tracker.stream.start", "stream tracker points as tracker.point telemetry", "operator",
            cli=("tracker", "stream", "start"),
            result="{streaming, rate_hz: the rate streamed, after any clamp}; points then flow as "
                   "tracker.point",
            args=(
                Arg("rate_hz", "float", "points per second", unit="Hz", lo=0, lo_open=True, hi=10000,
                    default_text="config [tracker] stream_rate_hz", cli="--rate", metavar="HZ"),)),
    Command("tracker.stream.stop", "stop the point stream", "operator", cli=("tracker", "stream", "stop"),
            result="{streaming: false}"),
    Command("tracker.status", "tracker adapter status and counters", cli=("tracker", "status"),
            result="adapter status and counters; clock: the tracker clock's mapping onto the host's from its "
                   "stream packets {source (clockmap, null before the first), offset_ns, drift_ppm, "
                   "sigma_ns, samples, window_s, two_way, resets}; sigma_ns leaves out the latency's fixed "
                   "part (docs/architecture.md, Time)",
            polled=True),
    Command("tracker.readback", "what the controller holds now: frames, environment, packet rate "
            "(ritactl commission)", cli=("tracker", "readback"),
            result="{apply_station_orientation_params, apply_transformation_params, station_orientation, "
                   "transformation, weather_monitor_status, environment {temperature, pressure, humidity}, "
                   "packet_rate}"),
    Command("camera.capture", "trigger one frame", "operator", cli=("camera", "capture"),
            result="{header, path?}; pixels as one attachment", args=(
                Arg("pixels", "bool", "send the pixels back as an attachment", default=False),
                Arg("save", "bool", "store the frame as a dataset entry on the robot",
                    default_text="not pixels"),
                Arg("label", "str", "name of the stored entry", default="frame", cli="--label")),
            polled=True),
    Command("camera.stream.start", "free-running frames on the frame socket", "operator",
            cli=("camera", "stream", "start"), result="{streaming: true}"),
    Command("camera.stream.stop", "stop the free run", "operator", cli=("camera", "stream", "stop"),
            result="{streaming: false}"),
    Command("camera.status", "applied camera settings, warnings, counters, ptp (PTP status), link "
            "(GigE link statistics) and clock (how frames are timed)", cli=("camera", "status"),
            result="applied settings, warnings, counters, ptp, link; clock: how the newest frame was put on "
                   "the host's timeline {source (ptp, clockmap or host; null before the first frame), "
                   "offset_ns (host − device), drift_ppm, sigma_ns, samples, window_s, two_way, resets, ptp "
                   "(the camera's PTP state at that frame), note (why PTP is not used, else null); with "
                   "source ptp also clockmap {offset_ns, drift_ppm, sigma_ns}, the map kept as fallback} "
                   "(docs/architecture.md, Time)",
            polled=True),
    Command("camera.preview", "the newest streamed frame, small (or a full-resolution region), as one JPEG "
            "attachment: live views over a thin link", verb="console",
            result="{header, format: jpeg, x, y, w, h, step, out_w, out_h, full_w, full_h}: the region shown "
                   "(sensor px) and the stride; {unchanged: true, frame_id} while the newest frame's id is "
                   "after; not_found before the first streamed frame", args=(
                Arg("width", "int", "largest width of the picture", unit="px", default=640, lo=16, hi=4096),
                Arg("roi_x", "int", "left edge of the region", unit="px", lo=0, default_text="0"),
                Arg("roi_y", "int", "top edge of the region", unit="px", lo=0, default_text="0"),
                Arg("roi_w", "int", "region width", unit="px", lo=1, default_text="the whole frame"),
                Arg("roi_h", "int", "region height", unit="px", lo=1, default_text="the whole frame"),
                Arg("quality", "int", "JPEG quality", default=80, lo=10, hi=95),
                Arg("after", "int", "frame id the client already shows", default=-1, lo=-1)), polled=True),
    Command("camera.detect", "the plate target's ChArUco corners or a floor mark in the newest streamed "
            "frame, on demand (one detection at a time)", cli=("camera", "detect"),
            result="{target, frame_id, full_w, full_h, searched_w, searched_h, found, n, uv: sensor px "
                   "(corners: [[u, v], ...] with ids and plate_id; mark: [u, v]), took_s}; mark not found: "
                   "{found: false, message}; busy while a detection runs", args=(
                Arg("target", "str", "what to look for", default="plate", choices=("plate", "dot", "cross"),
                    cli="--target"),
                Arg("plate_file", "str", "plate definition (data-dir path) for target plate",
                    default="calibration/plate.json", cli="--plate-file", metavar="FILE"),
                Arg("width", "int", "search a copy downscaled to this width (faster, coarser)", unit="px",
                    lo=64, hi=16384, default_text="the full frame", cli="--width", metavar="PX"),
                Arg("size_px", "float", "mark size (dot radius or cross half-size) in sensor px: searches "
                    "coarse to fine", unit="px", lo=0, lo_open=True,
                    default_text="unknown: full-resolution search", cli="--size", metavar="PX")),
            polled=True),
    Command("robot.move", "drive straight (negative: backwards)", "operator", cli=("robot", "move"),
            result="controller's DONE, or {started} with wait: false", args=(
                Arg("distance_mm", "float", "distance to drive (limit: config [robot] max_distance_mm)",
                    unit="mm", default=REQUIRED, cli=POS, metavar="MM"),
                Arg("speed_mm_s", "float", "speed (limit: config [robot] max_speed_mm_s)", unit="mm/s",
                    default=50.0, lo=0, lo_open=True, cli="--speed", metavar="MM_S"),
                _CONFIRM, _WAIT, _motion_timeout("distance_mm", "speed_mm_s")), motion="moves"),
    Command("robot.turn", "turn on the spot (positive: counter-clockwise)", "operator", cli=("robot", "turn"),
            result="as robot.move", args=(
                Arg("angle_deg", "float", "angle to turn", unit="°", default=REQUIRED, lo=-360, hi=360,
                    cli=POS, metavar="DEG"),
                Arg("speed_deg_s", "float", "turn rate (limit: config [robot] max_turn_speed_deg_s)",
                    unit="°/s", default=20.0, lo=0, lo_open=True, cli="--speed", metavar="DEG_S"),
                _CONFIRM, _WAIT, _motion_timeout("angle_deg", "speed_deg_s")), motion="moves"),
    Command("robot.stop", "stop the base now and latch: every job that drives is stopped, every motion "
            "refused until robot.release (any key may stop; no confirmation)", "viewer",
            cli=("robot", "stop"), result="{stopped, latched, jobs_stopped}", motion="stops"),
    Command("robot.release", "clear a latched stop: motions and robot jobs are allowed again (stopped jobs "
            "continue only on calib.resume)", "operator", cli=("robot", "release"),
            result="{released, was_latched}"),
    Command("robot.commission", "the base firmware's conformance checks (drivers/robot_conformance) run on "
            "ritad's own port: reachable, versions, reply latency, t_us; with allow_motion the host watchdog "
            "and STOP's braking (ritactl commission)", "operator", cli=("robot", "conformance"),
            result="{port, checks: [{name, verdict (pass, fail, warn, skip), value, detail}]}",
            motion="moves",
            args=(
                Arg("allow_motion", "bool", "run the checks that drive the base (~0.1 m forwards)",
                    default=False, cli="--allow-motion"),
                Arg("clock_s", "float", "how long the base's clock is polled", unit="s", lo=0.5, hi=600,
                    default=5.0, cli="--clock-s", metavar="S"),
                _CONFIRM)),
    Command("robot.status", "base state, odometry, inclination, battery", cli=("robot", "status"),
            result="RobotState: state IDLE/MOVING/FAULT, x_mm y_mm heading_deg, roll_deg pitch_deg (with an "
                   "inclinometer), battery_v, fault, host_time_ns, t_us (the base's clock, protocol 2; else "
                   "null); streams: the sample topics the base sends (robot.odometry, robot.incl; [] from a "
                   "version-1 base); clock: the base clock's mapping onto the host's from its samples, as in "
                   "tracker.status",
            polled=True),
    Command("capture", "image + tracker point + robot state, stored as a dataset entry", "operator",
            verb="capture",
            result="{path, header, tracker, robot, at_exposure}: tracker is a stationary measurement, null "
                   "while the tracker streams; at_exposure holds the tracker's stream, the base's pose and "
                   "its tilt at the frame's exposure (interpolated, with the gap bridged)",
            args=(
                Arg("label", "str", "name of the entry", default="capture", cli="--label"),
                Arg("dataset", "str", "dataset folder name", default_text="today's captures",
                    cli="--dataset"))),
    Command("data.dir", "the daemon's data folder", result="{data_dir}", polled=True),
    Command("files.list", "regular files under a data-dir folder (secrets never listed)", verb="fetch",
            result="{root, files: [{path, size, mtime_ns}], truncated}: paths relative to data_dir with /; "
                   "at most 20000 entries",
            args=(Arg("path", "str", "folder or file relative to the data dir",
                      default_text="the whole data dir"),),
            polled=True),
    Command("files.read", "one chunk of a data-dir file; the bytes follow as an attachment", verb="fetch",
            result="{path, offset, length, size, mtime_ns, eof}; fewer than length bytes at the end of the "
                   "file",
            args=(
                Arg("path", "str", "file relative to the data dir", default=REQUIRED),
                Arg("offset", "int", "first byte", unit="B", default=0, lo=0),
                Arg("length", "int", "bytes to read", unit="B", default=1048576, lo=0, hi=1048576)),
            polled=True),
    Command("files.hash", "sha256 of the first length bytes of a data-dir file", verb="fetch",
            result="{path, length, size, sha256}", args=(
                Arg("path", "str", "file relative to the data dir", default=REQUIRED),
                Arg("length", "int", "bytes to hash", unit="B", lo=0, default_text="the whole file")),
            polled=True),
    Command("calib.results", "active calibration and every stored result", verb="results",
            result="{active, history}", polled=True),
    Command("calib.plate.upload", "store a plate definition (e.g. surveyed on the laptop) as "
            "calibration/NAME on the robot, checked against plate.schema.json first; a file it replaces is "
            "kept in calibration/history/plates/",
            "operator", verb="plate upload",
            result="{path, sha256, size, replaced, unchanged}: data-dir paths",
            args=(
                Arg("plate", "map", "the plate definition (the object of a plate.json)", default=REQUIRED),
                Arg("name", "str", "file name in the robot's calibration folder", default="plate.json"))),
    Command("calib.resume", "queue a failed, cancelled or stopped job again; the worker continues from its "
            "checkpoint (a stopped one only after robot.release)",
            "operator", verb="resume", result="{job, worker_seen_s_ago}", args=(_job(),)),
    Command("calib.start", "post a calibration job (an existing job id resumes it)", "operator",
            verb="calibrate", result="{job, worker_seen_s_ago}", args=(
                Arg("procedure", "str", "what to run", default=REQUIRED, choices=PROCEDURES),
                Arg("params", "map", "the procedure's parameters, checked against its table in "
                    "daemon/bus/procedure_params.py (types, ranges, names; a definition file as the JSON "
                    "object)", default={}),
                Arg("job", "str", "job id", default_text="generated"))),
    Command("calib.answer", "answer a job's prompt", "operator", verb="answer",
            result="{delivered}; answer must be one of the prompt's choices",
            args=(_job(), Arg("answer", "str", "the answer", default=REQUIRED, cli=POS, metavar="TEXT"))),
    Command("calib.cancel", "ask the worker to stop a job", "operator", verb="cancel",
            result="{cancel_requested, state}; the job's data stays (calib.resume continues it)",
            args=(_job(),)),
    Command("calib.jobs", "calibration jobs and their state", verb="jobs",
            result="{jobs: [{job, procedure, state, progress, result, prompt, error, params, by, "
            "posted_ns}], queued, worker_seen_s_ago}", polled=True),
    Command("calib.next", "worker: long-poll for the next job", "operator", worker_only=True,
            result="the job, or null on timeout",
            args=(
        Arg("timeout_s", "float", "long-poll time", unit="s", default=10.0, lo=0, hi=60),), polled=True),
    Command("calib.inbox", "worker: long-poll for answers and cancels of a job", "operator",
            worker_only=True, result="{answer} or {cancel: true}, or null on timeout",
            args=(_job(), Arg("timeout_s", "float", "long-poll time", unit="s", default=0.0, lo=0, hi=60)),
            polled=True),
    Command("calib.report", "worker: progress, prompt, result or error of a job", "operator",
            worker_only=True,
            result="{ok}; republished as calib.progress, calib.prompt or calib.result telemetry",
            args=(_job(), Arg("kind", "str", "report kind", default=REQUIRED,
                              choices=("progress", "result", "prompt", "error")),
                  Arg("data", "any", "the report", default_text="{}"),
                  Arg("procedure", "str", "procedure of a resumed job",
                      default_text="the posted job's")),
            polled=True),
    Command("keys.list", "the allow-list: names, roles and public keys of the CURVE keys", "admin",
            verb="keys", result="{dir, keys: [{name, role, public_key}], unreadable: {file: why}}"),
    Command("keys.allow", "allow a CURVE key with a role (replaces an entry of that name)", "admin",
            verb="keys", result="{name, role, public_key}", args=(
                _KEY_NAME,
                Arg("public_key", "str", "the client's public key (z85, 40 characters)", default=REQUIRED),
                Arg("role", "str", "what the key may do", default="viewer", choices=ROLES))),
    Command("keys.role", "change the role of an allowed key", "admin", verb="keys",
            result="{name, role, public_key}", args=(
                _KEY_NAME, Arg("role", "str", "what the key may do", default=REQUIRED, choices=ROLES))),
    Command("keys.revoke", "remove a key from the allow-list (its open connections too)", "admin",
            verb="keys", result="{revoked}", args=(_KEY_NAME,)),
)

assert len({c.name for c in TABLE}) == len(TABLE), "duplicate command in TABLE"
assert all(c.role in ROLES for c in TABLE)
assert all(c.motion in ("", "moves", "stops") for c in TABLE)


class CommandTable(Mapping[str, Command]):
    """The commands one ritad serves: the product's ``TABLE`` and the plugins' it registered.

    An instance, owned by the daemon that registers into it; the product's table alone is
    ``COMMANDS`` (what the laptop client knows without asking a daemon's ``help``).
    """

    def __init__(self, commands: tuple[Command, ...] = TABLE) -> None:
        self._by_name: dict[str, Command] = {c.name: c for c in commands}

    def __getitem__(self, name: str) -> Command:
        return self._by_name[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._by_name)

    def __len__(self) -> int:
        return len(self._by_name)

    def register(self, plugin: str, commands: tuple[Command, ...]) -> None:
        """Add a plugin's commands: same validation, roles and logging as the product's.

        A name the product or another plugin already declares is refused, so a plugin can never
        replace a product command; registering the same plugin's commands again is a no-op.
        """
        for c in commands:
            if not c.name.startswith(f"{plugin}."):
                raise ValueError(f"plugin {plugin!r}: command {c.name!r} must be named {plugin}.<verb>")
            if c.role not in ROLES or c.motion not in ("", "moves", "stops"):
                raise ValueError(f"plugin {plugin!r}: command {c.name!r}: bad role {c.role!r} "
                                 f"or motion {c.motion!r}")
            known = self._by_name.get(c.name)
            if known is not None and known.plugin != plugin:
                raise ValueError(f"plugin {plugin!r}: command {c.name!r} is already declared "
                                 f"by {known.plugin or 'the product'}")
        for c in commands:
            self._by_name[c.name] = c if c.plugin == plugin else dataclasses.replace(c, plugin=plugin)

    def moves(self, cmd: str) -> bool:
        """``cmd`` drives something physical: refused while the stop is latched."""
        c = self._by_name.get(cmd)
        return c is not None and c.motion == "moves"

    def validate(self, cmd: str, args: dict[str, Any]) -> dict[str, Any]:
        """Every declared argument of ``cmd``, checked and defaulted (:func:`validate`)."""
        return check_args(self._by_name[cmd], args)


#: the product's commands (a read-only view: plugins register into a daemon's own ``CommandTable``)
COMMANDS: Mapping[str, Command] = MappingProxyType({c.name: c for c in TABLE})


def moves(cmd: str) -> bool:
    """``cmd`` (a product command) drives something physical: refused while the stop is latched."""
    c = COMMANDS.get(cmd)
    return c is not None and c.motion == "moves"

# ---------------------------------------------------------------------------- validation

def _bad(cmd: str, text: str) -> CommandError:
    return CommandError(ErrorCode.BAD_ARGS, f"{cmd}: {text}")


def check_arg(cmd: str, arg: Arg, value: Any) -> Any:
    """``value`` checked against ``arg`` (:meth:`Arg.checked`); ``bad_args`` names command and argument."""
    try:
        return arg.checked(value)
    except BadValue as exc:
        raise _bad(cmd, str(exc)) from None


def validate(cmd: str, args: dict[str, Any]) -> dict[str, Any]:
    """Every declared argument of the product command ``cmd``, checked and defaulted (:func:`check_args`)."""
    return check_args(COMMANDS[cmd], args)


def check_args(command: Command, args: dict[str, Any]) -> dict[str, Any]:
    """Every declared argument of ``command``, checked and defaulted; ``bad_args`` names the first bad one.

    An optional argument whose default is None ("the daemon decides") may also be sent as null.
    Keys the table does not declare are ignored (older and newer clients keep working).
    """
    cmd = command.name
    out: dict[str, Any] = {}
    for arg in command.args:
        value = args.get(arg.name)
        if arg.name not in args or (value is None and arg.default is None):
            if arg.required:
                raise _bad(cmd, f"missing argument {arg.name!r} ({arg.kind_text()})")
            out[arg.name] = copy.deepcopy(arg.default)  # a handler may keep a default map
            continue
        out[arg.name] = check_arg(cmd, arg, value)
    return out


# ---------------------------------------------------------------------------- help and docs

def _default_text(arg: Arg) -> str:
    if arg.required:
        return "required"
    if arg.default is None:
        return arg.default_text or "optional"
    return json.dumps(arg.default)


def help_entry(cmd: Command) -> dict[str, Any]:
    """What the ``help`` command says about ``cmd``."""
    return {"help": cmd.help, "role": cmd.role, "result": cmd.result, "worker_only": cmd.worker_only,
            "args": [{"name": a.name, "type": a.type, "unit": a.unit, "range": a.range_text(),
                      "choices": list(a.choices), "required": a.required, "default": _default_text(a),
                      "help": a.help} for a in cmd.args]}


def markdown_table(commands: tuple[Command, ...] = TABLE) -> str:
    """The command table of docs/protocol.md, generated from ``TABLE`` (or a plugin's commands)."""
    rows = ["| command | role | args | result | what it does |", "|---|---|---|---|---|"]
    for c in commands:
        args = "<br>".join(_arg_cell(a) for a in c.args) or "–"
        what = c.help + (" *(polled)*" if c.polled else "")  # polled: not reported on daemon.command
        result = c.result.replace("|", "\\|") or "–"  # a bar inside a cell would split it
        rows.append(f"| `{c.name}` | {c.role} | {args} | {result} | {what} |")
    return "\n".join(rows) + "\n"


def _arg_cell(arg: Arg) -> str:
    facts = [arg.type + (f", {arg.unit}" if arg.unit else "")]
    if arg.range_text():
        facts.append(arg.range_text())
    if arg.choices:
        facts.append(" \\| ".join(f"`{c}`" for c in arg.choices))
    if not arg.required:
        facts.append(f"default {_default_text(arg)}")
    return f"`{arg.name}`{'' if arg.required else '?'} ({'; '.join(facts)})"


if __name__ == "__main__":
    import sys

    if sys.argv[1:] != ["--markdown"]:
        sys.exit("usage: python -m daemon.bus.command_table --markdown")
    sys.stdout.write(markdown_table())
