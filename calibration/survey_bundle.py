"""The plate survey's least-squares bundle: intrinsics, camera poses and nest seats together.

Unknowns: fx fy cx cy k1 k2 p1 p2 [k3] (k3 only when ``fit_k3``), (rvec, tvec) per
photograph, the three seats in PCS. Observations: patch corners (px) and the ring
centre observations (px, perspective bias removed). Each group's σ comes from its own
residuals (σ² = Σr² / redundancy), none is assumed. Jacobians: ``cv2.projectPoints`` for
poses and intrinsics, central differences for the seats.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError

ITERATIONS = 10
STEP_TOL = 1e-8  # relative parameter change that counts as converged


@dataclass
class Bundle:
    """Solution of :func:`adjust`."""

    model: CameraModel
    poses: list[np.ndarray]  # (rvec, tvec) per view
    seats: np.ndarray  # (3, 3) PCS, rows in NEST_NAMES order
    seat_cov: np.ndarray  # (3, 3, 3) covariance per seat, mm²
    sigma_corner_px: float
    sigma_ring_px: float
    corner_res: list[np.ndarray]  # per view (N, 2) px
    ring_res: list[dict[int, np.ndarray]]  # per view {nest index: (2,) px}
    intr_sigma: np.ndarray  # 1σ of the 9 intrinsics (0 for a fixed k3)


def _intr_vector(model: CameraModel) -> np.ndarray:
    K = model.K
    return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], model.dist])


def _model(v: np.ndarray, size: tuple[int, int]) -> CameraModel:
    K = np.array([[v[0], 0, v[2]], [0, v[1], v[3]], [0, 0, 1.0]])
    return CameraModel(K, v[4:9], size)


def _project(P: np.ndarray, pose: np.ndarray, intr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) and d(uv)/d(rvec, tvec, fx, fy, cx, cy, k1..k3) (2N, 15) of PCS points P."""
    K = np.array([[intr[0], 0, intr[2]], [0, intr[1], intr[3]], [0, 0, 1.0]])
    uv, jac = cv2.projectPoints(P.reshape(-1, 1, 3), pose[:3], pose[3:], K, intr[4:9])
    return uv.reshape(-1, 2), jac


def _system(intr: np.ndarray, poses: list[np.ndarray], seats: np.ndarray,
            corners: list[tuple[np.ndarray, np.ndarray]], rings: list[dict[int, np.ndarray]],
            cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals, Jacobian (over the free columns ``cols``) and a group flag (0 corner, 1 ring) per row."""
    V = len(poses)
    N_ALL = 9 + 6 * V + 9
    rows_r, rows_J, group = [], [], []
    for k, (pose, (P, uv), ring) in enumerate(zip(poses, corners, rings)):
        pv = 9 + 6 * k
        proj, jac = _project(P, pose, intr)
        J = np.zeros((2 * len(P), N_ALL))
        J[:, pv:pv + 6], J[:, 0:9] = jac[:, 0:6], jac[:, 6:15]
        rows_r.append((proj - uv).reshape(-1))
        rows_J.append(J)
        group.append(np.zeros(2 * len(P)))
        for i, obs in sorted(ring.items()):
            proj1, jac1 = _project(seats[i][None, :], pose, intr)
            J = np.zeros((2, N_ALL))
            J[:, pv:pv + 6], J[:, 0:9] = jac1[:, 0:6], jac1[:, 6:15]
            sx = 9 + 6 * V + 3 * i
            for a in range(3):  # seats: central differences (0.01 mm: linear to ~1e-9 px)
                d = np.zeros(3)
                d[a] = 1e-2
                J[:, sx + a] = (_project((seats[i] + d)[None, :], pose, intr)[0]
                                - _project((seats[i] - d)[None, :], pose, intr)[0]).reshape(-1) / 2e-2
            rows_r.append((proj1.reshape(-1) - obs))
            rows_J.append(J)
            group.append(np.ones(2))
    return np.concatenate(rows_r), np.vstack(rows_J)[:, cols], np.concatenate(group)


def _unpack(x: np.ndarray, V: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    return x[:9], [x[9 + 6 * k: 15 + 6 * k] for k in range(V)], x[9 + 6 * V:].reshape(3, 3)


def adjust(model: CameraModel, poses: list[np.ndarray], seats: np.ndarray,
           corners: list[tuple[np.ndarray, np.ndarray]], rings: list[dict[int, np.ndarray]],
           fit_k3: bool) -> Bundle:
    """Camera (intrinsics, poses) from the corners, then the seats from the rings, with their covariance.

    Two stages rather than one joint weighting: the rings carry almost no pose
    information, and a joint variance-component estimate lets the poses absorb the
    ring residuals (the rings' redundancy collapses, their σ runs to zero). The seats'
    covariance is the measurement part σ_r²(AᵀA)⁻¹ plus the camera's covariance
    propagated through the seats' dependence on it, G·Σ_cam·Gᵀ with G = (AᵀA)⁻¹AᵀB
    (A, B: ring Jacobians by seats and by camera). σ_r from the ring residuals already
    holds part of the pose error, so the sum errs on the safe side.
    """
    V = len(poses)
    x = np.concatenate([_intr_vector(model)] + [np.asarray(p, float) for p in poses] + [seats.reshape(-1)])
    if not fit_k3:
        x[8] = 0.0
    n_cam = 9 + 6 * V
    allc = np.array([j for j in range(n_cam + 9) if fit_k3 or j != 8])
    n_free_cam = len(allc) - 9
    for group, sel in ((0, slice(0, n_free_cam)), (1, slice(n_free_cam, None))):
        for _ in range(ITERATIONS):
            r, J, g = _system(*_unpack(x, V), corners, rings, allc)
            m = g == group
            dx = np.linalg.lstsq(J[m][:, sel], -r[m], rcond=None)[0]
            x[allc[sel]] += dx
            if np.max(np.abs(dx) / np.maximum(np.abs(x[allc[sel]]), 1.0)) < STEP_TOL:
                break
    r, J, g = _system(*_unpack(x, V), corners, rings, allc)
    c, k = g == 0, g == 1
    Jc = J[c][:, :n_free_cam]
    var_c = float(np.sum(r[c] ** 2)) / max(int(c.sum()) - n_free_cam, 1)
    A, B = J[k][:, n_free_cam:], J[k][:, :n_free_cam]
    var_r = float(np.sum(r[k] ** 2)) / max(int(k.sum()) - 9, 1)
    try:
        cov_cam = var_c * np.linalg.inv(Jc.T @ Jc)
        AtA_inv = np.linalg.inv(A.T @ A)
    except np.linalg.LinAlgError:
        raise CalibrationError("the survey bundle is singular: too few or too similar photographs") from None
    G = AtA_inv @ A.T @ B
    cov = np.zeros((len(allc), len(allc)))
    cov[:n_free_cam, :n_free_cam] = cov_cam
    cov[n_free_cam:, n_free_cam:] = var_r * AtA_inv + G @ cov_cam @ G.T
    return _result(x, allc, cov, np.array([var_c, var_r]), r, g, corners, rings, model.size)


def _result(x: np.ndarray, cols: np.ndarray, cov: np.ndarray, var: np.ndarray, r: np.ndarray, g: np.ndarray,
            corners: list[tuple[np.ndarray, np.ndarray]], rings: list[dict[int, np.ndarray]],
            size: tuple[int, int]) -> Bundle:
    V = len(corners)
    intr, poses, seats = _unpack(x, V)
    full = np.zeros((len(x), len(x)))
    full[np.ix_(cols, cols)] = cov
    s0 = 9 + 6 * V
    seat_cov = np.array([full[s0 + 3 * i:s0 + 3 * i + 3, s0 + 3 * i:s0 + 3 * i + 3] for i in range(3)])
    corner_res: list[np.ndarray] = []
    ring_res: list[dict[int, np.ndarray]] = []
    at = 0
    for (P, _), ring in zip(corners, rings):
        corner_res.append(r[at:at + 2 * len(P)].reshape(-1, 2))
        at += 2 * len(P)
        ring_res.append({})
        for i in sorted(ring):
            ring_res[-1][i] = r[at:at + 2]
            at += 2
    return Bundle(_model(intr, size), [p.copy() for p in poses], seats.copy(), seat_cov,
                  float(np.sqrt(var[0])), float(np.sqrt(var[1])), corner_res, ring_res,
                  np.sqrt(np.diag(full)[:9]))
