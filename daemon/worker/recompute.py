"""Offline recompute: the stored observations of a dataset → the same result as the live run.

The folder is validated against its contract first (:func:`daemon.bus.datasets.validate_folder`),
so bad input is reported as a list of problems with file and JSON path, never as a
bare ``KeyError``. ``camera_model`` / ``plate`` / ``calibration`` replace what the
dataset stored: this is how old data is re-evaluated after recalibrating the camera.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from calibration.errors import CalibrationError  # noqa: F401 - re-exported for ritactl recompute
from daemon.worker.compensations import parse_compensation
from daemon.worker.compute import COMPUTE
from daemon.worker.images import grey_loader
from daemon.bus.datasets import DatasetInvalid, check_file, validate_folder

#: which stored inputs each override replaces, per procedure (obs key)
OVERRIDES = {"camera_model": {"referencing": "camera_model", "intrinsics": "initial_model"},
             "plate": {"referencing": "plate", "intrinsics": "plate"},
             "calibration": {"experiment": "calibration", "measure-mark": "calibration"}}
#: the schema each override file must meet
_OVERRIDE_SCHEMA = {"camera_model": "camera_model", "plate": "plate", "calibration": "result"}


def _load(root: Path):
    return grey_loader(root)


def _max_diff(a: Any, b: Any) -> float:
    if isinstance(a, dict) and isinstance(b, dict):
        return max([_max_diff(a[k], b[k]) for k in a.keys() & b.keys()] or [0.0])
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)) and len(a) == len(b):
        return max([_max_diff(x, y) for x, y in zip(a, b)] or [0.0])
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return abs(float(a) - float(b))
    return 0.0


def apply_overrides(root: Path, proc: str, obs: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``obs`` with the given replacement documents, each checked against its schema first."""
    obs = dict(obs)
    for name, doc in overrides.items():
        if doc is None:
            continue
        key = OVERRIDES[name].get(proc)
        if key is None:
            raise ValueError(f"--{name.replace('_', '-')} does not apply to a {proc} dataset "
                             f"(it applies to {', '.join(OVERRIDES[name])})")
        problems = check_file(doc, _OVERRIDE_SCHEMA[name], f"--{name.replace('_', '-')}")
        if name == "calibration" and not problems and doc.get("procedure") != "referencing":
            raise ValueError(f"--calibration must be a referencing result, got procedure {doc.get('procedure')!r}")
        if problems:
            raise DatasetInvalid(root, problems)
        obs[key] = doc
    return obs


def apply_compensation(proc: str, obs: dict[str, Any], compensation: str | None) -> dict[str, Any]:
    """``obs`` with another set of issue #15 compensations (none, all, or names): a bad name is a ValueError."""
    if compensation is None:
        return obs
    if proc not in ("experiment", "measure-mark"):
        raise ValueError(f"--compensation does not apply to a {proc} dataset (it applies to experiment, measure-mark)")
    parse_compensation(compensation)
    return {**obs, "compensation": compensation}


def recompute(root: Path, *, camera_model: dict[str, Any] | None = None, plate: dict[str, Any] | None = None,
              calibration: dict[str, Any] | None = None, compensation: str | None = None
              ) -> tuple[dict[str, Any], float | None]:
    """Return (result, largest numeric difference to the stored result.json or None).

    Raises :class:`DatasetInvalid` listing every problem of the folder, ``ValueError``
    for an override that does not fit, and whatever the computation raises
    (``CalibrationError`` when the data cannot give a trustworthy result).
    """
    root = Path(root)
    problems = validate_folder(root)
    if problems:
        raise DatasetInvalid(root, problems)
    state = json.loads((root / "state.json").read_text())
    proc = state["procedure"]
    overrides = {"camera_model": camera_model, "plate": plate, "calibration": calibration}
    obs = apply_compensation(proc, apply_overrides(root, proc, state["obs"], overrides), compensation)
    result = COMPUTE[proc](obs, _load(root))
    result["job"] = state.get("job") or root.name
    result["params"] = {k: v for k, v in (state.get("params") or {}).items()
                        if k not in ("plate", "camera_model", "calibration")}
    overrides["compensation"] = compensation
    if any(v is not None for v in overrides.values()):
        result["recomputed_with"] = sorted(k for k, v in overrides.items() if v is not None)
        return result, None  # other inputs: a difference to the stored result is expected
    diff = None
    stored_path = root / "result.json"
    if stored_path.exists():
        stored = json.loads(stored_path.read_text())
        keys = [k for k in ("rob_H_cam", "rob_H_scn", "mark", "marks", "metrics", "camera_model") if k in result]
        diff = max([_max_diff(result[k], stored.get(k)) for k in keys] or [0.0])
    return result, diff
