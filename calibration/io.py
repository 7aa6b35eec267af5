"""The calibration's only file I/O: reading plate files (JSON).

Everything else in ``calibration/`` works on arrays and dicts. It writes no files: callers
serialise with ``to_dict()`` and write through the project's one atomic write
(daemon/bus/storage.py), which calibration, importing nothing of ours, cannot use itself.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from calibration.plate import Plate


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a JSON {what} ({exc})") from None


def load_plate(path: str | Path) -> Plate:
    """Read a plate file (OSError if unreadable, ValueError naming the file and key if bad)."""
    return Plate.from_dict(_read_json(Path(path), "plate definition"), source=str(path))
