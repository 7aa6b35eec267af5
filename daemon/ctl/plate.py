"""``ritactl plate survey FOLDER`` (offline, on this computer) and ``plate upload FILE`` (to the robot).

``plate upload`` sends a plate definition, e.g. the surveyed one, to the robot's calibration
folder over the bus (``calib.plate.upload``, an operator's command; the daemon checks it
against the plate schema and keeps a file it replaces): referencing then names it as
``calibration/NAME``. Exit codes: 0 stored, 5 an unreadable file, 4 refused by the daemon
(the message names the bad field).

Computes here (numpy + OpenCV needed), like ``ritactl recompute``: the photographs
are on the laptop and the survey needs no robot (docs/operations.md, "Plate survey").
Exit codes (daemon/ctl/exitcodes.py): 0 verdict ok, 1 warn (a nest's 1σ above 50 µm),
2 the survey failed (no or too few usable photographs, a ring not found in enough of
them: the message names the photograph and colour), 5 a bad input file or folder
(none, unreadable, grey images, a plate definition without patches), 64 usage.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from daemon.ctl.exitcodes import CtlError, Exit, for_verdict
from daemon.ctl.extras import LAPTOP, require
from daemon.ctl.io import fail, say


def _read_plate(path: str) -> Any:
    """The file's JSON, whatever it holds (the callers check it is a plate definition)."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"cannot read plate definition {path}: {type(exc).__name__}: {exc}") from None


def _show(plate: dict[str, Any], out: str) -> None:
    rep = plate["survey"]
    print(f"{rep['verdict'].upper()}: {rep['message']}")
    for c, n in rep["nests"].items():
        x, y, z = n["ref_P_nst_mm"]
        sx, sy, sz = (s * 1000 for s in n["sigma_mm"])
        print(f"  {c:5s} seat ({x:9.3f}, {y:9.3f}, {z:7.3f}) mm  1σ ({sx:4.0f}, {sy:4.0f}, {sz:4.0f}) µm  "
              f"from {n['views']} photographs")
    print(f"  corners σ {rep['sigma_corner_px']:.3f} px, rings σ {rep['sigma_ring_px']:.3f} px; "
          f"k3 {'fitted' if rep['k3_fitted'] else 'fixed at 0 (not supported by the data)'}")
    for v in rep["views"]:
        rings = ", ".join(f"{c} {r:.2f}" for c, r in v["ring_residual_px"].items())
        missing = f"; missing: {', '.join(v['rings_missing'])}" if v["rings_missing"] else ""
        print(f"  {v['image']}: {v['corners']} corners, RMS {v['corner_rms_px']:.3f} px; "
              f"rings (px) {rings}{missing}")
    for name, why in rep["skipped"].items():
        print(f"  {name}: skipped, {why}")
    print(f"wrote {out}")


def cmd_survey(c: Any, a: argparse.Namespace) -> int:
    try:  # every package of the extra before anything is read or written
        require("ritactl plate survey", LAPTOP)
    except CtlError as e:
        return fail(e.exit, e.code, e.args[0], a.json)
    from daemon.bus.storage import atomic_write_json
    from daemon.compute.survey import CalibrationError, survey_plate
    if Path(a.out).resolve() == Path(a.plate).resolve():  # the design file is the survey's input: keep it
        return fail(Exit.BAD_INPUT, "bad_input", f"--out {a.out} would overwrite the design file "
                    f"--plate {a.plate}: write the surveyed plate to another file", a.json)
    try:
        plate = survey_plate(Path(a.folder), _read_plate(a.plate), a.plate,
                             lambda pct, step: say(f"[{pct:5.1f}%] {step}", a.json))  # parsed by the console
        atomic_write_json(Path(a.out), plate)
    except KeyboardInterrupt:
        return Exit.INTERRUPTED
    except CalibrationError as exc:
        return fail(Exit.FAIL, "survey_failed", f"plate survey of {a.folder} failed: {exc}", a.json)
    except (OSError, ValueError) as exc:
        return fail(Exit.BAD_INPUT, "bad_input", f"plate survey of {a.folder}: {exc}", a.json)
    except Exception as exc:  # noqa: BLE001 - e.g. cv2.error on a pathological image: still no traceback
        why = f"{type(exc).__name__}: {exc}"
        return fail(Exit.FAIL, "failed", f"plate survey of {a.folder} failed: {why}", a.json)
    if a.json:
        print(json.dumps(plate, indent=2))
    else:
        _show(plate, a.out)
    return for_verdict(plate["survey"]["verdict"])


def cmd_upload(c: Any, a: argparse.Namespace) -> int:
    try:
        plate = _read_plate(a.file)
    except ValueError as exc:
        return fail(Exit.BAD_INPUT, "bad_input", str(exc), a.json)
    if not isinstance(plate, dict):
        return fail(Exit.BAD_INPUT, "bad_input", f"{a.file}: a plate definition is a JSON object, not "
                                                 f"{type(plate).__name__}", a.json)
    r = c.call("calib.plate.upload", plate=plate, name=a.name or Path(a.file).name)
    if a.json:
        print(json.dumps(r, indent=2))
        return Exit.OK
    kept = f"; the previous one is kept as {r['replaced']}" if r.get("replaced") else ""
    what = "already there, unchanged" if r.get("unchanged") else "stored"
    print(f"{a.file} {what} on the robot as {r['path']} (sha256 {r['sha256'][:12]}…){kept}")
    if r["path"] == "calibration/plate.json":
        print("referencing uses it by default "
              "(ritactl calibrate without --plate; the console's plate field empty)")
    else:
        print(f"the console's referencing form: plate {r['path']}")
    return Exit.OK


def add_parsers(sub: Any) -> None:
    grp = sub.add_parser("plate",
                         help="plate definitions: survey (offline, on this computer), upload (to the robot)")
    grp.set_defaults(fn=None, parser_=grp)
    gsub = grp.add_subparsers(title="plate verbs", metavar="VERB")
    p = gsub.add_parser("survey",
                        help="nest seats from photographs of the whole plate (offline, on this computer)",
                        description="Survey the three nest seats in PCS from colour photographs of the whole "
                                    "plate taken with any camera (calibrated here from the plate's patches). "
                                    "Writes plate.json with per-nest 1σ and the survey report.")
    p.add_argument("folder",
                   help="folder of photographs (.png .jpg .jpeg .tif .tiff), >= 3, whole plate in each")
    p.add_argument("--plate", required=True, metavar="FILE",
                   help="the plate's design plate.json (board, survey patches, smr_offset_mm)")
    p.add_argument("--out", default="plate.json", metavar="FILE",
                   help="surveyed plate definition (default plate.json)")
    p.set_defaults(fn=cmd_survey, offline=True, parser_=p)
    u = gsub.add_parser("upload", help="send a plate definition (e.g. the surveyed one) to the robot's "
                                       "calibration folder (calib.plate.upload; operator)",
                        description="Store a plate definition on the robot as calibration/NAME, checked "
                                    "against the plate schema first; a file it replaces is kept in "
                                    "calibration/history/plates/.")
    u.add_argument("file", help="plate.json on this computer")
    u.add_argument("--name", metavar="NAME", help="file name on the robot (default: the file's own name)")
    u.set_defaults(fn=cmd_upload, parser_=u)
