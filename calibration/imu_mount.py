"""The inclinometer's mounting in the body, as far as the referencing runs show it.

A sensor fixed to the body reads, to first order in its small angles,

    reading = R(−ψ) · t + o

with ``t`` the body's (roll, pitch) and ``o`` the mounting's roll/pitch offset; ``ψ`` is
its yaw in the body, which rotates the tilt it sees. On the plate the tracker gives ``t``
(:func:`calibration.compensation.tilt_of_pose`). One run gives ``o`` only if ``ψ = 0``:
an unknown yaw is absorbed as ``(R(−ψ) − I)·t`` and comes back at every other tilt. Two runs
at different body tilts (the 0°/180° reversal turns the plate's tilt around in the body)
give ``o`` and ``ψ``; then their yaw-free offsets disagree by ``(R(−ψ) − I)(t₁ − t₂)``, which
is the self-check: a disagreement that a plausible yaw does not explain is reported and the
offset is not used. At use the body's tilt is ``R(ψ)·(reading − o)`` (:func:`body_tilt`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

#: the yaw a sensor screwed to a machined face may have (an assumption, no source: it only sizes the
#: warning of a single run, and docs/accuracy.md lists it among the unsourced assumptions)
MAX_MOUNT_YAW_DEG = 2.0
#: a fitted yaw beyond this is no mounting error: the data contradict the model
PLAUSIBLE_YAW_DEG = 10.0
#: lateral error at the reflector from an unresolved yaw above which a single run warns
YAW_WARN_UM = 50.0
#: the least 1σ credited to an averaged standstill reading (deg): the SCA100T's noise density class
READING_SIGMA_FLOOR_DEG = 0.002
#: 1σ (deg, per axis) of the body's tilt on the plate about the plate normal the tracker gives: the wheels
#: and the caster stand on the plate's own unevenness (the paper's "plane within sub-millimeter
#: tolerances"; 20 µm rms over the ~0.4 m between the contacts ≈ 70 µrad, an assumption like the
#: simulation's, docs/accuracy.md). It sits in each run's offset beside the reading's own noise.
SEATING_SIGMA_DEG = 0.004
#: body tilts closer than this (deg) across the runs cannot resolve a yaw
MIN_TILT_SPREAD_DEG = 0.05


def rot2(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def body_tilt(reading: Sequence[float], offset: Sequence[float], yaw_deg: float = 0.0) -> tuple[float, float]:
    """The body's (roll, pitch) in degrees from a reading, the mounting offset and yaw."""
    t = rot2(yaw_deg) @ (np.asarray(reading, float) - np.asarray(offset, float))
    return float(t[0]), float(t[1])


@dataclass
class ImuMount:
    """What the runs give: the offset, the yaw (None when not resolved), checks and their messages."""

    offset_deg: list[float] | None  # None: the data contradict the model; do not compensate the tilt
    yaw_deg: float | None
    yaw_sigma_deg: float | None
    runs_offset_deg: list[list[float]]  # each run's yaw-free offset (reading − body tilt)
    verdict: str = "ok"
    messages: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, object]:
        return {"imu_offset_deg": self.offset_deg, "imu_yaw_deg": self.yaw_deg,
                "imu_yaw_sigma_deg": self.yaw_sigma_deg, "runs": self.runs_offset_deg,
                "verdict": self.verdict, "messages": list(self.messages)}


def _single(off: np.ndarray, t: np.ndarray, height_mm: float) -> ImuMount:
    tilt = float(np.hypot(*t))
    bound_um = math.sin(math.radians(MAX_MOUNT_YAW_DEG)) * math.radians(tilt) * height_mm * 1000.0
    out = ImuMount(off.tolist(), None, None, [off.tolist()])
    if bound_um > YAW_WARN_UM:
        out.verdict = "warn"
        out.messages.append(
            f"inclinometer yaw not resolved by a single run: on this plate, tilted {tilt:.2f}°, a sensor "
            f"yawed {MAX_MOUNT_YAW_DEG:g}° in the body would leave {bound_um:.0f} µm of lean at the "
            f"reflector wherever the floor is level; run the referencing with --reversal to measure the yaw")
    return out


def imu_mount(body_tilts: Sequence[Sequence[float]], readings: Sequence[Sequence[float]],
              reading_sigma_deg: Sequence[float], height_mm: float,
              seating_sigma_deg: float = SEATING_SIGMA_DEG) -> ImuMount:
    """Offset and yaw from the runs' body tilts (tracker) and readings; see the module docstring.
    Each run's offset is known to its reading's σ (at least :data:`READING_SIGMA_FLOOR_DEG`) and the
    body's seating on the plate (``seating_sigma_deg``) together."""
    t = np.asarray(body_tilts, float).reshape(-1, 2)
    r = np.asarray(readings, float).reshape(-1, 2)
    sig = np.hypot(np.maximum(np.asarray(reading_sigma_deg, float).reshape(-1), READING_SIGMA_FLOOR_DEG),
                   seating_sigma_deg)
    offs = r - t
    if len(t) == 1:
        return _single(offs[0], t[0], height_mm)
    spread = float(np.max(np.linalg.norm(t[:, None] - t[None], axis=2)))
    d = offs[0] - offs[1]
    sd = float(np.hypot(sig[0], sig[1]))
    agree = float(np.hypot(*d)) <= 3.0 * sd
    if spread < MIN_TILT_SPREAD_DEG:
        msg = [] if agree else [f"the runs' inclinometer offsets disagree by {np.hypot(*d):.4f}° (3σ "
                                f"{3 * sd:.4f}°) although the body's tilt hardly differed between them: "
                                f"the inclinometer is not read as modelled; the tilt compensation is not "
                                f"calibrated"]
        return ImuMount(offs.mean(axis=0).tolist() if agree else None, None, None, offs.tolist(),
                        "ok" if agree else "warn", msg)
    # reading = [[c, s], [−s, c]]·t + o: linear in (o_r, o_p, c, s); weighted by each run's σ
    A = np.vstack([np.hstack([np.eye(2), np.array([[tr, tp], [tp, -tr]])]) for tr, tp in t])
    w = np.repeat(1.0 / sig ** 2, 2)
    cov = np.linalg.inv(A.T @ (A * w[:, None]))
    o_r, o_p, c, s = cov @ (A.T @ (w * r.reshape(-1)))
    yaw = math.degrees(math.atan2(s, c))  # R(−ψ) = [[c, s], [−s, c]] with c = cos ψ, s = sin ψ
    yaw_sigma = math.degrees(math.sqrt(max(cov[3, 3], 0.0)))
    scale = math.hypot(c, s)
    out = ImuMount([float(o_r), float(o_p)], yaw, yaw_sigma, offs.tolist())
    implausible = abs(yaw) > PLAUSIBLE_YAW_DEG or abs(scale - 1.0) > 0.2
    if implausible and not agree:
        out.offset_deg, out.yaw_deg, out.verdict = None, None, "warn"
        out.messages.append(
            f"the runs' inclinometer offsets disagree by {np.hypot(*d):.4f}° (3σ {3 * sd:.4f}°), more than a "
            f"mounting yaw explains (fitted yaw {yaw:.1f}°, gain {scale:.2f}): the inclinometer or the drive "
            f"direction is not as recorded; the tilt compensation is not calibrated")
    elif implausible or abs(yaw) <= 3.0 * yaw_sigma:
        # not shown (a fit of a small tilt spread may wander): the offsets agree, their mean is the offset
        out.yaw_deg = 0.0
        out.offset_deg = offs.mean(axis=0).tolist()
        if implausible:  # that fit's σ describes no yaw
            out.yaw_sigma_deg = None
    else:
        out.messages.append(f"the inclinometer is yawed {yaw:.2f}° ± {yaw_sigma:.2f}° in the body (from the "
                            f"runs' offsets, which disagree by {np.hypot(*d):.4f}°): the tilt is compensated "
                            f"with it")
    return out
