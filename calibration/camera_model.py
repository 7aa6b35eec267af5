"""Pinhole camera with Brown (OpenCV 5-coefficient) distortion.

The model follows OpenCV conventions: integer pixel coordinates are pixel *centres*,
``uv`` is (column, row), the camera frame (CCS) has x right, y down and z along the
optical axis. ``undistort`` uses tight iteration criteria: OpenCV's default leaves
about 4e-5 px of round-trip error in the image corners, the criteria below ~1e-12.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

#: undistortPoints: 100 iterations or 1e-12 change (the default's error: docs/accuracy.md, "Image side")
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
MODEL_SCHEMA = 1


def _points(uv: np.ndarray, cols: int, name: str) -> np.ndarray:
    """Return ``uv`` as a finite float64 (N, cols) array or raise ValueError naming it."""
    a = np.asarray(uv, dtype=float)
    if a.ndim == 1 and a.shape[0] == cols:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != cols:
        raise ValueError(f"{name}: expected an (N, {cols}) array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains non-finite values")
    return a


@dataclass
class CameraModel:
    """Intrinsics ``K`` (3x3), distortion ``dist`` (k1, k2, p1, p2, k3) and image ``size`` (w, h)."""

    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int]

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=float)
        self.dist = np.asarray(self.dist, dtype=float).reshape(-1)
        self.size = (int(self.size[0]), int(self.size[1]))
        if self.K.shape != (3, 3) or not np.all(np.isfinite(self.K)):
            raise ValueError(f"CameraModel: K must be a finite 3x3 matrix, got {self.K!r}")
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0 or abs(self.K[2, 2] - 1) > 1e-12:
            raise ValueError(f"CameraModel: K has fx={self.K[0, 0]}, fy={self.K[1, 1]}, "
                             f"K[2,2]={self.K[2, 2]}; need fx, fy > 0 and K[2,2] = 1")
        if self.dist.shape != (5,) or not np.all(np.isfinite(self.dist)):
            raise ValueError(f"CameraModel: dist must be 5 finite coefficients, got {self.dist!r}")
        if self.size[0] <= 0 or self.size[1] <= 0:
            raise ValueError(f"CameraModel: size must be positive (w, h), got {self.size}")

    # ------------------------------------------------------------------ geometry

    @property
    def f(self) -> float:
        """Mean focal length in pixels."""
        return float((self.K[0, 0] + self.K[1, 1]) / 2)

    def project(self, P_cam: np.ndarray) -> np.ndarray:
        """Project CCS points (N, 3) with z > 0 to distorted pixel coordinates (N, 2)."""
        P = _points(P_cam, 3, "P_cam")
        if np.any(P[:, 2] <= 0):
            behind = int(np.sum(P[:, 2] <= 0))
            raise ValueError(f"P_cam: {behind} point(s) not in front of the camera (z <= 0)")
        uv, _ = cv2.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, self.dist)
        return uv.reshape(-1, 2)

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        """Map pixel coordinates (N, 2) to normalised undistorted coordinates x/z, y/z (N, 2)."""
        a = _points(uv, 2, "uv")
        xy = cv2.undistortPoints(a.reshape(-1, 1, 2), self.K, self.dist, criteria=UNDISTORT_CRITERIA)
        return xy.reshape(-1, 2)

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N, 3) in CCS through the pixel coordinates ``uv``."""
        xy = self.undistort(uv)
        d = np.column_stack([xy, np.ones(len(xy))])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    # ------------------------------------------------------------------ files

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (lists), with a schema number."""
        return {"schema": MODEL_SCHEMA, "K": self.K.tolist(), "dist": self.dist.tolist(),
                "size": list(self.size)}

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "camera model") -> "CameraModel":
        """Inverse of :meth:`to_dict`; every error is a ValueError naming ``source`` and the key."""
        if not isinstance(d, dict):
            raise ValueError(f"{source}: expected a JSON object (camera model), got {type(d).__name__}")
        schema = d.get("schema", MODEL_SCHEMA)
        if schema != MODEL_SCHEMA or isinstance(schema, bool):
            raise ValueError(f"{source}: camera model schema {schema!r} is not supported "
                             f"(expected {MODEL_SCHEMA})")
        missing = [k for k in ("K", "dist", "size") if k not in d]
        if missing:
            raise ValueError(f"{source}: missing key(s) {', '.join(map(repr, missing))}")
        arrays = {}
        for key, shape, what in (("K", (3, 3), "a 3x3 matrix"),
                                 ("dist", (5,), "5 coefficients (k1 k2 p1 p2 k3)"),
                                 ("size", (2,), "[width, height] in pixels")):
            try:
                a = np.array(d[key], dtype=float)
            except (TypeError, ValueError):
                a = None
            if a is None or a.shape != shape or not np.all(np.isfinite(a)):
                raise ValueError(f"{source}: {key} must be {what} of finite numbers, got {d[key]!r}")
            arrays[key] = a
        w, h = arrays["size"]
        if not (w.is_integer() and h.is_integer()):
            raise ValueError(f"{source}: size must be whole pixels, got {d['size']!r}")
        try:
            return cls(arrays["K"], arrays["dist"], (int(w), int(h)))
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None

