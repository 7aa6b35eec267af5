"""Accuracy runs on the rendering-free simulation: the product's compensations scored by truth.

One *case* is a profile, a set of compensations and a set of error groups switched off.
One run of a case on one seed does what the robot would do:

1. referencing on the plate (PnP on projected corners + 0.05 px), with the 180° reversal when
   the procedure table's default says so, as the product combines it: the mean of the two runs,
   the reflector mount's offset (calibration/mount.py) and the inclinometer's offset and yaw
   (calibration/imu_mount.py) from both runs;
2. with the bias compensation: an 8-direction experiment over mark M2 whose fitted
   robot-frame bias b is stored with the calibration (the learning run);
3. the scored 8 × 5 experiment over mark M1 with every compensation of the case;
4. the paper's metrics, plus what only the simulation knows: the marks' ACS error and
   rob_H_cam's error against truth.

Truth enters only in step 4. The product code used is calibration/ (referencing,
measure, metrics, compensation); the simulation supplies what the robot's devices would.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.bias_check import chord_bias, cov_in_acs
from calibration.compensation import (Compensation, Stop, compensate, imu_offset_deg, reflector_height_mm,
                                      tilt_of_pose)
from calibration.heading_weight import NOT_LEARNED, HeadingWeight, learn_from_stops, stop_marks
from calibration.imu_mount import imu_mount
from calibration.measure import DEFAULT_SIGMA_T_MM, measure_mark, stated_tracker_sigma
from calibration.metrics import experiment_metrics
from calibration.mount import MountOffset, from_reversal as mount_from_reversal
from calibration.referencing import reference, rob_H_cam_error
from calibration.reversal import combine
from calibration.scs import make_scs
from daemon.bus.figures import ACCURACY_GOALS_MM
from daemon.bus.procedures import REFERENCING
from fakes import profiles
from fakes.simulate import MarkObs, SimConfig, Simulation
from fakes.world import World, WorldParams

#: the paper's glass-plate figures (Table target_direction_metrics) and the goals for
#: ``paper+imu`` with the compensations (mm), by metric key
PAPER_MM = {"enclosing_mm": 0.747, "pairwise_mm": 0.215}
GOALS_MM = dict(ACCURACY_GOALS_MM)  # the product's goals: one source (daemon/bus/figures.py)
#: the referencing's Monte Carlo samples, as the worker takes them (the marks' stated σ needs cov_rob_H_scn)
MC_SAMPLES = 200
#: metric keys of one run, in table order (mm; rotation in degrees)
METRICS = ("enclosing_mm", "pairwise_mm", "abs_rms_mm", "t_xy_mm", "rotation_deg")


@dataclass(frozen=True)
class Calibration:
    """What a referencing gives the later jobs (the fields of the product's referencing result they read)."""

    rob_H_scn: np.ndarray
    rob_H_cam: np.ndarray
    scs: Any
    cov: np.ndarray | None  # cov_rob_H_scn
    imu_offset: tuple[float, float] | None = None
    imu_yaw_deg: float = 0.0
    mount: MountOffset | None = None


@dataclass(frozen=True)
class Case:
    profile: str = "paper"
    comp: Compensation = Compensation()
    off: tuple[str, ...] = ()
    mark_window_mm: float = 3.0  # the mark's spread about the footprint centre
    tweak: tuple[tuple[str, str, Any], ...] = ()  # (group, field, value): sensitivity cases
    name: str = ""  # a short label for a tweaked case
    reversal: bool = REFERENCING.resolve({}).reversal  # the referencing procedure's default

    @property
    def label(self) -> str:
        comp = "+".join(self.comp.names()) or "none"
        tweaks = "".join(f" {g}.{f}={v}" for g, f, v in self.tweak)
        return self.name or (f"{self.profile}, {comp}" + "".join(f" −{g}" for g in self.off) + tweaks)


def _stop(o: MarkObs) -> Stop:
    tilt_at = None if o.roll_deg is None else (o.roll_deg, o.pitch_deg)
    tilt_prev = None if o.prev_roll_deg is None else (o.prev_roll_deg, o.prev_pitch_deg)
    return Stop(o.abs_P_prev, o.abs_P_at, tilt_prev, tilt_at, o.stream, o.stream_tilt_deg)


def _distance_mm(o: MarkObs, abs_t_trk: np.ndarray | None) -> float | None:
    """The tracker's distance to the stop's two points, as the product takes it (the larger)."""
    if abs_t_trk is None:
        return None
    return max(float(np.linalg.norm(P - abs_t_trk)) for P in (o.abs_P_prev, o.abs_P_at))


def measure_all(val: Any, comp: Compensation, scs: Any, rob_H_scn: np.ndarray, imu_offset: Any,
                bias: Any, cov: np.ndarray | None = None, abs_t_trk: np.ndarray | None = None,
                mount: MountOffset | None = None, imu_yaw_deg: float = 0.0,
                heading_weight: HeadingWeight | None = NOT_LEARNED, learn: list[Any] | None = None,
                bias_cov: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ACS marks of every stop, their approach headings (deg) and (N, 6) σ figures, with ``comp`` applied.

    σ as the product states it (daemon/compute/procedures.py ``_mark_in_acs``): the tracker's σ
    from its MPE at its distance (``abs_t_trk``: the tracker's ACS position; None: the 10 µm
    default), the compensation's heading σ, 0.05 px, the calibration's ``cov_rob_H_scn``, the reflector
    mount's share, the stored bias's (``bias_cov``: its RCS covariance, calibration/bias_check.py). Per stop:
    that std_mm; the mark variance per unit tracker variance (mm²/mm², to restate σ with another
    σ_t); the mark's lever arm from the reflector (mm); the std_mm the product first stated
    (10 µm, no heading or mount term); the heading term's share (mm); the tracker σ used (mm).
    ``heading_weight``: the calibration's learned share of the fitted bend (as the product: none learned,
    the chord;
    None: each stop's own significance test); ``learn``: a list each stop's
    chord and fitted marks are appended to (calibration/heading_weight.py ``stop_marks``), as the experiment
    the product learns the weight from records them.
    """
    pts, heads, sig = [], [], []
    for o in val.observations:
        a = compensate(comp, _stop(o), rob_H_scn, imu_offset=imu_offset, bias_b_mm=bias, mount=mount,
                       abs_t_trk=abs_t_trk, imu_yaw_deg=imu_yaw_deg, heading_weight=heading_weight)
        s_t = stated_tracker_sigma(None, _distance_mm(o, abs_t_trk))[0]
        v = o.abs_P_at - a.abs_P_prev
        heading = float(np.degrees(np.arctan2(v[1], v[0])))
        m = measure_mark(o.uv, scs, a.rob_H_scn, a.abs_P_prev, a.abs_P_at, roll_deg=a.roll_deg,
                         pitch_deg=a.pitch_deg, cov_rob_H_scn=cov, sigma_t_mm=s_t,
                         sigma_heading_rad=a.sigma_heading_rad, cov_mount_xy_mm2=a.cov_mount_xy_mm2,
                         cov_bias_xy_mm2=cov_in_acs(bias_cov, heading) if bias_cov is not None
                         and "bias" in a.applied else None)
        parts = m.std_parts_mm
        if learn is not None:
            learn.append(stop_marks(a, m.rob_P))
        unit = (parts["tracker"] / s_t) ** 2
        old = np.sqrt(m.std_mm ** 2 - sum(parts.get(k, 0.0) ** 2 for k in ("heading", "mount", "bias"))
                      + (DEFAULT_SIGMA_T_MM ** 2 - s_t ** 2) * unit)
        pts.append(m.abs_P)
        sig.append((m.std_mm, unit, float(np.linalg.norm(m.rob_P[:2])), old, parts["heading"], s_t))
        heads.append(heading)
    return np.array(pts), np.array(heads), np.array(sig)


def _visit(sim: Simulation, heading_deg: float | None, stream: str, nests: Any = None, seed: int = 0
           ) -> tuple[Any, Any]:
    """Run ``seed`` on the plate (its Monte Carlo seed, as the product numbers runs); ``nests``: as measured
    for the first run (the worker measures them once for both)."""
    obs = sim.calibration(heading_deg, stream=stream)
    return obs, reference(sim.model, sim.plate, obs.abs_P_nests if nests is None else nests, obs.abs_P_rob0,
                          obs.abs_P_rob1, cam_ref=obs.cam_ref, mc_samples=MC_SAMPLES, seed=seed)


def referencing(sim: Simulation, reversal: bool) -> Calibration:
    """The referencing as daemon/compute/procedures.py ``compute_referencing`` combines it (one run, or two
    180° apart), on the simulation's observations."""
    obs, res = _visit(sim, None, "calib")
    # with a reversal: the SCS of the first run (calibration/reversal.py)
    scs = make_scs(sim.model, res.cam_H_ref)
    if not reversal:
        offset = imu_offset_deg(res.abs_H_rob, *obs.imu_deg) if obs.imu_deg is not None else None
        return Calibration(res.rob_H_scn, res.rob_H_cam, scs, None if res.uncertainty is None else
                           res.uncertainty.cov_rob_H_scn, offset)
    obs1, res1 = _visit(sim, obs.heading_deg + 180.0, "calib-reversal", obs.abs_P_nests, seed=1)
    rev = combine([res, res1])
    # every tracker point carries abs_H_trk in a dataset
    mount, why = mount_from_reversal(rev, [res, res1], sim.world.abs_H_trk[:3, 3])
    assert mount is not None, why
    offset, yaw = None, 0.0
    if obs.imu_deg is not None and obs1.imu_deg is not None:
        im = imu_mount([tilt_of_pose(res.abs_H_rob), tilt_of_pose(res1.abs_H_rob)],
                       [obs.imu_deg, obs1.imu_deg], [obs.imu_sigma_deg or 0.0, obs1.imu_sigma_deg or 0.0],
                       reflector_height_mm(rev.rob_H_scn))
        offset = None if im.offset_deg is None else (im.offset_deg[0], im.offset_deg[1])
        yaw = im.yaw_deg or 0.0
    return Calibration(rev.rob_H_scn, rev.rob_H_cam, scs, rev.cov_rob_H_scn, offset, yaw, mount)


def run(case: Case, seed: int) -> dict[str, Any]:
    """One seed of ``case``: the metrics of :data:`METRICS`, per-stop image positions, errors and σ figures
    (:func:`measure_all`; ``std_mm`` as the product states it, ``std_old_mm`` as it first
    did), and the experiment's full metrics (``metrics``)."""
    p = profiles.apply(case.profile, WorldParams(seed=seed))
    world = World(p.with_(errors=p.errors.without(*case.off).tweaked(case.tweak)))
    imu = world.params.base_has_inclinometer
    cfg = SimConfig(seed=seed, pnp_sigma_px=0.05, report_tilt=imu, mark_window_mm=case.mark_window_mm)
    sim = Simulation(world, cfg)
    cal = referencing(sim, case.reversal)
    # without a learning experiment the product has no weight for heading_fit: the chord
    bias, bias_cov, weight, trk = None, None, NOT_LEARNED, world.abs_H_trk[:3, 3]
    kw: dict[str, Any] = dict(abs_t_trk=trk, mount=cal.mount, imu_yaw_deg=cal.imu_yaw_deg)
    if case.comp.bias:  # learn b (and heading_fit's weight) on another mark, as a later job finds them stored
        learn = Simulation(world, SimConfig(**{**cfg.__dict__, "mark": "M2"})).validation("learn-bias")
        base = Compensation(case.comp.tilt, case.comp.heading_fit, False, case.comp.mount)
        stops: list[Any] = []
        lp, lh, _ = measure_all(learn, base, cal.scs, cal.rob_H_scn, cal.imu_offset, None, learn=stops,
                                heading_weight=NOT_LEARNED, **kw)
        groups = [o.direction for o in learn.observations]
        fit = experiment_metrics(lp, lh, groups).fit
        bias = None if fit is None else fit.b
        made = chord_bias(lp[:, :2], lh, np.array(groups))
        bias_cov = None if made is None else made[1]
        weight = learn_from_stops(stops, lh)
        if case.comp.heading_fit and weight.b_mm is not None:  # as the product stores it: b fitted with w
            bias, bias_cov = list(weight.b_mm), weight.b_cov_mm2
    val = sim.validation()
    pts, heads, sig = measure_all(val, case.comp, cal.scs, cal.rob_H_scn, cal.imu_offset, bias, cal.cov,
                                  heading_weight=weight, bias_cov=bias_cov, **kw)
    m = experiment_metrics(pts, heads, [o.direction for o in val.observations])
    err = pts[:, :2] - val.mark_abs[:2]
    e = rob_H_cam_error(cal.rob_H_cam, world.rob_H_cam)
    return {"enclosing_mm": m.enclosing_diameter_mm, "pairwise_mm": m.pairwise_mean_mm,
            "abs_rms_mm": float(np.sqrt(np.mean(np.sum(err ** 2, axis=1)))), "t_xy_mm": e["t_xy_mm"],
            "rotation_deg": e["rot_deg"], "uv": np.array([o.uv for o in val.observations]),
            "err_mm": np.linalg.norm(err, axis=1), "std_mm": sig[:, 0], "t_unit_mm2": sig[:, 1],
            "lever_mm": sig[:, 2], "std_old_mm": sig[:, 3], "heading_mm": sig[:, 4], "sigma_t_mm": sig[:, 5],
            "size": sim.model.size, "metrics": m, "heading_weight": weight if case.comp.heading_fit else None}


def summarise(rows: list[dict[str, Any]]) -> dict[str, tuple[float, float]]:
    """Median and p95 over seeds of each metric."""
    return {k: (float(np.median([r[k] for r in rows])), float(np.percentile([r[k] for r in rows], 95)))
            for k in METRICS}


__all__ = ["Calibration", "Case", "GOALS_MM", "METRICS", "PAPER_MM", "measure_all", "referencing", "run",
           "summarise"]
