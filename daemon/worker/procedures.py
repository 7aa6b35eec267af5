"""The guided procedures as resumable step sequences.

Every step first checks ``ctx.done(step)``: a resumed job skips what it already
measured. Steps gather raw observations into ``ctx.obs``; the result is always
computed from those stored observations by :mod:`daemon.compute.procedures`, the
same code ``ritactl recompute`` runs.
"""
from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from calibration.plate import NEST_NAMES
from daemon.compute.inputs import parse_compensation
from daemon.worker.compensations import read_tilt
from daemon.compute.procedures import footprint_abs
from daemon.worker.guided_intrinsics import guided_intrinsics
from daemon.worker.job import JobContext, StepFailed
from daemon.worker.motion import HEADING_TOL_DEG, ODOMETRY_TOL_MM, odometry_delta
from daemon.worker.nav import Navigator
from daemon.bus.procedures import COMMISSION, EXPERIMENT, INTRINSICS, MEASURE_MARK, REFERENCING, Hooks
from daemon.worker.commission import run_commission
from daemon.bus.protocol import CommandError

#: a referencing drive cut short is driven back when the odometry since P0 shows the robot on its line
#: (a straight move does not turn it or put it sideways) and the tracker agrees on the distance from P0
#: within the drive's errors (scale, slip, lateral: a few mm over the plate): otherwise the odometry
#: is not the robot's (a restarted base starts at 0, 0, 0; a robot moved by hand) and driving back is blind
BACK_ACROSS_MM, BACK_TURNED_DEG = 5.0, 1.0
BACK_AGREE_MM, BACK_AGREE_REL = 5.0, 0.05
#: unmoved by odometry, the tracker must find the reflector at P0 within this (mm) for P0 to hold
BACK_STILL_MM = 0.5


def _record_sigma_t(ctx: JobContext) -> None:
    """The job's tracker σ in the observations, only when given: without it the computation states its own
    (daemon/compute/procedures.py: 10 µm for the referencing, the MPE at the tracker's distance for marks)."""
    if ctx.params.sigma_t_mm is not None:
        ctx.obs.setdefault("sigma_t_mm", ctx.params.sigma_t_mm)


def _measure_reflector(ctx: JobContext, name: str, approx_trk: Sequence[float] | None,
                       pct: float) -> dict[str, Any]:
    """Aim + find + measure; when the tracker cannot find it, ask the operator to help."""
    ctx.progress(f"measure {name}", pct, f"tracker: find the reflector at {name}")
    if approx_trk is not None:
        try:
            ctx.call("tracker.aim", timeout=60, x=approx_trk[0], y=approx_trk[1], z=approx_trk[2])
            ctx.call("tracker.find", timeout=60)
            return ctx.call("tracker.measure", timeout=60)
        except CommandError as exc:
            reason = f"the tracker could not find it ({exc.args[0]})"
    else:
        reason = "no approximate position is known"
    where = f"in the {name} nest" if name in NEST_NAMES else "on the robot"
    ctx.ask(f"{reason}: put the reflector {where}, lock the tracker onto it, then answer 'ok'", ["ok"])
    return ctx.call("tracker.measure", timeout=60)


def _on_plate_run(ctx: JobContext, nav: Navigator, tag: str, base_pct: float) -> None:
    """Image + P0 at one standstill, drive d straight, P1 (paper: Robot pose estimation).

    The pose belongs to P0 and the image taken at the same standstill; P1 only gives the direction
    of the drive, whose length ``move_mm`` records. The drive is recorded only once the base executed
    all of it; a resume finds a drive that is not done and redoes the run from P0 (:func:`_back_to_p0`).
    """
    runs = ctx.obs.setdefault("runs", [])
    if ctx.done(f"{tag}.image") and not ctx.done(f"{tag}.drive"):
        _back_to_p0(ctx, nav, tag, base_pct)
    if not ctx.done(f"{tag}.image"):
        ctx.progress(f"{tag}: image and P0", base_pct, "camera + tracker at standstill")
        taken = sum(1 for e in ctx.dataset.manifest["entries"] if str(e["name"]).startswith(f"{tag}-p0"))
        file, header, _ = ctx.capture_image(f"{tag}-p0" + (f"-{taken + 1}" if taken else ""))  # a retake
        P0 = ctx.call("tracker.measure", timeout=60)
        robot = ctx.call("robot.status")
        imu = read_tilt(ctx.call, ctx.params.imu_readings, ctx.params.imu_interval_s)  # None: no tilt
        runs[:] = [r for r in runs if r["tag"] != tag]
        runs.append({"tag": tag, "image": file, "header": header, "P0": P0, "robot0": robot,
                     **({"imu0": imu} if imu else {})})
        ctx.mark_done(f"{tag}.image")
    run = next(r for r in runs if r["tag"] == tag)
    if not ctx.done(f"{tag}.drive"):
        ctx.progress(f"{tag}: drive {ctx.params.distance_mm:.0f} mm", base_pct + 10, "robot moving")
        nav.move(ctx.params.distance_mm)  # returns once all of it is driven, else raises
        run["robot1"] = ctx.call("robot.status")  # the odometry at P1: the dataset shows the executed drive
        run["move_mm"] = float(ctx.params.distance_mm)
        ctx.mark_done(f"{tag}.drive")
    if not ctx.done(f"{tag}.P1"):
        run["P1"] = ctx.call("tracker.measure", timeout=60)
        v = np.asarray(run["P1"]["abs_xyz"]) - np.asarray(run["P0"]["abs_xyz"])
        nav.nav["heading_deg"] = math.degrees(math.atan2(v[1], v[0]))
        ctx.mark_done(f"{tag}.P1")


def _back_to_p0(ctx: JobContext, nav: Navigator, tag: str, base_pct: float) -> None:
    """A run whose drive is not done (stopped, cut short, or its end not recorded): back to a defined state.

    Where the robot stands is found from its odometry since P0 (``robot0``), checked against the
    tracker. Unmoved, image and P0 still hold. Otherwise it drives back the distance the odometry shows
    (to the standstill whose view of the target was good; driving on could leave the plate) and the
    run starts afresh: image and P0 again, since the robot never comes back exactly to the same pose.
    """
    runs = ctx.obs["runs"]
    run = next(r for r in runs if r["tag"] == tag)
    along, across, turned = odometry_delta(run["robot0"], ctx.call("robot.status"))
    still = max(abs(along), abs(across)) <= ODOMETRY_TOL_MM and abs(turned) <= HEADING_TOL_DEG
    P_now, _ = nav.where()
    moved = float(np.hypot(*(P_now[:2] - np.asarray(run["P0"]["abs_xyz"], float)[:2])))
    agree = BACK_STILL_MM if still else BACK_AGREE_MM + BACK_AGREE_REL * abs(along)
    if abs(across) > BACK_ACROSS_MM or abs(turned) > BACK_TURNED_DEG or abs(moved - abs(along)) > agree:
        raise StepFailed(f"{tag}: cannot return to P0 to redo the drive: the odometry since P0 says "
                         f"{along:.1f} mm along the drive, {across:.1f} mm across, {turned:.2f}° turned, "
                         f"the tracker {moved:.1f} mm from P0 (was the base restarted or moved by hand?). "
                         f"Start a new referencing with the robot on the plate", resumable=False)
    if still:  # stopped before the drive began: image and P0 hold
        return
    ctx.progress(f"{tag}: back to P0", base_pct, f"the drive was cut short after {along:.1f} mm: "
                 f"driving back to redo it from P0")
    nav.move(-along)
    back = float(np.hypot(*(nav.where()[0][:2] - np.asarray(run["P0"]["abs_xyz"], float)[:2])))
    if back > BACK_AGREE_MM + BACK_AGREE_REL * abs(along):  # the odometry misled the way back: stop here
        raise StepFailed(f"{tag}: driven back {along:.1f} mm, the robot is {back:.1f} mm from P0, not at it "
                         f"(was the base restarted?). Start a new referencing with the robot on the plate",
                         resumable=False)
    ctx.state["done"].remove(f"{tag}.image")  # image and P0 are taken again at the new standstill
    runs[:] = [r for r in runs if r["tag"] != tag]
    ctx.checkpoint()


def referencing(ctx: JobContext) -> None:
    """Nests, robot on the plate (image + P0), drive, P1; optional 180° reversal run."""
    from daemon.compute.procedures import compute_referencing

    nav = Navigator(ctx)
    for key in ("plate", "camera_model"):
        if key not in ctx.obs:
            ctx.obs[key] = ctx.definition(key)
    _record_sigma_t(ctx)
    nests = ctx.obs.setdefault("nests", {})
    approx = ctx.params.nests_approx_trk or {}
    for i, name in enumerate(NEST_NAMES):
        if name not in nests:
            nests[name] = _measure_reflector(ctx, name, approx.get(name), 5 + 10 * i)
            ctx.checkpoint()
    if not ctx.done("lock_robot"):
        _measure_reflector(ctx, "robot", ctx.params.robot_approx_trk, 35)
        ctx.mark_done("lock_robot")
    _on_plate_run(ctx, nav, "run0", 40)
    if ctx.params.reversal:
        if not ctx.done("reverse"):
            ctx.progress("reversal: turn the robot 180° on the plate", 60, "robot moving")
            first = compute_referencing({**ctx.obs, "runs": ctx.obs["runs"][:1]}, ctx.load_image)
            run0 = ctx.obs["runs"][0]
            P0 = np.asarray(run0["P0"]["abs_xyz"])
            abs_H_rob0 = np.array(first["runs"][0]["abs_H_rob"])
            foot = footprint_abs(first, abs_H_rob0)
            heading = math.degrees(math.atan2(abs_H_rob0[1, 0], abs_H_rob0[0, 0])) + 180.0
            # the reflector spot that puts the same footprint on the target at the reversed
            # heading: the horizontal reflector→footprint offset turns by 180°
            target = 2 * foot[:2] - P0[:2]
            # a referencing stores no approach and declares no recording: nothing to record along it
            nav.approach(target, heading, ctx.params.distance_mm, record=False)
            ctx.mark_done("reverse")
        _on_plate_run(ctx, nav, "run1", 70)
    ctx.progress("compute rob_H_cam", 90, "")


def measure_stop(ctx: JobContext, nav: Navigator, name: str, mark_xy: np.ndarray, heading: float,
                 offset: np.ndarray, calib: dict[str, Any]) -> dict[str, Any]:
    """Approach so the mark falls near the image centre (+ offset), then image + positions."""
    abs_H_rob_now = np.eye(4)
    abs_H_rob_now[:3, :3] = np.array([[math.cos(math.radians(heading)), -math.sin(math.radians(heading)), 0],
                                      [math.sin(math.radians(heading)), math.cos(math.radians(heading)), 0],
                                      [0, 0, 1.0]])
    foot = footprint_abs(calib, abs_H_rob_now)[:2]  # footprint relative to the reflector at this heading
    target = np.asarray(mark_xy, float) - foot - offset
    nav.approach(target, heading, ctx.params.distance_mm)
    if nav.last_points is None:  # approach() ends with a recorded straight move, which sets them
        raise RuntimeError("measure_stop: the approach left no tracker points")
    P_prev, P_at = nav.last_points  # both frames + abs_H_trk, as tracker.measure returned them
    file, header, _ = ctx.capture_image(name)
    robot = ctx.call("robot.status")
    # the compensations' inputs: inclinometer at both stops, stream between them (when base/tracker give them)
    imu_at = read_tilt(ctx.call, ctx.params.imu_readings, ctx.params.imu_interval_s)
    rec = {"imu_at": imu_at, **nav.last_record}
    return {"image": file, "header": header, "P_prev": P_prev, "P_at": P_at, "robot": robot,
            "heading_cmd_deg": heading, "offset_mm": offset.tolist(),
            "move_mm": float(ctx.params.distance_mm), **{k: v for k, v in rec.items() if v}}


def _calibration(ctx: JobContext) -> dict[str, Any]:
    if "calibration" not in ctx.obs:
        ctx.obs["calibration"] = ctx.definition("calibration")
        ctx.checkpoint()
    return ctx.obs["calibration"]


def _mark_setup(ctx: JobContext) -> tuple[dict[str, Any], Navigator]:
    """The active calibration, a navigator, and the mark's parameters recorded in the observations."""
    ctx.obs.setdefault("kind", ctx.params.kind)
    _record_sigma_t(ctx)
    parse_compensation(ctx.params.compensation)  # a bad name fails before the robot moves
    ctx.obs.setdefault("compensation", ctx.params.compensation)
    ctx.obs.setdefault("mark_size_mm", ctx.params.mark_size_mm)
    return _calibration(ctx), Navigator(ctx)


def measure_mark(ctx: JobContext) -> None:
    calib, nav = _mark_setup(ctx)
    if not ctx.done("stop"):
        ctx.progress("approach the mark", 20, "robot moving")
        # none given: the heading it stands at
        heading = nav.heading if ctx.params.heading_deg is None else ctx.params.heading_deg
        ctx.obs["stop"] = measure_stop(ctx, nav, "stop", np.asarray(ctx.params.mark_xy, float), heading,
                                       np.zeros(2), calib)
        ctx.mark_done("stop")
    ctx.progress("compute the mark position", 90, "")


def experiment(ctx: JobContext) -> None:
    """The paper's validation: N repetitions from each of K equidistant headings."""
    calib, nav = _mark_setup(ctx)
    k_dirs, reps = ctx.params.directions, ctx.params.repetitions
    rng = np.random.default_rng(ctx.params.seed)
    plan = [(k, r, rng.uniform(-1, 1, 2) * ctx.params.offset_mm, rng.normal(0, 0.5))
            for r in range(reps) for k in range(k_dirs)]
    psi0 = ctx.params.psi0_deg
    stops = ctx.obs.setdefault("stops", [])
    mark = np.asarray(ctx.params.mark_xy, float)
    for j, (k, r, offset, jitter) in enumerate(plan):
        name = f"stop-{j:03d}-k{k}-r{r}"
        if ctx.done(name):
            continue
        heading = psi0 + k * 360.0 / k_dirs + jitter
        ctx.progress(f"direction {k + 1}/{k_dirs}, repetition {r + 1}/{reps}", 5 + 85 * j / len(plan),
                     "robot approaching the mark")
        stop = measure_stop(ctx, nav, name, mark, heading, offset, calib)
        stops.append({**stop, "k": k, "rep": r})
        ctx.mark_done(name)
    ctx.progress("compute the metrics", 92, "")


#: the worker's run per declared procedure; a declared procedure without one fails here, at import
RUN: Hooks[Callable[[JobContext], None]] = Hooks("worker run")
for _proc, _fn in ((REFERENCING, referencing), (INTRINSICS, guided_intrinsics), (MEASURE_MARK, measure_mark),
                   (EXPERIMENT, experiment), (COMMISSION, run_commission)):
    RUN.on(_proc)(_fn)
RUN.complete()
