"""compensate(): the heading fit on a tilted robot, with and without the inclinometer read along the stream."""
from __future__ import annotations

import math

import numpy as np

from calibration.compensation import NO_STREAM_TILT, Compensation, Stop, body_z, compensate


def _rob_H_scn(height_mm: float) -> np.ndarray:
    H = np.eye(4)
    H[:3, 3] = [300.0, 0.0, -height_mm]  # the SCS plane height_mm below the reflector
    return H


def test_straight_ground_path_with_changing_roll_fits_no_bend():
    """The floor rolls 0 → 0.05° along a straight 200 mm move: the reflector drifts sideways, the ground does not."""
    h, n = 300.0, 41
    s = np.linspace(0.0, 200.0, n)
    roll = 0.05 * s / 200.0
    ground = np.column_stack([s, np.zeros(n), np.zeros(n)])
    refl = np.array([g + h * body_z(0.0, r, 0.0) for g, r in zip(ground, roll)])
    tilt = np.column_stack([roll, np.zeros(n)])
    stop = Stop(refl[0], refl[-1], (0.0, 0.0), (0.05, 0.0), refl, tilt)
    comp = Compensation(tilt=True, heading_fit=True)
    a = compensate(comp, stop, _rob_H_scn(h), imu_offset=(0.0, 0.0))
    assert a.applied == ["tilt", "heading_fit"] and a.skipped == {}
    v = refl[-1] - a.abs_P_prev
    assert abs(math.atan2(v[1], v[0])) < 1e-6  # the ground path's heading, 0
    # without readings along the stream the lean would look like a bend: the fit is skipped, the
    # ground chord (from the two standstill readings) stays
    b = compensate(comp, Stop(refl[0], refl[-1], (0.0, 0.0), (0.05, 0.0), refl, None), _rob_H_scn(h),
                   imu_offset=(0.0, 0.0))
    assert b.applied == ["tilt"] and b.skipped == {"heading_fit": NO_STREAM_TILT}
    v = refl[-1] - b.abs_P_prev
    assert abs(math.atan2(v[1], v[0])) < 1e-6
    raw = compensate(Compensation(heading_fit=True), stop, _rob_H_scn(h))
    w = refl[-1] - raw.abs_P_prev
    assert abs(math.atan2(w[1], w[0])) > 1e-3  # the reflector's path bends: 0.26 mm over 200 mm
