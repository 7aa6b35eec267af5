"""Starting a procedure from the page: its form's values checked again here, files read on the robot.

The page builds its form from ``daemon.bus.procedures.schema()`` and checks what it
can, but the console never trusts it: every ``calib.start`` a page sends comes through
``start_job``, which checks the parameters against the same table, reads each chosen
definition file (a data-dir path on the robot) with ``files.read`` and sends the parsed
object, as ``ritactl calibrate --plate FILE`` sends the file it read.
"""
from __future__ import annotations

from typing import Any

from daemon.bus.procedures import check_params, load_files
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.console.bridge import Bridge

#: a definition file larger than this is not a plate, model or board definition
MAX_DEFINITION_BYTES = 16 << 20


def read_robot_file(bridge: Bridge, path: str, limit: int = MAX_DEFINITION_BYTES) -> bytes:
    """A data-dir file of the robot, whole (``files.read`` chunk by chunk); not_found names it."""
    out, offset = bytearray(), 0
    while True:
        meta, parts = bridge.call_raw("files.read", {"path": path, "offset": offset}, 30.0)
        if meta["size"] > limit:
            raise CommandError(ErrorCode.BAD_ARGS, f"{path}: {meta['size']} B, more than a definition file "
                                                   f"({limit} B)")
        chunk = parts[0] if parts else b""
        out += chunk
        offset += len(chunk)
        if meta.get("eof") or not chunk:
            return bytes(out)


def start_job(bridge: Bridge, args: dict[str, Any], timeout: float = 30.0) -> Any:
    """``calib.start`` with the page's procedure and parameters, checked and with files loaded."""
    procedure = args.get("procedure")
    if not isinstance(procedure, str):
        raise CommandError(ErrorCode.BAD_ARGS, f"calib.start: procedure must be a name, got {procedure!r}")
    params = load_files(procedure, check_params(procedure, args.get("params", {})),
                        lambda path: read_robot_file(bridge, path))
    start = {"procedure": procedure, "params": params}
    if isinstance(args.get("job"), str) and args["job"]:
        start["job"] = args["job"]
    return bridge.call("calib.start", start, timeout)
