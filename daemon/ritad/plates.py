"""``calib.plate.upload``: a plate definition from the laptop into the robot's calibration folder.

The plate survey runs on the laptop (``ritactl plate survey``, the console's survey panel);
referencing runs on the robot and reads its plate file there. This puts one checked plate
definition at ``calibration/<name>`` so the referencing form can name it. The definition is
checked against the plate schema and its value rules before anything is written; a file it
replaces is kept in ``calibration/history/plates/`` (data already written is never lost);
the write is atomic (temp file + fsync + rename).
"""
from __future__ import annotations

import hashlib
import json
import logging
import re
import time
from pathlib import Path
from typing import Any

from daemon.bus.datasets import check_file
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.storage import atomic_write_bytes, calibration_dir

log = logging.getLogger("ritad.plates")

#: a file name in the calibration folder: no folders, no hidden files, .json
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,79}\.json$")
#: names the worker owns in the calibration folder: never replaced by an upload
RESERVED = frozenset({"active.json", "camera_model.json", "tracker_station.json"})


def _checked_name(name: str) -> str:
    if not NAME.match(name) or ".." in name:
        raise CommandError(ErrorCode.BAD_ARGS,
                           f"calib.plate.upload: name={name!r} must be a file name like plate.json "
                           f"(letters, digits, _ . -; ending .json; no folders)")
    if name in RESERVED:
        raise CommandError(ErrorCode.BAD_ARGS, f"calib.plate.upload: name={name!r} is the worker's own "
                                               f"file in the calibration folder: choose another name")
    return name


def _checked_plate(plate: dict[str, Any], name: str) -> bytes:
    problems = check_file(plate, "plate", name)
    if problems:
        listed = "; ".join(f"{p.path}: {p.message}" for p in problems[:8])
        more = f" (and {len(problems) - 8} more)" if len(problems) > 8 else ""
        raise CommandError(ErrorCode.BAD_ARGS,
                           f"calib.plate.upload: the plate is not a valid plate definition "
                           f"(docs/datasets.md, plate.schema.json): {listed}{more}")
    return (json.dumps(plate, indent=2) + "\n").encode("utf-8")


def store_plate(data_dir: Path, plate: dict[str, Any], name: str, who: str) -> dict[str, Any]:
    """Check and write ``plate`` as ``calibration/<name>``; an existing file moves to the history first."""
    name = _checked_name(name)
    data = _checked_plate(plate, name)
    cdir = calibration_dir(data_dir)
    target = cdir / name
    kept = None
    if target.exists():
        if target.read_bytes() == data:
            return _answer(data_dir, target, data, None, unchanged=True)
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        kept = cdir / "history" / "plates" / f"{target.stem}-{stamp}-{time.time_ns() % 1_000_000:06d}.json"
        atomic_write_bytes(kept, target.read_bytes())  # a copy first: the old plate survives a failure below
    atomic_write_bytes(target, data)
    log.info("plate %s stored by %s (plate_id %s%s)", target, who, plate.get("plate_id"),
             f"; the previous one kept as {kept}" if kept else "")
    return _answer(data_dir, target, data, kept, unchanged=False)


def _answer(data_dir: Path, target: Path, data: bytes, kept: Path | None, unchanged: bool) -> dict[str, Any]:
    def rel(p: Path) -> str:  # data-dir paths as files.* use them
        return str(p.relative_to(data_dir)).replace("\\", "/")

    return {"path": rel(target), "sha256": hashlib.sha256(data).hexdigest(), "size": len(data),
            "replaced": rel(kept) if kept else None, "unchanged": unchanged}
