"""Offline recompute: the stored observations of a dataset → the same result as the live run.

The folder is validated against its contract first (:func:`daemon.bus.datasets.validate_folder`),
so bad input is reported as a list of problems with file and JSON path, never as a
bare ``KeyError``. ``camera_model`` / ``plate`` / ``calibration`` replace what the
dataset stored: this is how old data is re-evaluated after recalibrating the camera.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from calibration.errors import CalibrationError  # noqa: F401 - re-exported for ritactl recompute
from daemon.bus.procedures import ALL, EXPERIMENT, REFERENCING, get
from daemon.bus.storage import atomic_write_json
from daemon.compute.bias_store import biased_calibration
from daemon.compute.inputs import parse_compensation
from daemon.compute.procedures import COMPUTE, shown_params
from daemon.compute.images import grey_loader
from daemon.bus.datasets import DatasetInvalid, check_file, validate_folder

#: the schema each override file must meet
_OVERRIDE_SCHEMA = {"camera_model": "camera_model", "plate": "plate", "calibration": "result"}


class BiasNotStored(Exception):
    """The experiment's result gives no bias a calibration can hold (ritactl recompute --store-bias: exit
    2)."""


class ComputationFailed(Exception):
    """The computation failed on a dataset that met its contract (ritactl recompute: exit 2)."""


class Difference(float):
    """The largest numeric difference to the stored result; infinite when anything else differs.

    ``mismatches`` names each structural difference by its path in the result (a missing or
    extra key, a list of another length, a changed string, verdict or flag, a number against
    a non-number): a recompute that drops a mark or changes a verdict never passes as "0.0".
    """

    mismatches: list[str]

    def __new__(cls, max_abs: float, mismatches: list[str]) -> "Difference":
        self = super().__new__(cls, math.inf if mismatches else max_abs)
        self.mismatches = mismatches
        return self


def _a(word: str) -> str:
    """``word`` with its indefinite article: "an experiment", "a referencing"."""
    return f"{'an' if word[:1] in 'aeiou' else 'a'} {word}"


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def compare(a: Any, b: Any, path: str = "result") -> tuple[float, list[str]]:
    """(largest numeric difference, mismatches) between a recomputed value ``a`` and the stored ``b``."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = 0.0
        bad = [f"{path}.{k}: missing from the recomputed result" for k in sorted(b.keys() - a.keys())]
        bad += [f"{path}.{k}: not in the stored result" for k in sorted(a.keys() - b.keys())]
        for k in sorted(a.keys() & b.keys()):
            d, m = compare(a[k], b[k], f"{path}.{k}")
            out, bad = max(out, d), bad + m
        return out, bad
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return 0.0, [f"{path}: {len(a)} entries recomputed, {len(b)} stored"]
        out, bad = 0.0, []
        for i, (x, y) in enumerate(zip(a, b)):
            d, m = compare(x, y, f"{path}[{i}]")
            out, bad = max(out, d), bad + m
        return out, bad
    if _number(a) and _number(b):
        d = abs(float(a) - float(b))
        return (d, []) if math.isfinite(d) or a == b else (0.0, [f"{path}: {a!r} recomputed, {b!r} stored"])
    if a == b and type(a) is type(b):
        return 0.0, []
    return 0.0, [f"{path}: {a!r} recomputed, {b!r} stored"]


#: what a recompute must reproduce of the stored result
COMPARED = ("verdict", "rob_H_cam", "rob_H_scn", "mark", "marks", "metrics", "camera_model")


def apply_overrides(root: Path, proc: str, obs: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``obs`` with the given replacement documents, each checked against its schema first."""
    obs = dict(obs)
    for name, doc in overrides.items():
        if doc is None:
            continue
        key = get(proc).inputs.get(name)  # which stored input it replaces: the procedure's declaration says
        if key is None:
            takers = [p.name for p in ALL if name in p.inputs]
            raise ValueError(f"--{name.replace('_', '-')} does not apply to {_a(proc)} dataset "
                             f"(it applies to {', '.join(takers)})")
        problems = check_file(doc, _OVERRIDE_SCHEMA[name], f"--{name.replace('_', '-')}")
        if name == "calibration" and not problems and doc.get("procedure") != REFERENCING.name:
            raise ValueError(f"--calibration must be a referencing result, "
                             f"got procedure {doc.get('procedure')!r}")
        if problems:
            raise DatasetInvalid(root, problems)
        obs[key] = doc
    return obs


def apply_compensation(proc: str, obs: dict[str, Any], compensation: str | None) -> dict[str, Any]:
    """``obs`` with another set of compensations (none, all, or names): a bad name is a ValueError."""
    if compensation is None:
        return obs
    takers = [p.name for p in ALL if any(q.name == "compensation" for q in p.params)]
    if proc not in takers:
        raise ValueError(f"--compensation does not apply to {_a(proc)} dataset "
                         f"(it applies to {', '.join(takers)})")
    parse_compensation(compensation)
    return {**obs, "compensation": compensation}


def recompute(root: Path, *, camera_model: dict[str, Any] | None = None, plate: dict[str, Any] | None = None,
              calibration: dict[str, Any] | None = None, compensation: str | None = None
              ) -> tuple[dict[str, Any], Difference | None]:
    """Return (result, its :class:`Difference` to the stored result.json, or None without one).

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
    try:
        result = COMPUTE[proc](obs, grey_loader(root))
    except (ValueError, KeyError, TypeError, IndexError, ArithmeticError) as exc:
        # the folder met its contract, so this is the computation failing on the data, not bad input
        what = f"the stored data lacks {exc.args[0]!r}" if isinstance(exc, KeyError) else str(exc)
        raise ComputationFailed(f"the {proc} computation failed on the stored data: {what}") from exc
    result["job"] = state.get("job") or root.name
    result["params"] = shown_params(proc, state.get("params") or {})
    given = [k for k, v in (*overrides.items(), ("compensation", compensation)) if v is not None]
    if given:
        result["recomputed_with"] = sorted(given)
        return result, None  # other inputs: a difference to the stored result is expected
    stored_path = root / "result.json"
    if not stored_path.exists():
        return result, None
    stored = json.loads(stored_path.read_text())
    keys = [k for k in COMPARED if k in result or k in stored]
    d, bad = compare({k: result.get(k) for k in keys}, {k: stored.get(k) for k in keys})
    return result, Difference(d, bad)


def store_bias_offline(root: Path, result: dict[str, Any], out: Path,
                       calibration: dict[str, Any] | None = None,
                       stored: str | None = None) -> dict[str, Any]:
    """Write to ``out`` (atomic) the calibration the live ``store_bias`` would make of ``result``: the
    calibration the experiment used (the dataset's, or the ``calibration`` given in its place) with the
    experiment's b, heading_fit weight and σ check (:func:`daemon.compute.bias_store.biased_calibration`, the
    function the worker calls). ``stored``: the record's time stamp (None: now). ValueError for a dataset that
    is no experiment, :class:`BiasNotStored` naming why the result gives no b to store (nothing is
    written)."""
    if result.get("procedure") != EXPERIMENT.name:
        what = _a(str(result.get("procedure")))
        raise ValueError(f"--store-bias applies to an experiment dataset, not {what}")
    used = calibration
    if used is None:
        state = json.loads((Path(root) / "state.json").read_text())
        used = state["obs"][EXPERIMENT.inputs["calibration"]]
    try:
        new = biased_calibration(used, result, stored)
    except ValueError as exc:
        raise BiasNotStored(f"robot-frame bias NOT stored: {exc}") from None
    atomic_write_json(Path(out), new)
    return new
