"""Rigid transforms in SE(3), named as in the paper.

A transform ``a_H_b`` is a 4x4 homogeneous matrix mapping coordinates in frame ``b``
to frame ``a``: ``a_P = a_H_b @ b_P``.  Compose as the paper writes it:
``rob_H_cam = rob_H_scn @ scn_H_cam``.  Every rotation that enters or leaves this
module is checked to be proper (orthonormal, det = +1): a left-handed frame is a bug.
Lengths are millimetres throughout the project.
"""
from __future__ import annotations

import numpy as np
import numpy.typing as npt

#: tolerance for orthonormality / det checks on rotations assembled from data
ROT_TOL = 1e-6


def assert_rotation(R: np.ndarray, name: str = "R", tol: float = ROT_TOL) -> np.ndarray:
    """Return ``R`` if it is a proper rotation, else raise ValueError naming it."""
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3):
        raise ValueError(f"{name}: expected a 3x3 rotation, got shape {R.shape}")
    err = np.abs(R.T @ R - np.eye(3)).max()
    det = float(np.linalg.det(R))
    if err > tol or abs(det - 1.0) > tol:
        raise ValueError(f"{name}: not a right-handed rotation (|RᵀR−I|={err:.2e}, det={det:+.6f})")
    return R


def assert_rotations(R: np.ndarray, name: str = "R", tol: float = ROT_TOL) -> np.ndarray:
    """:func:`assert_rotation` for a stack of rotations (n, 3, 3); the error names the first bad one."""
    R = np.asarray(R, dtype=float)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise ValueError(f"{name}: expected (n, 3, 3) rotations, got shape {R.shape}")
    err = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((err > tol) | (np.abs(det - 1.0) > tol))
    if bad.size:
        assert_rotation(R[bad[0]], f"{name} [{bad[0]}]", tol)
    return R


def make_H(R: np.ndarray, t: np.ndarray, name: str = "H") -> np.ndarray:
    """Assemble a 4x4 transform from a rotation and a translation."""
    H = np.eye(4)
    H[:3, :3] = assert_rotation(R, name)
    H[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return H


def check_H(H: np.ndarray, name: str = "H") -> np.ndarray:
    """Validate a 4x4 rigid transform (proper rotation, last row 0 0 0 1)."""
    H = np.asarray(H, dtype=float)
    if H.shape != (4, 4):
        raise ValueError(f"{name}: expected 4x4, got {H.shape}")
    if np.abs(H[3] - [0, 0, 0, 1]).max() > 1e-12:
        raise ValueError(f"{name}: last row must be [0 0 0 1], got {H[3]}")
    assert_rotation(H[:3, :3], name)
    return H


def inv_H(H: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (exact: Rᵀ, −Rᵀt)."""
    R, t = H[:3, :3], H[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def apply_H(H: np.ndarray, P: npt.ArrayLike) -> np.ndarray:
    """Transform points ``P`` (shape (3,) or (N, 3)) by ``H``."""
    P = np.asarray(P, dtype=float)
    return P @ H[:3, :3].T + H[:3, 3]


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rotation_angle(R: np.ndarray) -> float:
    """Rotation angle of ``R`` in radians (robust near 0 and π)."""
    c = (np.trace(R) - 1.0) / 2.0
    s = np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    return float(np.arctan2(s, np.clip(c, -1.0, 1.0)))
