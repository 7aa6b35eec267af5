"""The simulated world's error model: every effect a named magnitude with its source.

Each group is a frozen dataclass whose defaults are the ``paper`` profile's magnitudes
(fakes/profiles.py); the source of every number sits next to it (``field`` metadata
``source``) and is listed in docs/accuracy.md, "Simulated error sources"
(:func:`sources_table` prints that table). A group set to ``None`` in
:class:`ErrorModel` is switched off; ``ErrorModel()`` (every group off) is the
``ideal`` world, bit-identical to the world before this model existed.

How each magnitude is applied is in :mod:`fakes.effects` (tracker, reflectors, IMU,
target print) and :mod:`fakes.floor` (floor and plate height maps, wheel contacts).
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

from fakes.path_shapes import SHAPES

#: sources quoted more than once
AT_MPE = ("AT901 U_xyz MPE ±15 µm + 6 µm/m (Leica AT500 manual p. 39: published for the AT500, "
          "unverified for the AT901)")
TYPICAL = "Leica: typical = ½ MPE (AT500 manual p. 39); we take the typical value as 1σ"
ADM = "ADM MPE ±10 µm + 0.3 µm/m (AT500 manual p. 39)"
#: RobotErrors.path_shape values (fakes/path_shapes.py)
PATH_SHAPES = SHAPES
CAL_44 = "assumed: 50 µm lateral path deviation between the heading positions 0.2 m apart"


def sourced(value: Any, source: str) -> Any:
    """A dataclass field with a default and the source of its magnitude."""
    return field(default=value, metadata={"source": source})


@dataclass(frozen=True)
class TrackerErrors:
    """Laser tracker (AT901): noise in spherical coordinates plus a per-station systematic part."""

    transverse_a_mm: float = sourced(0.015, AT_MPE + ": constant part, taken as the random part (noise, "
                                            "centring of the beam on the SMR); split is our assumption")
    transverse_b_mm_per_m: float = sourced(0.006, AT_MPE + ": distance part, taken as the systematic part "
                                                  "(angle encoder and axis residuals grow with distance); "
                                                  "split is our assumption")
    range_a_mm: float = sourced(0.010, ADM + ": random range part")
    range_b_mm_per_m: float = sourced(0.0003, ADM + ": systematic range part")
    mpe_to_sigma: float = sourced(0.5, TYPICAL)
    random_share_b: float = sourced(0.0, "assumption: share of the transverse distance part's variance that "
                                         "is random per reading instead of the station's smooth pattern "
                                         "(0 = all systematic); the MPE does not say how it splits; the "
                                         "sensitivity envelope takes 0.5")


@dataclass(frozen=True)
class ReflectorErrors:
    """SMRs and their seats: centring of the optics, nest re-seating, the robot's rotatable mount."""

    smr_centring_mm: float = sourced(0.005, "optical centre vs ball centre of a 1.5-inch SMR: ±2.5–12.7 µm "
                                            "by grade in typical SMR data sheets (unverified); 5 µm assumed")
    nest_reseat_mm: float = sourced(0.0025, "seating repeatability of a magnetic kinematic SMR nest, "
                                            "0.0001 in in typical nest data sheets (unverified); 1σ per axis")
    mount_eccentricity_mm: float = sourced(0.030, "paper §Robot: the SMR's movement in the rotatable mount "
                                                  "is 'sub-mm'; 30 µm assumed (radial runout of a "
                                                  "normal-class small ball bearing is 10–15 µm, ISO 492, "
                                                  "plus seat machining)")


@dataclass(frozen=True)
class RobotErrors:
    """Drive: each straight move bends on an arc (lateral and heading deviation together), wheel slip.

    The arc's curvature κ is drawn per move so that the lateral offset at the end of a
    move of ``lateral_ref_mm`` has σ = ``lateral_sigma_mm``: the end is κd²/2 to the side,
    the heading turns by κd, and the chord P_prev→P_at is off the final heading by κd/2
    (250 µrad for 50 µm over 0.2 m). These add to WorldParams.drive_*.
    """

    lateral_sigma_mm: float = sourced(0.050, CAL_44)
    path_shape: str = sourced("arc", "assumption: each move bends on one arc ('arc'); 's' bends left then "
                                     "right (curvature ±2κ over the halves): the same lateral offset at the "
                                     "end and the same chord-to-heading angle κd/2, but the heading turns "
                                     "back (envelope case); 'early', 'late' (the bend in the first or last "
                                     "30 %), 'kink' (a heading step at a random point), 'kink-end' (in the "
                                     "last 10 %): envelope cases no larger than the arc in end offset or "
                                     "turn (fakes/path_shapes.py)")
    lateral_ref_mm: float = sourced(200.0, CAL_44 + " (the move length the 50 µm refers to)")
    slip_sigma: float = sourced(0.002, "relative distance error per move from wheel slip; non-systematic "
                                       "odometry errors of 0.1–1 % of travel on smooth floors "
                                       "(Borenstein & Feng 1996, UMBmark; order of magnitude, unverified); "
                                       "0.2 % assumed")
    #: robot frame, mm: left and right drive wheel contacts and the front caster
    wheel_track_mm: float = sourced(400.0, "paper Fig. 1: differential drive with a front caster; dimensions "
                                           "not published, 0.4 m track assumed")
    caster_x_mm: float = sourced(350.0, "paper Fig. 1 (layout only); caster 0.35 m ahead of the drive axle "
                                        "assumed, the reflector above the axle centre")

    def __post_init__(self) -> None:
        if self.path_shape not in PATH_SHAPES:
            raise ValueError(f"RobotErrors.path_shape={self.path_shape!r} (known: {', '.join(PATH_SHAPES)})")


@dataclass(frozen=True)
class FloorErrors:
    """Shop floor: global slope and a smooth random waviness (Gaussian-correlated height field)."""

    slope_sigma_mrad: float = sourced(1.0, "assumption: 1 mm/m per axis; well inside DIN 18202 Table 3 row 3 "
                                           "(4 mm over 1 m); ACS z is the levelled tracker's vertical")
    rms_slope_mrad: float = sourced(0.5, "assumed: robot tilt at use from floor unevenness ≈ 0.5 mrad "
                                         "(rms slope of the waviness per axis)")
    correlation_mm: float = sourced(400.0, "assumption: of the order of the wheel base; gives 0.2 mm rms "
                                           "height, inside DIN 18202 Table 3 row 4 (3 mm over 1 m)")


@dataclass(frozen=True)
class PlateErrors:
    """Referencing plate (19 mm glass): thickness and flatness."""

    thickness_tol_mm: float = sourced(1.0, "EN 572-2 float glass thickness tolerance for 19 mm: ±1.0 mm "
                                           "(uniform draw)")
    flatness_rms_mm: float = sourced(0.020, "paper §Referencing plate: 'conforms to a plane within "
                                            "sub-millimeter tolerances'; 20 µm rms assumed for float glass")
    flatness_correlation_mm: float = sourced(300.0, "assumption: a few waves over the 1.1 m plate")


@dataclass(frozen=True)
class TargetErrors:
    """Printed calibration target versus its nominal definition."""

    scale_sigma: float = sourced(2e-4, "assumption: 200 ppm print scale error of a professionally printed "
                                       "target (0.02 mm over 100 mm)")
    shear_sigma_rad: float = sourced(1e-4, "assumption: 0.1 mrad non-orthogonality of the printed grid")


@dataclass(frozen=True)
class ImuErrors:
    """The base's inclinometer/IMU (``paper+imu`` only): roll and pitch per STATUS."""

    noise_sigma_deg: float = sourced(0.0025, "Murata SCA100T/SCA121T dual-axis inclinometer data sheet: "
                                             "0.0025° resolution at 10 Hz bandwidth, taken as 1σ noise per "
                                             "reading")
    bias_sigma_deg: float = sourced(0.0057, "assumption: 0.1 mrad per axis residual zero offset and mounting "
                                            "misalignment after a one-time levelling, constant per power-on")


@dataclass(frozen=True)
class ErrorModel:
    """All effect groups; ``None`` = off. ``ErrorModel()`` is the ideal world."""

    tracker: TrackerErrors | None = None
    reflector: ReflectorErrors | None = None
    robot: RobotErrors | None = None
    floor: FloorErrors | None = None
    plate: PlateErrors | None = None
    target: TargetErrors | None = None
    imu: ImuErrors | None = None

    @classmethod
    def paper(cls) -> "ErrorModel":
        """Every group at its sourced magnitude except the IMU (the paper's Rita had none)."""
        return cls(TrackerErrors(), ReflectorErrors(), RobotErrors(), FloorErrors(), PlateErrors(),
                   TargetErrors(), None)

    def tweaked(self, tweaks: tuple[tuple[str, str, Any], ...]) -> "ErrorModel":
        """The same model with ``(group, field, value)`` changes (sensitivity cases); the group must be on."""
        out = self
        for group, name, value in tweaks:
            g = getattr(out, group, None) if group in GROUPS else None
            if g is None or name not in {f.name for f in fields(g)}:
                raise ValueError(f"cannot set {group}.{name}: no such field in an active error group")
            out = replace(out, **{group: replace(g, **{name: value})})
        return out

    def without(self, *groups: str) -> "ErrorModel":
        """The same model with ``groups`` switched off (for one-effect-off budgets)."""
        unknown = sorted(set(groups) - set(GROUPS))
        if unknown:
            raise ValueError(f"unknown error group(s) {', '.join(unknown)} (known: {', '.join(GROUPS)})")
        return replace(self, **{g: None for g in groups})

    @property
    def active(self) -> bool:
        return any(getattr(self, g) is not None for g in GROUPS)

    def summary(self) -> dict[str, Any]:
        """JSON-able magnitudes of the groups that are on (for sim.truth and reports)."""
        out: dict[str, Any] = {}
        for g in GROUPS:
            v = getattr(self, g)
            if v is not None:
                out[g] = {f.name: getattr(v, f.name) for f in fields(v)}
        return out


#: group names in ErrorModel order
GROUPS = tuple(f.name for f in fields(ErrorModel))
#: the group classes, for the sources table
GROUP_CLASSES = (TrackerErrors, ReflectorErrors, RobotErrors, FloorErrors, PlateErrors, TargetErrors,
                 ImuErrors)


def sources_table() -> str:
    """The markdown table of every magnitude and its source (docs/accuracy.md)."""
    rows = ["| Group | Parameter | paper value | Source |", "|---|---|---:|---|"]
    for group, cls in zip(GROUPS, GROUP_CLASSES):
        for f in fields(cls):
            value = f.default if isinstance(f.default, str) else f"{f.default:g}"
            rows.append(f"| {group} | `{f.name}` | {value} | {f.metadata['source']} |")
    return "\n".join(rows)


__all__ = ["ErrorModel", "FloorErrors", "GROUPS", "ImuErrors", "PATH_SHAPES", "PlateErrors",
           "ReflectorErrors", "RobotErrors", "TargetErrors", "TrackerErrors", "sourced", "sources_table"]
