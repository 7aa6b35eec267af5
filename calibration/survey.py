"""Rays' least-squares intersection: the plate survey's first estimate of a nest seat in PCS
(calibration/plate_survey.py, before its bundle).

A ray in PCS starts at a camera centre ``C_k`` with direction ``d_k``; the point closest to all rays
in the least-squares sense solves ``Σ (I − d_k d_kᵀ)·X = Σ (I − d_k d_kᵀ)·C_k``.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from calibration.errors import CalibrationError

#: rays closer to parallel than this cannot locate a point along them
MIN_RAY_ANGLE_DEG = 2.0


def intersect_rays(C: Any, d: Any) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares point of rays (centres C (K, 3), directions d (K, 3)): (X, distances, max angle deg)."""
    C = np.asarray(C, dtype=float).reshape(-1, 3)
    d = np.asarray(d, dtype=float).reshape(-1, 3)
    if len(C) < 2 or len(C) != len(d):
        raise ValueError(f"intersect_rays: need >= 2 rays with matching centres, got {len(C)} and {len(d)}")
    if not (np.all(np.isfinite(C)) and np.all(np.isfinite(d))):
        raise ValueError("intersect_rays: non-finite ray centre or direction")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    cosines = np.clip(np.abs(d @ d.T), 0.0, 1.0)
    max_angle = float(np.degrees(np.arccos(cosines.min())))
    if max_angle < MIN_RAY_ANGLE_DEG:
        raise CalibrationError(f"views are too close to parallel to triangulate: widest angle between rays "
                               f"{max_angle:.2f}° < {MIN_RAY_ANGLE_DEG}°")
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # projectors onto each ray's normal plane
    A = P.sum(axis=0)
    b = np.einsum("kij,kj->i", P, C)
    X = np.linalg.solve(A, b)
    dist = np.linalg.norm(np.einsum("kij,kj->ki", P, X - C), axis=1)
    return X, dist, max_angle
