"""Covariance of a referencing result by seeded Monte Carlo.

The referencing chain is run again on perturbed inputs: every tracker point (three
nests, P0, P1) gets N(0, σ_t²) per coordinate, and the image-derived ``cam_H_ref``
gets a draw from its PnP covariance. Poses are summarised as 6-vectors
(translation mm, rotation vector rad) of the perturbation ``H = [exp(δr)·R̂ | t̂ + δt]``.
The chain itself is passed in as a function, so this module knows no frames beyond
the pose parameterisation; :mod:`calibration.referencing` supplies it. The chain takes
every sample at once (a leading batch axis): a Python loop over 200 samples cost more
than the rest of the referencing arithmetic together.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import cv2
import numpy as np

#: chain(abs_P_nests (n,3,3), P0 (n,3), P1 (n,3), cam_H_ref (n,4,4)) -> (rob_H_cam, rob_H_scn), each (n,4,4);
#: without the leading axis n it takes and returns one sample
Chain = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis·angle, rad) of a rotation matrix.

    Written out rather than ``cv2.Rodrigues``, which returns zero for angles below
    about 1e-5 rad, the very size of the errors this module measures.
    """
    R = np.asarray(R, dtype=float)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = np.linalg.norm(w) / 2
    c = (np.trace(R) - 1) / 2
    theta = float(np.arctan2(s, np.clip(c, -1.0, 1.0)))
    if theta < 1e-8:
        return w / 2
    if np.pi - theta > 1e-6:
        return w * (theta / (2 * s))
    # near π the antisymmetric part vanishes; the axis is the dominant column of R + I
    B = (R + np.eye(3)) / 2
    k = int(np.argmax(np.diag(B)))
    axis = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
    return axis * theta


def rotmat(r: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (rad), Rodrigues' formula."""
    r = np.asarray(r, dtype=float).reshape(3)
    theta = float(np.linalg.norm(r))
    Kx = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    if theta < 1e-8:
        return np.eye(3) + Kx + Kx @ Kx / 2
    return np.eye(3) + np.sin(theta) / theta * Kx + (1 - np.cos(theta)) / theta ** 2 * Kx @ Kx


def rotvecs(R: np.ndarray) -> np.ndarray:
    """:func:`rotvec` of a stack of rotations (n, 3, 3) -> (n, 3), the same three cases elementwise."""
    R = np.asarray(R, dtype=float)
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = np.linalg.norm(w, axis=1) / 2
    c = (np.trace(R, axis1=1, axis2=2) - 1) / 2
    theta = np.arctan2(s, np.clip(c, -1.0, 1.0))
    out = w / 2
    mid = (theta >= 1e-8) & (np.pi - theta > 1e-6)
    out[mid] = w[mid] * (theta[mid] / (2 * s[mid]))[:, None]
    for i in np.flatnonzero((theta >= 1e-8) & ~mid):  # near π: rare, as in rotvec
        out[i] = rotvec(R[i])
    return out


def rotmats(r: np.ndarray) -> np.ndarray:
    """:func:`rotmat` of a stack of rotation vectors (n, 3) -> (n, 3, 3)."""
    r = np.asarray(r, dtype=float).reshape(-1, 3)
    theta = np.linalg.norm(r, axis=1)
    Kx = np.zeros((len(r), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
    K2 = Kx @ Kx
    small = theta < 1e-8
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(t) / t)
    b = np.where(small, 0.5, (1 - np.cos(t)) / t ** 2)
    return np.eye(3) + a[:, None, None] * Kx + b[:, None, None] * K2


def pose_deltas(H: np.ndarray, H_ref: np.ndarray) -> np.ndarray:
    """:func:`pose_delta` of a stack of poses (n, 4, 4) against one ``H_ref`` -> (n, 6)."""
    H = np.asarray(H, dtype=float)
    dr = rotvecs(H[:, :3, :3] @ H_ref[:3, :3].T)
    return np.concatenate([H[:, :3, 3] - H_ref[:3, 3], dr], axis=1)


def perturb_poses(H_ref: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """:func:`perturb_pose` for a stack of 6-vectors (n, 6) -> (n, 4, 4)."""
    H = np.broadcast_to(np.eye(4), (len(delta), 4, 4)).copy()
    H[:, :3, :3] = rotmats(delta[:, 3:]) @ H_ref[:3, :3]
    H[:, :3, 3] = H_ref[:3, 3] + delta[:, :3]
    return H


def pose_delta(H: np.ndarray, H_ref: np.ndarray) -> np.ndarray:
    """6-vector (δt mm, δr rad) with ``H = [exp(δr)·R_ref | t_ref + δt]``."""
    return np.concatenate([H[:3, 3] - H_ref[:3, 3], rotvec(H[:3, :3] @ H_ref[:3, :3].T)])


def perturb_pose(H_ref: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pose_delta`: apply a 6-vector perturbation to ``H_ref``."""
    H = np.eye(4)
    H[:3, :3] = rotmat(delta[3:]) @ H_ref[:3, :3]
    H[:3, 3] = H_ref[:3, 3] + delta[:3]
    return H


def footprint(rob_H_cam: np.ndarray, rob_H_plane: np.ndarray) -> np.ndarray:
    """Where the optical axis meets the plane z = 0 of ``rob_H_plane``, in RCS (3,)."""
    C, a = rob_H_cam[:3, 3], rob_H_cam[:3, 2]
    o, m = rob_H_plane[:3, 3], rob_H_plane[:3, 2]
    denom = float(a @ m)
    if abs(denom) < 1e-9:
        raise ValueError("footprint: optical axis is parallel to the plane")
    return C + a * float((o - C) @ m) / denom


def footprints(rob_H_cam: np.ndarray, rob_H_plane: np.ndarray) -> np.ndarray:
    """:func:`footprint` of stacks of poses (n, 4, 4) -> (n, 3)."""
    C, a = rob_H_cam[:, :3, 3], rob_H_cam[:, :3, 2]
    o, m = rob_H_plane[:, :3, 3], rob_H_plane[:, :3, 2]
    denom = np.sum(a * m, axis=1)
    if np.any(np.abs(denom) < 1e-9):
        raise ValueError("footprint: optical axis is parallel to the plane")
    return C + a * (np.sum((o - C) * m, axis=1) / denom)[:, None]


def pnp_covariance(K: np.ndarray, dist: np.ndarray, cam_H_ref: np.ndarray, ref_P: np.ndarray,
                   sigma_px: float) -> np.ndarray:
    """First-order covariance of ``cam_H_ref`` as (δt, δr) from its corner correspondences.

    Gauss-Newton: Σ = σ²(JᵀJ)⁻¹ with J the Jacobian of the projection of the board
    points with respect to the pose; OpenCV's ``projectPoints`` returns it for
    (rvec, tvec), which is converted to this module's (δt, δr) perturbation.
    """
    ref_P = np.asarray(ref_P, dtype=float).reshape(-1, 3)
    if len(ref_P) < 4:
        raise ValueError(f"pnp_covariance: need at least 4 corners, got {len(ref_P)}")
    if not np.isfinite(sigma_px) or sigma_px <= 0:
        raise ValueError(f"pnp_covariance: sigma_px must be > 0, got {sigma_px}")
    rvec = rotvec(cam_H_ref[:3, :3])
    tvec = cam_H_ref[:3, 3]
    _, J = cv2.projectPoints(ref_P.reshape(-1, 1, 3), rvec, tvec, K, dist)
    Jp = J[:, :6]  # columns: rvec (3), tvec (3)
    cov_rt = sigma_px ** 2 * np.linalg.inv(Jp.T @ Jp)
    # numerically map a small rvec step to the (δt, δr) parameterisation
    eps = 1e-7
    A = np.zeros((6, 6))
    base = cam_H_ref
    for k in range(6):
        rv, tv = rvec.copy(), tvec.copy()
        (rv if k < 3 else tv)[k % 3] += eps
        H = np.eye(4)
        H[:3, :3], H[:3, 3] = rotmat(rv), tv
        A[:, k] = pose_delta(H, base) / eps
    return A @ cov_rt @ A.T


@dataclass
class PoseUncertainty:
    """Spread of ``rob_H_cam`` (and ``rob_H_scn``) from a Monte Carlo run."""

    cov_rob_H_cam: np.ndarray  # 6x6, (δt mm, δr rad)
    cov_rob_H_scn: np.ndarray  # 6x6, same parameterisation
    std_footprint_mm: np.ndarray  # (2,) RCS x, y of the camera footprint
    n_samples: int
    method: str

    @property
    def std_t_mm(self) -> np.ndarray:
        """Std of the rob_H_cam translation (x, y, z), mm."""
        return np.sqrt(np.diag(self.cov_rob_H_cam)[:3])

    @property
    def std_rot_deg(self) -> np.ndarray:
        """Std of the rob_H_cam rotation-vector components, degrees."""
        return np.degrees(np.sqrt(np.diag(self.cov_rob_H_cam)[3:]))

    @property
    def footprint_std_mm(self) -> float:
        """Radial std of the footprint, sqrt(σx² + σy²)."""
        return float(np.hypot(*self.std_footprint_mm))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"std_t_mm": self.std_t_mm.tolist(), "std_rot_deg": self.std_rot_deg.tolist(),
                "std_footprint_mm": self.std_footprint_mm.tolist(),
                "footprint_std_mm": self.footprint_std_mm,
                "cov_rob_H_cam": self.cov_rob_H_cam.tolist(), "cov_rob_H_scn": self.cov_rob_H_scn.tolist(),
                "n_samples": self.n_samples, "method": self.method}


def monte_carlo(chain: Chain, abs_P_nests: np.ndarray, abs_P_rob0: np.ndarray, abs_P_rob1: np.ndarray,
                cam_H_ref: np.ndarray, sigma_t_mm: float, cov_cam_H_ref: np.ndarray | None = None,
                n_samples: int = 200, seed: int = 0) -> PoseUncertainty:
    """Covariance of the chain's ``rob_H_cam`` and ``rob_H_scn`` under input noise."""
    if n_samples < 10:
        raise ValueError(f"monte_carlo: n_samples must be >= 10, got {n_samples}")
    if not np.isfinite(sigma_t_mm) or sigma_t_mm < 0:
        raise ValueError(f"monte_carlo: sigma_t_mm must be >= 0, got {sigma_t_mm}")
    rng = np.random.default_rng(seed)
    rob_H_cam0, rob_H_scn0 = chain(abs_P_nests, abs_P_rob0, abs_P_rob1, cam_H_ref)
    L = None
    if cov_cam_H_ref is not None:
        cov = np.asarray(cov_cam_H_ref, dtype=float)
        if cov.shape != (6, 6):
            raise ValueError(f"monte_carlo: cov_cam_H_ref must be 6x6, got {cov.shape}")
        w, V = np.linalg.eigh((cov + cov.T) / 2)
        L = V * np.sqrt(np.clip(w, 0, None))
    # one draw per sample in the order a per-sample loop would take them: 15 tracker
    # coordinates, then 6 for cam_H_ref (normal(0, σ) is σ times the same standard draw)
    z = rng.standard_normal((n_samples, 15 if L is None else 21))
    noise = (sigma_t_mm * z[:, :15]).reshape(n_samples, 5, 3)
    H_ref = (np.broadcast_to(cam_H_ref, (n_samples, 4, 4)) if L is None
             else perturb_poses(cam_H_ref, z[:, 15:] @ L.T))
    rc, rs = chain(abs_P_nests + noise[:, :3], abs_P_rob0 + noise[:, 3], abs_P_rob1 + noise[:, 4], H_ref)
    d_cam = pose_deltas(rc, rob_H_cam0)
    d_scn = pose_deltas(rs, rob_H_scn0)
    foot = (footprints(rc, rs) - footprint(rob_H_cam0, rob_H_scn0))[:, :2]
    method = f"monte carlo, {n_samples} samples, σ_t = {sigma_t_mm * 1000:.1f} µm" + (
        ", PnP covariance" if L is not None else ", cam_H_ref fixed")
    return PoseUncertainty(np.cov(d_cam.T), np.cov(d_scn.T), foot.std(axis=0, ddof=1), n_samples, method)
