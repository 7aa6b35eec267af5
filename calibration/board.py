"""A hand-held ChArUco calibration board (``board.json``) for the camera's intrinsics.

The referencing plate's target cannot separate the focal length from the distance
(the camera only sees it from near nadir), so the intrinsics use a small rigid board
the operator holds under the camera at several tilts (docs/operations.md,
"Intrinsic calibration"). Its definition file has the same board fields as a plate
(``board_cols``, ``board_rows``, ``square_mm``, ``marker_mm``, ``aruco_dict``), so
:func:`calibration.target.make_board` and :func:`calibration.target.detect_corners`
take a Board wherever they take a Plate. Schema: ``daemon/bus/schemas/board.schema.json``.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # imported where used: OpenCV loads at the first detection
    from calibration.target import BoardLayout

BOARD_SCHEMA = 1

#: the board the recipe is written for: 12 x 9 squares of 4 mm (48 x 36 mm), 4x4-bit markers
#: (not the plate's 5x5 dictionary, so plate markers behind it are never taken for board markers).
#: It fills about half of the nadir camera's field at 35 mm (the field is ~75 x 55 mm there:
#: f = 470 px at 1000 px width) and is small enough to hold and tilt
#: by 45° between the camera (30 mm above the support) and a raised stand.
DEFAULT_BOARD = {"schema": BOARD_SCHEMA, "board_id": "RITA-INTRINSICS-1", "board_cols": 12, "board_rows": 9,
                 "square_mm": 4.0, "marker_mm": 3.0, "aruco_dict": "DICT_4X4_100",
                 "notes": "print on glass or aluminium; measure one square with a calliper"}


@dataclass(frozen=True)
class Board:
    """What the calibration knows about one printed ChArUco board (its nominal print)."""

    board_id: str
    board_cols: int
    board_rows: int
    square_mm: float
    marker_mm: float
    aruco_dict: str
    notes: str = ""

    def __post_init__(self) -> None:
        if self.board_cols < 3 or self.board_rows < 3:
            raise ValueError(f"board {self.board_id!r}: {self.board_cols}x{self.board_rows} squares "
                             f"is too small (need at least 3x3)")
        if not 0.1 <= self.square_mm <= 100:
            raise ValueError(f"board {self.board_id!r}: square_mm={self.square_mm} is not in 0.1..100")
        if not 0 < self.marker_mm < self.square_mm:
            raise ValueError(f"board {self.board_id!r}: marker_mm={self.marker_mm} must be in (0, square_mm="
                             f"{self.square_mm})")
        from calibration.patches import dictionary_size

        try:
            size = dictionary_size(self.aruco_dict)
        except ValueError:
            raise ValueError(f"board {self.board_id!r}: aruco_dict={self.aruco_dict!r} is not an OpenCV "
                             f"dictionary name (e.g. 'DICT_4X4_100')") from None
        needed = self.board_cols * self.board_rows // 2
        if needed > size:  # checked here, not at the first capture after the operator set up
            raise ValueError(f"board {self.board_id!r}: {self.board_cols}x{self.board_rows} squares need "
                             f"{needed} markers, {self.aruco_dict} has {size}")

    def board_size_mm(self) -> tuple[float, float]:
        return self.board_cols * self.square_mm, self.board_rows * self.square_mm

    @property
    def n_corners(self) -> int:
        """Inner chessboard corners (the points the calibration uses)."""
        return (self.board_cols - 1) * (self.board_rows - 1)

    def to_dict(self) -> dict[str, Any]:
        return {"schema": BOARD_SCHEMA, **asdict(self)}

    @classmethod
    def from_dict(cls, d: Any, source: str = "board file") -> "Board":
        """Inverse of :meth:`to_dict`; every error is a ValueError naming ``source`` and the key."""
        if not isinstance(d, dict):
            raise ValueError(f"{source}: expected a JSON object (board definition), got {type(d).__name__}")
        schema = d.get("schema", BOARD_SCHEMA)
        if schema != BOARD_SCHEMA or isinstance(schema, bool):
            raise ValueError(f"{source}: board schema {schema!r} is not supported (expected {BOARD_SCHEMA})")
        kinds: dict[str, type | tuple[type, ...]] = {
            "board_id": str, "board_cols": int, "board_rows": int, "square_mm": (int, float),
            "marker_mm": (int, float), "aruco_dict": str, "notes": str}
        missing = [k for k in kinds if k not in d and k != "notes"]
        if missing:
            raise ValueError(f"{source}: missing key(s) {', '.join(map(repr, missing))}")
        for key, kind in kinds.items():
            if key in d and (not isinstance(d[key], kind) or isinstance(d[key], bool)):
                raise ValueError(f"{source}: {key} has the wrong type ({d[key]!r})")
        try:
            return cls(**{k: d[k] for k in kinds if k in d})
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None


def detect_board_corners(image: np.ndarray, board: BoardLayout) -> tuple[np.ndarray, np.ndarray]:
    """ChArUco corners of ``board`` in ``image``: ``(ids (N,), uv (N, 2))``.

    Uses OpenCV's own marker detection (``fast=False``): for a board's small dictionary it
    is as quick as the plate-tuned fast path, and it finds the small 4x4 markers that path
    misses (docs/accuracy.md, "Reference figures").
    """
    from calibration.target import detect_corners

    return detect_corners(image, board, fast=False)
