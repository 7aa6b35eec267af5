"""Results from stored observations: the same code for a live run and for ``ritactl recompute``.

Each ``compute_*`` takes the procedure's observation dict (as saved in the dataset's
``state.json``) and an image loader, and returns a JSON-able result. Everything is
deterministic (the Monte Carlo uncertainty is seeded), so a recompute reproduces the
stored result to round-off.
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from calibration import __version__ as calib_version
from calibration.camera_model import CameraModel
from calibration.checks import bias_model_check
from calibration.frames import apply_H
from calibration.coverage import stored_scale
from calibration.bias_check import cov_in_acs
from calibration.heading_weight import NOT_LEARNED, stop_marks
from calibration.image import to_grey
from calibration.measure import DEFAULT_SIGMA_T_MM, measure_image, robot_pose_at, stated_tracker_sigma
from calibration.metrics import ExperimentMetrics, experiment_metrics
from calibration.plate import NEST_NAMES, Plate
from calibration.referencing import reference
from calibration.mount import from_reversal as mount_from_reversal, message as mount_message
from calibration.reversal import combine
from calibration.scs import Scs, make_scs
from calibration.compensation import Compensation, compensate, reflector_height_mm
from daemon.bus.procedures import (COMMISSION, EXPERIMENT, INTRINSICS, MEASURE_MARK, REFERENCING, Hooks,
                                   Procedure, Resolved, get)
from daemon.compute.commission import compute_commission
from daemon.compute.experiment_checks import bias_check, sigma_check, weight_checks
from daemon.compute.inputs import (bias_cov, calibration_inputs, compensation_summary, heading_weight,
                                   imu_yaw, parse_compensation, plate_imu_offset, reflector_mount, stop_of,
                                   stop_record, tracker_distance_mm, tracker_position)

LoadImage = Callable[[str], np.ndarray]
RESULT_SCHEMA = 1


def _abs(point: dict[str, Any]) -> np.ndarray:
    return np.asarray(point["abs_xyz"], dtype=float)


def _sigma_t(obs: dict[str, Any]) -> float:
    """The dataset's tracker 1σ per coordinate (mm); none given, the computation's own (the documented
    10 µm)."""
    s = recorded(REFERENCING, obs).sigma_t_mm
    return DEFAULT_SIGMA_T_MM if s is None else float(s)


def to_8bit(image: np.ndarray) -> np.ndarray:
    """An 8-bit grey image for the detectors (:func:`calibration.image.to_grey` of a format-less image).

    The loaders already give 8-bit grey (daemon.compute.images); this keeps a raw
    mono array handed in directly working: 16-bit is scaled by its peak, a pure gain.
    """
    return to_grey(np.asarray(image))


def _eight_bit(load: LoadImage) -> LoadImage:
    """The image loader, every image passed through :func:`to_8bit`."""
    return lambda file: to_8bit(load(file))


def compute_referencing(obs: dict[str, Any], load: LoadImage) -> dict[str, Any]:
    """rob_H_cam from the nests and one or two on-plate runs (two = 0°/180° reversal)."""
    model = CameraModel.from_dict(obs["camera_model"], source="state.json: obs.camera_model")
    plate = Plate.from_dict(obs["plate"], source="state.json: obs.plate")
    abs_P_nests = np.array([_abs(obs["nests"][n]) for n in NEST_NAMES])
    sigma_t = _sigma_t(obs)
    load = _eight_bit(load)
    runs = []
    for i, run in enumerate(obs["runs"]):
        P0, P1 = _abs(run["P0"]), _abs(run["P1"])
        if float(run.get("move_mm", 1.0)) < 0:  # driven backwards: the robot's x axis is P0 − P1
            P1 = 2 * P0 - P1
        res = reference(model, plate, abs_P_nests, P0, P1, image=load(run["image"]),
                        sigma_t_mm=sigma_t, seed=i, model_dict=obs["camera_model"])
        runs.append(res)
    first = runs[0]
    scs0 = make_scs(model, first.cam_H_ref)
    out: dict[str, Any] = {"schema": RESULT_SCHEMA, "procedure": REFERENCING.name, "software": calib_version,
                           "plate_id": plate.plate_id, "camera_model": model.to_dict(),
                           "runs": [r.to_dict() for r in runs]}
    first_d = first.to_dict()
    out["uncertainty"] = first_d.get("uncertainty")
    if len(runs) >= 2:
        messages, verdicts = _reversal(runs, obs["runs"][0]["P0"], out)
    else:
        out.update(rob_H_cam=first.rob_H_cam.tolist(), rob_H_scn=first.rob_H_scn.tolist(), reversal=None,
                   reflector_mount=None)
        messages, verdicts = list(first.messages), [first.verdict]
    out["scs"] = scs0.to_dict()
    out["residuals_mm"] = first_d.get("nest_residuals_mm")
    out["verdict"] = "fail" if "fail" in verdicts else ("warn" if "warn" in verdicts else "ok")
    out["messages"] = messages
    height_mm = reflector_height_mm(np.array(out["rob_H_scn"]))
    imu = plate_imu_offset(obs["runs"], [r.abs_H_rob for r in runs], height_mm)
    if imu is not None:  # the inclinometer's mounting, part of the calibration like rob_H_scn
        if imu["imu_offset_deg"] is not None:
            out.update(imu_offset_deg=imu["imu_offset_deg"], imu_yaw_deg=imu["imu_yaw_deg"])
        out.update(imu_offset_runs_deg=imu["runs"], imu_yaw_sigma_deg=imu["imu_yaw_sigma_deg"])
        out["messages"] = out["messages"] + imu["messages"]
        if imu["verdict"] == "warn" and out["verdict"] == "ok":
            out["verdict"] = "warn"
    return out


def _reversal(runs: list[Any], P0: dict[str, Any], out: dict[str, Any]) -> tuple[list[str], list[str]]:
    """The runs combined by reversal into ``out`` (rob_H_cam, rob_H_scn, the covariance of their mean, the
    reflector mount offset); their messages and verdicts."""
    rev = combine(runs)
    out.update(rob_H_cam=rev.rob_H_cam.tolist(), rob_H_scn=rev.rob_H_scn.tolist(), reversal=rev.to_dict())
    # dict.fromkeys: a note both runs give (same text) is listed once
    messages = list(dict.fromkeys([m for r in runs for m in r.messages] + rev.messages))
    verdicts = [r.verdict for r in runs]
    mount, why = mount_from_reversal(rev, runs, tracker_position(P0))
    out["reflector_mount"] = None if mount is None else mount.to_dict()
    if mount is None:  # the reason goes with the calibration: a later job's skip names it, not a guess
        out["reflector_mount_why"] = why
    messages.append(f"reflector mount offset not estimated: {why}" if mount is None else mount_message(mount))
    if mount is not None:
        verdicts.append("warn" if mount.warn else "ok")
    if rev.cov_rob_H_scn is not None and out["uncertainty"]:
        # the combined estimate: its covariance replaces the single run's for marks
        out["uncertainty"] = {**out["uncertainty"], "cov_rob_H_scn": rev.cov_rob_H_scn.tolist(),
                              "note": "cov_rob_H_scn of the reversal mean; other figures of run 0"}
    return messages, verdicts


def no_mount_why(calib: dict[str, Any]) -> str:
    """Why a calibration holds no reflector mount offset: the reason its referencing gave (a reversal whose P0
    carries no ``abs_H_trk`` cannot orient the line of sight), or that it had no reversal."""
    head = "the calibration holds no reflector mount offset"
    if calib.get("reflector_mount_why"):
        return f"{head}: {calib['reflector_mount_why']}"
    if calib.get("reversal") is None:
        return f"{head}: its referencing had one run (reference with --reversal)"
    said = [m for m in calib.get("messages") or []
            if str(m).startswith("reflector mount offset not estimated: ")]
    return f"{head}: " + (said[0].split(": ", 1)[1] if said
                          else "its referencing's reversal did not estimate it")


#: the marks' pixel 1σ (the locator's, calibration.measure.measure_mark's default)
MARK_SIGMA_PX = 0.05


def recorded(proc: Procedure, obs: dict[str, Any]) -> Resolved:
    """The settings the worker recorded with the observations (mark kind and size, compensations, tracker σ),
    resolved by the declaration: one an older worker did not record gets the declared default."""
    names = {p.name for p in proc.params if p.type != "file"}
    return proc.resolve({k: v for k, v in obs.items() if k in names}, required=False)


def shown_params(procedure: str, params: dict[str, Any]) -> dict[str, Any]:
    """A result's ``params``: the job's, without the definitions a recompute may replace (the obs hold
    them)."""
    return {k: v for k, v in params.items() if k not in get(procedure).inputs}


def _mark_in_acs(calib: dict[str, Any], stop: dict[str, Any], load: LoadImage, kind: str,
                 size_mm: float, sigma_t_mm: float | None, comp: Compensation,
                 learn: list[Any] | None = None) -> dict[str, Any]:
    """One stop's mark in ACS with ``comp`` applied (calibration/compensation.py does the math).

    Its σ (docs/accuracy.md, "Coverage of the stated σ"): the tracker's σ as the dataset states it, else
    the MPE at the tracker's distance to the stop; the heading's σ beyond the two points (the chord's path
    deviation, or heading_fit's own); ``sigma`` in the mark records which, and each one's share.
    ``learn``: a list the stop's chord and fitted marks are appended to (heading_fit's weight).
    """
    scs = Scs.from_dict(calib["scs"], source="calibration result: scs")
    cov = (calib.get("uncertainty") or {}).get("cov_rob_H_scn")
    offset, bias = calibration_inputs(calib)
    # heading_fit's anchors keep the 10 µm default its significance test was built with
    anchor = DEFAULT_SIGMA_T_MM if sigma_t_mm is None else sigma_t_mm
    mount, bad_mount = reflector_mount(calib)
    weight, bad_weight = heading_weight(calib)
    a = compensate(comp, stop_of(stop), np.array(calib["rob_H_scn"], dtype=float), imu_offset=offset,
                   bias_b_mm=bias, anchor_sigma_mm=anchor, imu_yaw_deg=imu_yaw(calib), mount=mount,
                   abs_t_trk=tracker_position(stop["P_at"]), heading_weight=weight, calibration=calib)
    if bad_mount and comp.mount:  # a record no offset can be read from: measure without it, say why
        a.skipped["mount"] = bad_mount
    elif mount is None and comp.mount:  # the calibration's own reason, not a guess
        a.skipped["mount"] = no_mount_why(calib)
    if bad_weight and comp.heading_fit:  # a record no weight can be read from: the chord, say why
        a.skipped["heading_fit"] = "; ".join(r for r in (a.skipped.get("heading_fit"), bad_weight) if r
                                             and r != NOT_LEARNED.why) + ": the chord is used"
    distance = tracker_distance_mm(stop)
    s_t, t_source = stated_tracker_sigma(sigma_t_mm, distance)
    P_at = a.abs_P_at
    abs_H_rob = robot_pose_at(a.abs_P_prev, P_at)
    heading = math.degrees(math.atan2(abs_H_rob[1, 0], abs_H_rob[0, 0]))
    b_cov, _ = bias_cov(calib)  # a record it cannot read: the experiment's bias check, or the mark, says so
    m = measure_image(load(stop["image"]), scs, a.rob_H_scn, a.abs_P_prev, P_at, kind=kind,
                      mark_size_mm=size_mm, roll_deg=a.roll_deg, pitch_deg=a.pitch_deg,
                      sigma_t_mm=s_t, sigma_px=MARK_SIGMA_PX, sigma_heading_rad=a.sigma_heading_rad,
                      cov_rob_H_scn=None if cov is None else np.array(cov),
                      cov_mount_xy_mm2=a.cov_mount_xy_mm2,
                      cov_bias_xy_mm2=cov_in_acs(b_cov, heading) if "bias" in a.applied and b_cov is not None
                      else None)
    if learn is not None:
        learn.append(stop_marks(a, m.rob_P))
    sigma = {"tracker_mm": s_t, "tracker_source": t_source, "tracker_distance_mm": distance,
             "heading_rad": a.sigma_heading_rad, "heading_source": a.heading_source,
             "heading_sigma_basis": a.heading_sigma_basis, "pixel_px": MARK_SIGMA_PX,
             "calibration": cov is not None, "parts_mm": m.std_parts_mm}
    return {"abs_xyz": m.abs_P.tolist(), "uv": m.uv.tolist(), "std_mm": float(m.std_mm),
            "heading_deg": heading, **({"k": stop["k"]} if "k" in stop else {}), "sigma": sigma,
            "compensation": stop_record(comp, a)}


def compute_measure_mark(obs: dict[str, Any], load: LoadImage) -> dict[str, Any]:
    """One floor mark in ACS from one stop (image + approach positions); its σ scaled as the calibration's
    last experiment found its own σ to need (calibration/coverage.py, stored by ``store_bias`` as
    ``sigma_check``)."""
    s = recorded(MEASURE_MARK, obs)
    comp = parse_compensation(s.compensation)
    r = _mark_in_acs(obs["calibration"], obs["stop"], _eight_bit(load), s.kind, s.mark_size_mm, s.sigma_t_mm,
                     comp)
    record = obs["calibration"].get("sigma_check")
    scale, bad = stored_scale(record)
    source = (record or {}).get("job") if not bad else None
    r["sigma"].update(stated_mm=r["std_mm"], scale=scale, scale_source=source)
    r["std_mm"] = r["std_mm"] * scale
    messages = [bad] if bad else ([f"σ scaled by {scale:.2f}: the calibration's last experiment ({source}) "
                                   f"found its stated σ short of its scatter by that factor"]
                                  if scale > 1.0 else [])
    bad_cov = bias_cov(obs["calibration"])[1]
    if bad_cov and "bias" in r["compensation"]["applied"]:  # no experiment here to say so: the mark does
        messages.append(bad_cov)
    return {"schema": RESULT_SCHEMA, "procedure": MEASURE_MARK.name, "software": calib_version,
            "calibration_job": obs["calibration"].get("job"), "mark": r,
            "compensation": compensation_summary(comp, [r["compensation"]], obs["calibration"]),
            "verdict": "ok", "messages": messages}


def compute_experiment(obs: dict[str, Any], load: LoadImage) -> dict[str, Any]:
    """The paper's 8-direction repeatability experiment: per-stop marks, the metrics table, and what the
    experiment's own scatter says about its stated σ and heading_fit's weight
    (daemon/compute/experiment_checks.py)."""
    s, load = recorded(EXPERIMENT, obs), _eight_bit(load)
    comp = parse_compensation(s.compensation)
    stops: list[Any] = []
    marks = [_mark_in_acs(obs["calibration"], stop, load, s.kind, s.mark_size_mm, s.sigma_t_mm, comp, stops)
             for stop in obs["stops"]]
    xy = np.array([m["abs_xyz"][:2] for m in marks])
    headings = np.array([m["heading_deg"] for m in marks])
    groups = np.array([s["k"] for s in obs["stops"]])
    metrics = experiment_metrics(xy, headings, groups)
    # the mount's share is the same offset at every stop: no scatter between the cluster means
    # ... nor the stored bias's own error: R(ψ)·δb, which b takes up
    scatter = [math.sqrt(max(m["std_mm"] ** 2 - sum(m["sigma"]["parts_mm"].get(p, 0.0) ** 2
                                                   for p in ("mount", "bias")), 0.0)) for m in marks]
    fit_rms_mm = None if metrics.fit is None else metrics.fit.rms_mm
    check = bias_model_check(xy, groups.tolist(), fit_rms_mm, scatter)
    summary = compensation_summary(comp, [m["compensation"] for m in marks], obs["calibration"])
    checks: dict[str, Any] = {"bias_model": check, "sigma": sigma_check(marks, xy, headings),
                              "bias": bias_check(obs["calibration"], summary, xy, headings, groups)}
    messages = [m for m in (check["message"], *((checks[k] or {}).get("message") for k in ("sigma", "bias")))
                if m]
    out: dict[str, Any] = {"heading_weight": None}
    if comp.heading_fit:
        weight, recheck, chord = weight_checks(obs, marks, stops, headings, groups)
        out.update(heading_weight=weight, chord=chord)
        checks["heading_weight"] = recheck
        said = [recheck["message"]] if recheck and recheck["message"] else []
        messages += [weight_message(weight)] + said
    _label_bias(metrics, summary)
    ok = all(c is None or c.get("ok", True) for c in checks.values())
    return {"schema": RESULT_SCHEMA, "procedure": EXPERIMENT.name, "software": calib_version,
            "calibration_job": obs["calibration"].get("job"), "marks": marks, "metrics": metrics.to_dict(),
            "compensation": summary, "table_markdown": metrics.to_markdown(), "table_csv": metrics.to_csv(),
            "checks": checks, **out, "verdict": "ok" if ok else "warn", "messages": messages}


def _label_bias(metrics: ExperimentMetrics, summary: dict[str, Any]) -> None:
    """The table's fitted b is what is left after a bias the stops applied: it says so, and shows that one."""
    n, stops = summary["applied"].get("bias", 0), summary["stops"]
    if n and n == stops and summary.get("robot_bias_mm") is not None:
        metrics.applied_b = list(summary["robot_bias_mm"])
    elif n:
        metrics.partly_applied = f"{n} of {stops} stops only: the fitted b mixes both"


def weight_message(weight: dict[str, Any]) -> str:
    """The experiment's line about heading_fit's learned weight (stored with the bias)."""
    if not weight["applied"]:
        return f"heading_fit: later jobs keep the chord: {weight['why']}"
    return (f"heading_fit: the stream's fitted bend makes the marks agree best at weight "
            f"{weight['weight']:.2f} ± {weight['sigma']:.2f} ({weight['n_stops']} stops; heading σ left "
            f"{weight['sigma_heading_rad'] * 1e6:.0f} µrad); later jobs apply it")


#: the focal length's 1σ above which an intrinsics model is only a warn (the
#: intrinsics' goal |Δf|/f ≤ 0.1 %, docs/accuracy.md "The closed loop without ground truth")
MAX_F_STD_FRACTION = 0.001


def _intrinsics_verdict(model: CameraModel, report: dict[str, Any]) -> tuple[str, list[str]]:
    if report["degenerate"]:
        return "fail", [f"the views do not determine the camera model: {m}" for m in report["findings"]]
    messages = list(report["warnings"])
    f_std = max(report["std"]["fx"], report["std"]["fy"])
    if f_std > MAX_F_STD_FRACTION * model.f:
        messages.append(f"focal length only known to ±{f_std:.2f} px ({100 * f_std / model.f:.3f} % > "
                        f"{100 * MAX_F_STD_FRACTION:.1f} %): add tilted views "
                        f"(recipe views tilt-x+35, tilt-y+35)")
    return ("warn" if messages else "ok"), messages


def compute_intrinsics(obs: dict[str, Any], load: LoadImage) -> dict[str, Any]:
    """Camera model + uncertainty from the stored board views (daemon/worker/guided_intrinsics.py)."""
    from calibration.board import Board
    from calibration.intrinsics import PARAM_NAMES, calibrate_intrinsics

    load = _eight_bit(load)
    if "board" in obs:
        board: Board | Plate = Board.from_dict(obs["board"], source="state.json: obs.board")
    else:  # a dataset of the earlier procedure: views of the plate target
        board = Plate.from_dict(obs["plate"], source="state.json: obs.plate")
    images = [load(v["image"]) for v in obs["views"]]
    if not images:
        raise ValueError("no views were taken (every view skipped): run the procedure again")
    size = (images[0].shape[1], images[0].shape[0])
    model, report = calibrate_intrinsics(images, board, size)
    verdict, messages = _intrinsics_verdict(model, report)
    for v, stored in zip(report["views"], obs["views"]):
        v["key"] = stored.get("key")
    camera_model = {**model.to_dict(), "std": {n: report["std"][n] for n in PARAM_NAMES},
                    "calibration": {"rms_px": report["rms_px"], "n_views": report["n_views_used"],
                                    "k3_fitted": report["k3"]["fitted"],
                                    "board_id": getattr(board, "board_id", getattr(board, "plate_id", None))}}
    return {"schema": RESULT_SCHEMA, "procedure": INTRINSICS.name, "software": calib_version,
            "camera_model": camera_model, "report": report, "verdict": verdict, "messages": messages}


#: the computation per declared procedure (the live worker and ``ritactl recompute`` alike)
COMPUTE: Hooks[Callable[..., dict[str, Any]]] = Hooks("computation")
for _proc, _fn in ((REFERENCING, compute_referencing), (INTRINSICS, compute_intrinsics),
                   (MEASURE_MARK, compute_measure_mark), (EXPERIMENT, compute_experiment),
                   (COMMISSION, compute_commission)):
    COMPUTE.on(_proc)(_fn)
COMPUTE.complete()


def footprint_abs(calib: dict[str, Any], abs_H_rob: np.ndarray) -> np.ndarray:
    """Where the image centre meets the floor, in ACS, for a robot pose (for navigation)."""
    scs = Scs.from_dict(calib["scs"], source="calibration result: scs")
    w, h = scs.size
    xy = scs.image_to_scn(np.array([[(w - 1) / 2, (h - 1) / 2]]))[0]
    rob_P = apply_H(np.array(calib["rob_H_scn"], float), [xy[0], xy[1], 0.0])
    return apply_H(abs_H_rob, rob_P)
