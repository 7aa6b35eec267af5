"""ritactl verbs on dataset folders, offline (no daemon): ``validate`` and ``recompute``.

``validate FOLDER`` checks a folder against docs/datasets.md and the shipped JSON
Schemas and lists every problem with its file and JSON path. ``recompute FOLDER``
validates, then re-runs the procedure's computation (numpy + OpenCV needed here);
``--out DIR`` writes the result files as the live procedure does, ``--camera-model``,
``--plate`` and ``--calibration`` re-evaluate old data with other inputs. Exit codes
are daemon/ctl/exitcodes.py's: 0/1/2 by verdict, 2 for a calibration error (or any other
failure of the computation, without a traceback), 5 for a missing or invalid dataset
or input file, 64 for usage, 130 for Ctrl-C.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.bus.datasets import DatasetInvalid, Problem, validate_folder
from daemon.ctl.exitcodes import CtlError, Exit, for_verdict
from daemon.ctl.extras import LAPTOP, require
from daemon.ctl.io import fail

if TYPE_CHECKING:  # imported where used: ritactl runs without numpy and OpenCV
    from daemon.compute.recompute import Difference


def _print_problems(folder: str, problems: list[Problem]) -> None:
    for p in problems:
        print(f"  {p}")
    print(f"{folder}: {len(problems)} problem(s)" if problems else f"{folder}: valid")


def cmd_validate(c: Any, a: argparse.Namespace) -> int:
    """Every problem of each dataset folder at once; exit 0 when all are clean, 5 when not."""
    reports = []
    for folder in a.folder:
        try:
            problems = validate_folder(Path(folder))
        except KeyboardInterrupt:
            return Exit.INTERRUPTED
        reports.append({"folder": folder, "problems": [p.to_dict() for p in problems]})
        if not a.json:
            _print_problems(folder, problems)
    if a.json:  # one folder: its report; several: a list of them
        print(json.dumps(reports[0] if len(reports) == 1 else reports, indent=2))
    return Exit.BAD_INPUT if any(r["problems"] for r in reports) else Exit.OK


def _input_file(path: str | None, what: str) -> Any:
    """A JSON input file given on the command line, or None; errors name the file."""
    if not path:
        return None
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"cannot read {what} {path}: {type(exc).__name__}: {exc}") from None


def _run(a: argparse.Namespace) -> tuple[dict[str, Any], Difference | None]:
    from daemon.compute.recompute import recompute

    return recompute(Path(a.dataset), camera_model=_input_file(a.camera_model, "camera model"),
                     plate=_input_file(a.plate, "plate definition"),
                     calibration=_input_file(a.calibration, "calibration result"),
                     compensation=a.compensation)


def _store_bias(a: argparse.Namespace, result: dict[str, Any]) -> dict[str, Any]:
    """The calibration the live ``store_bias`` would store, written to ``--store-bias FILE``."""
    from daemon.compute.recompute import store_bias_offline

    return store_bias_offline(Path(a.dataset), result, Path(a.store_bias),
                              _input_file(a.calibration, "calibration result"))


def _write_out(out: str, dataset: str, result: dict[str, Any]) -> dict[str, Any]:
    from daemon.compute.files import write_result_files

    return write_result_files(Path(out), result, dataset=dataset)


def _single_threaded_opencv() -> None:
    """OpenCV without its own worker threads in this process, unless cv2 is loaded or the user chose.

    A recompute makes many small OpenCV calls (800 marker warps, per-corner refinement) where
    waking OpenCV's workers costs more than it saves, most on a busy machine; the computation
    splits its larger steps over threads itself (calibration.target: the marker warps).
    """
    if "cv2" not in sys.modules:  # read when OpenCV loads
        os.environ.setdefault("OPENCV_FOR_THREADS_NUM", "1")


def cmd_recompute(c: Any, a: argparse.Namespace) -> int:
    """Re-run a procedure's computation offline from its dataset folder (needs numpy + OpenCV here)."""
    _single_threaded_opencv()
    try:  # every package of the extra, the plot's too, before anything is written
        require("ritactl recompute", LAPTOP)
    except CtlError as e:
        return fail(e.exit, e.code, e.args[0], a.json)
    from daemon.compute.recompute import BiasNotStored, CalibrationError, ComputationFailed
    stored: dict[str, Any] = {}
    try:
        result, diff = _run(a)
        if a.out:
            result = _write_out(a.out, a.dataset, result)
        if a.store_bias:
            stored = _store_bias(a, result)
    except KeyboardInterrupt:
        return Exit.INTERRUPTED
    except DatasetInvalid as exc:
        lines = "".join(f"\n  {p}" for p in exc.problems)
        return fail(Exit.BAD_INPUT, "invalid_dataset", f"cannot recompute {a.dataset}: {len(exc.problems)} "
                    f"problem(s) in its files or the given inputs:{lines}", a.json)
    except CalibrationError as exc:
        return fail(Exit.FAIL, "calibration_failed", f"calibration failed on {a.dataset}: {exc}", a.json)
    except ComputationFailed as exc:
        return fail(Exit.FAIL, "computation_failed", f"cannot recompute {a.dataset}: {exc}", a.json)
    except BiasNotStored as exc:  # the result stands (and --out has it); only no calibration was written
        return fail(Exit.FAIL, "bias_not_stored", f"{a.store_bias} not written: {exc}", a.json)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        # the schema passed but a value does not make sense (e.g. a plate whose nests coincide)
        what = f"missing key {exc}" if isinstance(exc, KeyError) else str(exc)
        return fail(Exit.BAD_INPUT, "bad_input", f"cannot recompute {a.dataset}: {what}", a.json)
    except Exception as exc:  # noqa: BLE001 - e.g. cv2.error on a pathological image: still no traceback
        why = f"{type(exc).__name__}: {exc}"
        return fail(Exit.FAIL, "failed", f"recompute of {a.dataset} failed: {why}", a.json)
    if a.json:
        print(json.dumps(result if not a.store_bias else {**result, "stored_calibration": a.store_bias},
                         indent=2, default=str))
    else:
        from daemon.ctl.calib import _show_result

        _show_result({**result, "dataset": a.out or a.dataset})
        if diff is not None and diff.mismatches:
            listed = "".join(f"\n  {m}" for m in diff.mismatches)
            print(f"\nthe stored result differs ({len(diff.mismatches)}):{listed}")
        elif diff is not None:
            print(f"\nlargest difference to the stored result: {diff:.3g}")
        if a.store_bias:
            b = stored["robot_bias_mm"]
            print(f"\ncalibration with b = ({b[0]:+.4f}, {b[1]:+.4f}) mm written to {a.store_bias} "
                  f"(as the live store_bias would store it)")
    return for_verdict(result.get("verdict"))


def add_parsers(sub: Any) -> None:
    p = sub.add_parser("validate", help="check a dataset folder against its documented format (offline)")
    p.add_argument("folder", nargs="+", help="dataset folder(s): a procedure folder or a captures folder")
    p.set_defaults(fn=cmd_validate, offline=True)
    p = sub.add_parser("recompute", help="re-run a procedure offline from its dataset folder")
    p.add_argument("dataset", metavar="DATASET",
                   help="a procedure's dataset folder (its state.json), e.g. one `ritactl fetch` copied")
    p.add_argument("--out", metavar="DIR",
                   help="write result.json, result.yaml (+ experiment report, plot) here")
    p.add_argument("--camera-model", metavar="FILE",
                   help="camera_model.json to use instead of the stored one")
    p.add_argument("--plate", metavar="FILE", help="plate.json to use instead of the stored one")
    p.add_argument("--calibration", metavar="FILE",
                   help="referencing result.json to use instead of the stored one (experiment, measure-mark)")
    p.add_argument("--compensation", metavar="NAMES",
                   help="compensations: none, all, or a comma list of tilt,heading_fit,bias,mount "
                        "(experiment, measure-mark; default: the job's own, the procedure table's when it "
                        "named none). A bad name exits 5")
    p.add_argument("--store-bias", metavar="OUT.json",
                   help="(experiment) write the calibration the live store_bias would store: the "
                        "calibration the experiment used with its fitted b, heading_fit weight and σ check "
                        "(docs/datasets.md)")
    p.set_defaults(fn=cmd_recompute, offline=True)
