"""Referencing-plate definition: ChArUco target, three reflector nests, SMR offset.

PCS (``ref``) is the OpenCV board frame: origin at the board's first chessboard
corner, x along columns, y along rows, z *into* the plate; the target surface is
z = 0. Nest seat points ``ref_P_nst`` lie on (or parallel to) the surface; the
mounted SMR centre is ``ref_P_smr = ref_P_nst − (0, 0, δ)`` (paper, eq. for
ref_P_smr): δ > 0 is the SMR centre's height above the seat, and z points down.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from calibration.patches import Patch

NEST_NAMES = ("red", "green", "blue")
PLATE_SCHEMA = 1


@dataclass
class Plate:
    """What the calibration knows about one physical referencing plate."""

    plate_id: str
    board_cols: int
    board_rows: int
    square_mm: float
    marker_mm: float
    aruco_dict: str
    nests_ref_nst: dict[str, list[float]]  # seat points in PCS, mm
    smr_offset_mm: float  # delta_smr,nst
    notes: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    #: survey patches (calibration/patches.py); absent in plates made before the survey existed
    patches: list[dict[str, Any]] = field(default_factory=list)
    #: 1σ of each surveyed nest seat per PCS axis (mm), and the survey's report (ritactl plate survey)
    nests_sigma_mm: dict[str, list[float]] = field(default_factory=dict)
    survey: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.validate()

    # ------------------------------------------------------------------ geometry

    def ref_P_smr(self) -> np.ndarray:
        """SMR centres in PCS, rows in the order red, green, blue (3x3)."""
        P = np.array([self.nests_ref_nst[n] for n in NEST_NAMES], dtype=float)
        P[:, 2] -= self.smr_offset_mm
        return P

    def board_size_mm(self) -> tuple[float, float]:
        return self.board_cols * self.square_mm, self.board_rows * self.square_mm

    def survey_patches(self) -> list["Patch"]:
        """The survey patches as :class:`calibration.patches.Patch` (validated)."""
        from calibration.patches import parse_patches

        return parse_patches(self.patches, (self.board_cols * self.board_rows) // 2, self.aruco_dict,
                             f"plate {self.plate_id!r}")

    # ------------------------------------------------------------------ checks

    def validate(self) -> None:
        """Raise ValueError naming the bad field."""
        at = f"plate {self.plate_id!r}"
        if self.board_cols < 3 or self.board_rows < 3:
            raise ValueError(f"{at}: board {self.board_cols}x{self.board_rows} is too small")
        if not 0 < self.marker_mm < self.square_mm:
            raise ValueError(f"{at}: marker_mm={self.marker_mm} must be in (0, square_mm="
                             f"{self.square_mm})")
        if not 0.1 <= self.square_mm <= 100:
            raise ValueError(f"{at}: square_mm={self.square_mm} is not a sensible size")
        missing = [n for n in NEST_NAMES if n not in self.nests_ref_nst]
        if missing or len(self.nests_ref_nst) != 3:
            raise ValueError(f"{at}: nests must be exactly {NEST_NAMES}, "
                             f"got {sorted(self.nests_ref_nst)}")
        for n, p in self.nests_ref_nst.items():
            if len(p) != 3 or not all(np.isfinite(p)):
                raise ValueError(f"{at}: nest {n!r} must be 3 finite numbers, got {p}")
            if max(abs(float(v)) for v in p) > 10_000:
                raise ValueError(f"{at}: nest {n!r} at {p} mm is not on a plate (beyond ±10 m)")
        if not 0 <= self.smr_offset_mm <= 100:
            raise ValueError(f"{at}: smr_offset_mm={self.smr_offset_mm} out of range 0..100")
        P = self.ref_P_smr()
        sides = [np.linalg.norm(P[i] - P[j]) for i, j in ((0, 1), (1, 2), (2, 0))]
        if min(sides) < 50.0:
            raise ValueError(f"{at}: nests only {min(sides):.1f} mm apart (need >= 50)")
        area2 = np.linalg.norm(np.cross(P[1] - P[0], P[2] - P[0]))
        # height of the triangle over its longest side: near zero means collinear nests
        if area2 / max(sides) < 0.1 * max(sides):
            raise ValueError(f"{at}: nests are (nearly) collinear "
                             f"(triangle height {area2 / max(sides):.1f} mm over a {max(sides):.1f} mm side)")
        if self.patches:
            self.survey_patches()
        for n, s in self.nests_sigma_mm.items():
            if not (n in NEST_NAMES and _three_sigmas(s)):
                raise ValueError(f"{at}: nests_sigma_mm.{n} must be a nest name with "
                                 f"3 finite numbers >= 0 (mm), got {s!r}")

    # ------------------------------------------------------------------ files

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for key in ("patches", "nests_sigma_mm", "survey"):  # optional: files without them stay as before
            if not d[key]:
                del d[key]
        return {"schema": PLATE_SCHEMA, **d}

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "plate") -> "Plate":
        """Inverse of :meth:`to_dict`; every error is a ValueError naming ``source`` and the key."""
        if not isinstance(d, dict):
            raise ValueError(f"{source}: expected a JSON object (plate definition), got {type(d).__name__}")
        d = dict(d)
        schema = d.pop("schema", PLATE_SCHEMA)
        if schema != PLATE_SCHEMA or isinstance(schema, bool):
            raise ValueError(f"{source}: plate schema {schema!r} is not supported (expected {PLATE_SCHEMA})")
        missing = [k for k in _REQUIRED if k not in d]
        if missing:
            raise ValueError(f"{source}: missing key(s) {', '.join(map(repr, missing))}")
        unknown = sorted(set(d) - set(_REQUIRED) - set(_OPTIONAL))
        if unknown:
            raise ValueError(f"{source}: unknown key(s) {', '.join(map(repr, unknown))}")
        for key, kind in {**_REQUIRED, **_OPTIONAL}.items():
            if key in d:
                d[key] = _typed(d[key], kind, f"{source}: {key}")
        d["nests_ref_nst"] = {name: _typed(p, list, f"{source}: nests_ref_nst.{name}")
                              for name, p in d["nests_ref_nst"].items()}
        try:
            return cls(**d)
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None


#: keys of a plate file and the JSON type each must have
_REQUIRED: dict[str, type] = {"plate_id": str, "board_cols": int, "board_rows": int, "square_mm": float,
                              "marker_mm": float, "aruco_dict": str, "nests_ref_nst": dict,
                              "smr_offset_mm": float}
#: (``object``: checked by :meth:`Plate.validate`, which names the bad entry)
_OPTIONAL: dict[str, type] = {"notes": str, "extra": dict, "patches": object, "nests_sigma_mm": dict,
                              "survey": dict}


def _typed(value: Any, kind: type, where: str) -> Any:
    """``value`` checked as JSON type ``kind`` (numbers finite, three of them for a point)."""
    if kind is list:
        ok = (isinstance(value, (list, tuple)) and len(value) == 3
              and all(_is_number(v) and np.isfinite(v) for v in value))
        if not ok:
            raise ValueError(f"{where} must be 3 finite numbers [x, y, z] in mm, got {value!r}")
        return [float(v) for v in value]
    if kind is float:
        if not (_is_number(value) and np.isfinite(value)):
            raise ValueError(f"{where} must be a finite number, got {value!r}")
        return float(value)
    if kind is int:
        if not (_is_number(value) and float(value).is_integer()):
            raise ValueError(f"{where} must be a whole number, got {value!r}")
        return int(value)
    if not isinstance(value, kind):
        raise ValueError(f"{where} must be a JSON {'string' if kind is str else 'object'}, got {value!r}")
    return value


def _three_sigmas(s: object) -> bool:
    """3 finite numbers >= 0: a nests_sigma_mm entry as read from a plate file, before it is trusted."""
    return isinstance(s, list) and len(s) == 3 and all(_is_number(v) and np.isfinite(v) and v >= 0 for v in s)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)
