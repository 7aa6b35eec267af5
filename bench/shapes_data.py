"""Simulated experiments as the product's records, for bench/accuracy_shapes.py.

The rendering-free simulation (fakes/simulate.py) gives each stop's tracker points, stream,
inclinometer readings and the mark's pixel position (projected truth + 0.05 px). Here they
become what the worker records (docs/datasets.md, "Experiment" and "Compensations"), so that the
product's own ``compute_experiment`` and ``biased_calibration`` (the live ``store_bias``)
compute every figure, σ and verdict: the harness judges the product, not a copy of it.

The image a stop's record names is a synthetic one: an anti-aliased dark dot centred on the
simulated pixel position (located back to ~0.01 px, far below the 0.05 px the simulation draws),
so the mark locator reads what the rendering-free simulation says the camera saw, in
milliseconds instead of the renderer's second per image.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from calibration.frames import apply_H, inv_H
from daemon.bus.procedure_params import SPEED
from fakes.accuracy import Calibration
from fakes.simulate import MarkObs, ValidationSet

#: the dot drawn (radius, mm: the world's M1) and its grey levels
DOT_RADIUS_MM = 0.4
BACKGROUND, DOT = 200.0, 40.0
#: supersampling per pixel axis when drawing the dot's edge
SUPERSAMPLE = 8


def calibration_record(cal: Calibration, job: str = "sim-referencing") -> dict[str, Any]:
    """The referencing result's fields later jobs read (docs/datasets.md), from the simulated referencing."""
    out: dict[str, Any] = {"job": job, "rob_H_scn": cal.rob_H_scn.tolist(), "verdict": "ok",
                           "rob_H_cam": cal.rob_H_cam.tolist(), "scs": cal.scs.to_dict()}
    if cal.cov is not None:
        out["uncertainty"] = {"cov_rob_H_scn": np.asarray(cal.cov).tolist()}
    if cal.imu_offset is not None:
        out["imu_offset_deg"] = [float(cal.imu_offset[0]), float(cal.imu_offset[1])]
        out["imu_yaw_deg"] = float(cal.imu_yaw_deg)
    if cal.mount is not None:
        out["reflector_mount"] = cal.mount.to_dict()
    return out


def point(abs_P: np.ndarray, abs_H_trk: np.ndarray) -> dict[str, Any]:
    """A tracker point as ritad stores it: ACS, tracker-frame x y z, the abs_H_trk it was measured with."""
    trk = apply_H(inv_H(abs_H_trk), np.asarray(abs_P, float))
    return {"abs_xyz": [float(v) for v in abs_P], "x": float(trk[0]), "y": float(trk[1]), "z": float(trk[2]),
            "abs_H_trk": abs_H_trk.tolist()}


def _imu(roll: float | None, pitch: float | None) -> dict[str, Any] | None:
    return None if roll is None or pitch is None else {"roll_deg": float(roll), "pitch_deg": float(pitch)}


def stop_record(o: MarkObs, i: int, abs_H_trk: np.ndarray, move_mm: float) -> dict[str, Any]:
    """One stop's record: its direction, approach points, stream, inclinometer and the image it names."""
    rec: dict[str, Any] = {"k": int(o.direction), "P_prev": point(o.abs_P_prev, abs_H_trk),
                           "P_at": point(o.abs_P_at, abs_H_trk), "move_mm": float(move_mm),
                           "image": f"stop-{i}"}
    if o.stream is not None:  # evenly spaced along the move, driven at the procedures' default speed
        n, seconds = len(o.stream), abs(move_mm) / SPEED.default
        rec["stream"] = {"n": n, "abs_xyz": np.asarray(o.stream).tolist(), "rate_hz": (n - 1) / seconds,
                         "host_time_ns": [int(round(1e9 * seconds * i / (n - 1))) for i in range(n)]}
        if o.stream_tilt_deg is not None:
            rec["stream"]["tilt_deg"] = np.asarray(o.stream_tilt_deg).tolist()
    for key, rp in (("imu_prev", (o.prev_roll_deg, o.prev_pitch_deg)), ("imu_at", (o.roll_deg, o.pitch_deg))):
        if _imu(*rp) is not None:
            rec[key] = _imu(*rp)
    return rec


def experiment_obs(val: ValidationSet, calib: dict[str, Any], compensation: str, abs_H_trk: np.ndarray,
                   move_mm: float) -> dict[str, Any]:
    """The experiment's observation record (what ``compute_experiment`` reads)."""
    return {"calibration": calib, "compensation": compensation, "kind": "dot", "mark_size_mm": DOT_RADIUS_MM,
            "stops": [stop_record(o, i, abs_H_trk, move_mm) for i, o in enumerate(val.observations)]}


def dot_image(uv: np.ndarray, radius_px: float, size: tuple[int, int]) -> np.ndarray:
    """An 8-bit image (h, w) of a dark anti-aliased dot of ``radius_px`` centred on ``uv`` (pixel centres
    at integers, the project's convention)."""
    w, h = size
    img = np.full((h, w), BACKGROUND)
    r = int(np.ceil(radius_px)) + 3
    u0, v0 = int(round(uv[0])), int(round(uv[1]))
    us, vs = np.arange(u0 - r, u0 + r + 1), np.arange(v0 - r, v0 + r + 1)
    off = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5  # sub-pixel sample offsets
    su = (us[:, None] + off[None, :]).ravel() - uv[0]
    sv = (vs[:, None] + off[None, :]).ravel() - uv[1]
    inside = (sv[:, None] ** 2 + su[None, :] ** 2) <= radius_px ** 2
    cover = inside.reshape(len(vs), SUPERSAMPLE, len(us), SUPERSAMPLE).mean(axis=(1, 3))
    ok_v, ok_u = (vs >= 0) & (vs < h), (us >= 0) & (us < w)
    patch = BACKGROUND + (DOT - BACKGROUND) * cover
    img[np.ix_(vs[ok_v], us[ok_u])] = patch[np.ix_(ok_v, ok_u)]
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def image_loader(val: ValidationSet, gsd_mm: float, size: tuple[int, int]) -> Any:
    """``load(name)`` for compute_experiment: stop i's synthetic image."""
    radius = DOT_RADIUS_MM / gsd_mm

    def load(name: str) -> np.ndarray:
        i = int(name.rsplit("-", 1)[1])
        return dot_image(np.asarray(val.observations[i].uv, float), radius, size)
    return load


__all__ = ["calibration_record", "dot_image", "experiment_obs", "image_loader", "point", "stop_record"]
