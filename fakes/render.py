"""Synthetic images of what Rita's nadir camera sees in the simulated world.

Per-pixel ray casting (calibration.md §3): every pixel is sampled SS×SS times; each
sub-sample's viewing ray comes from the exact inverse of the distortion model
(``cv2.undistortPoints`` with tight criteria), is intersected with the plate's top
face (ACS z = plate thickness, inside the plate square) or else with the floor
(z = 0), and the albedo there is looked up: the ChArUco target and three nest rings
on the plate, a smooth seeded texture plus the floor marks on the floor. The
sub-samples are box-averaged (100 % fill factor), blurred by a Gaussian PSF, shaded
by vignetting between black and white levels and given shot + read noise.

How it differs from the real camera: a perfect pinhole + Brown lens with no
chromatic or depth-of-field effects, a planar world (the plate's side faces, the
robot's wheels and shadows are not drawn, so rays that would hit a plate edge see
the floor), a uniform light source, Gaussian noise instead of Poisson, and no
rolling shutter, hot pixels or compression.

The undistorted rays are cached per (size, SS) as float32 *residuals* from the
pinhole mapping (small numbers, so float32 keeps ~1e-8 relative precision). Above
16 M sub-samples the residual is computed at pixel centres only and interpolated
bilinearly for the sub-samples (error ~5e-5 px at 4024×3036, far below what any
detector resolves), which keeps the full sensor within ~1 GB.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from calibration.camera_model import UNDISTORT_CRITERIA, CameraModel
from calibration.frames import apply_H, check_H, inv_H
from calibration.target import make_board
from fakes.world import World

#: albedo of the dark and white parts of printed targets and marks
DARK, WHITE = 0.05, 0.92
#: floor mean albedo and the peak amplitude of its smooth texture
FLOOR_MEAN, FLOOR_AMPL = 0.45, 0.06
#: nest rings: (inner radius, outer radius) of the ring and its grey level per nest
NEST_RING_MM = (9.0, 14.0)
NEST_GREY = {"red": 0.35, "green": 0.55, "blue": 0.25}
NEST_HOLE_GREY = 0.12
#: board texture resolution (texels per mm); squares must span a whole number of texels
TEXTURE_PPMM = 100.0
#: sub-samples processed per chunk (bounds the working memory)
CHUNK_SAMPLES = 1_500_000
#: above this many sub-samples the ray residual is cached at pixel centres only
EXACT_CACHE_LIMIT = 16_000_000


def world_camera_model(world: World, size: tuple[int, int]) -> CameraModel:
    """The true camera model of ``world`` for an image of ``size`` (w, h)."""
    return CameraModel(world.camera_matrix(size), world.dist_coeffs(), size)


def true_corner_projections(world: World, size: tuple[int, int],
                            abs_H_cam: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth pixel positions of the ChArUco inner corners inside the image.

    Returns ``(ids, uv)``: corner ids (N,) and their exact distorted projections (N, 2),
    for corners in front of the camera and within the pixel-centre extent of the image.
    """
    if abs_H_cam is None:
        abs_H_cam = world.abs_H_cam()
    model = world_camera_model(world, size)
    board = make_board(world.plate())
    ref_P = np.asarray(board.getChessboardCorners(), dtype=float)
    cam_P = apply_H(inv_H(check_H(abs_H_cam, "abs_H_cam")) @ world.abs_H_ref, ref_P)
    front = cam_P[:, 2] > 1e-6
    ids = np.flatnonzero(front)
    uv = model.project(cam_P[front])
    w, h = size
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    return ids[inside], uv[inside]


def _coverage(t: np.ndarray, width: np.ndarray | float) -> np.ndarray:
    """Fraction of a sub-sample of ``width`` inside a shape, given signed distance ``t`` (outside > 0)."""
    return np.clip(0.5 - t / width, 0.0, 1.0)


class Renderer:
    """Renders uint8 images of ``world`` for one image size; rays are cached once."""

    def __init__(self, world: World, size: tuple[int, int], supersampling: int | None = None) -> None:
        w, h = int(size[0]), int(size[1])
        if w < 8 or h < 8:
            raise ValueError(f"Renderer: image size {size} is too small (need at least 8x8)")
        ss = int(supersampling if supersampling is not None else world.params.supersampling)
        if not 1 <= ss <= 8:
            raise ValueError(f"Renderer: supersampling={supersampling} must be in 1..8")
        self.world, self.size, self.ss = world, (w, h), ss
        self.model = world_camera_model(world, self.size)
        K = self.model.K
        self._fx, self._fy, self._cx, self._cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        if abs(K[0, 1]) > 0:
            raise ValueError("Renderer: skewed camera matrices are not supported")
        p = world.params
        self.psf_sigma = p.psf_sigma_px * w / p.reduced_size[0]
        self._board_texture = self._make_board_texture()
        self._floor_waves = self._make_floor_waves()
        self._cache_rays()

    # ------------------------------------------------------------------ set-up

    def _make_board_texture(self) -> np.ndarray:
        plate = self.world.plate()
        ppsq = plate.square_mm * TEXTURE_PPMM
        if abs(ppsq - round(ppsq)) > 1e-9:
            raise ValueError(f"Renderer: square_mm={plate.square_mm} is not a whole number of texels "
                             f"at {TEXTURE_PPMM} texels/mm")
        bw, bh = plate.board_size_mm()
        board = make_board(plate)
        return board.generateImage((round(bw * TEXTURE_PPMM), round(bh * TEXTURE_PPMM)),
                                   marginSize=0, borderBits=1)

    def _make_floor_waves(self) -> np.ndarray:
        """Random plane waves (kx, ky, phase, amplitude) for the smooth floor texture."""
        rng = self.world.rng("floor-texture")
        n = 8
        lam = np.exp(rng.uniform(math.log(1.5), math.log(40.0), n))  # wavelengths, mm
        ang = rng.uniform(0, 2 * math.pi, n)
        k = 2 * math.pi / lam
        amp = rng.uniform(0.5, 1.0, n)
        amp *= FLOOR_AMPL / amp.sum()
        return np.column_stack([k * np.cos(ang), k * np.sin(ang), rng.uniform(0, 2 * math.pi, n), amp])

    def _cache_rays(self) -> None:
        """Residuals of the undistorted rays from the pinhole mapping, on a node grid."""
        w, h = self.size
        m = self.ss if w * h * self.ss ** 2 <= EXACT_CACHE_LIMIT else 1
        self._m = m
        # nodes at (i + 0.5)/m − 0.5 for i = −1 .. n·m (one extra node on each side)
        un = (np.arange(-1, w * m + 1) + 0.5) / m - 0.5
        vn = (np.arange(-1, h * m + 1) + 0.5) / m - 0.5
        dx = np.empty((len(vn), len(un)), np.float32)
        dy = np.empty_like(dx)
        step = max(1, 2_000_000 // len(un))
        for r0 in range(0, len(vn), step):
            vv = vn[r0:r0 + step]
            uu, vg = np.meshgrid(un, vv)
            pts = np.column_stack([uu.ravel(), vg.ravel()]).reshape(-1, 1, 2)
            xy = cv2.undistortPoints(pts, self.model.K, self.model.dist, criteria=UNDISTORT_CRITERIA)
            xy = xy.reshape(len(vv), len(un), 2)
            dx[r0:r0 + step] = xy[..., 0] - (uu - self._cx) / self._fx
            dy[r0:r0 + step] = xy[..., 1] - (vg - self._cy) / self._fy
        self._dx, self._dy = dx, dy

    def _rays(self, j0: int, j1: int) -> tuple[np.ndarray, np.ndarray]:
        """Normalised undistorted coordinates (x, y) of sub-sample rows j0..j1 (float64)."""
        w = self.size[0]
        ss, m = self.ss, self._m
        u = (np.arange(w * ss) + 0.5) / ss - 0.5
        v = (np.arange(j0, j1) + 0.5) / ss - 0.5
        fu = (u + 0.5) * m - 0.5 + 1
        fv = (v + 0.5) * m - 0.5 + 1
        iu = np.clip(np.floor(fu).astype(int), 0, self._dx.shape[1] - 2)
        iv = np.clip(np.floor(fv).astype(int), 0, self._dx.shape[0] - 2)
        a = (fu - iu)[None, :]
        b = (fv - iv)[:, None]

        def interp(D: np.ndarray) -> np.ndarray:
            top = D[iv][:, iu] * (1 - a) + D[iv][:, iu + 1] * a
            bot = D[iv + 1][:, iu] * (1 - a) + D[iv + 1][:, iu + 1] * a
            return top * (1 - b) + bot * b

        x = (u[None, :] - self._cx) / self._fx + interp(self._dx)
        y = (v[:, None] - self._cy) / self._fy + interp(self._dy)
        return x, y

    # ------------------------------------------------------------------ render

    def render(self, abs_H_cam: np.ndarray | None = None, rng: np.random.Generator | None = None,
               noise: bool = True) -> np.ndarray:
        """Render one uint8 (h, w) image from camera pose ``abs_H_cam`` (default: the world's).

        ``rng`` drives the noise; without one a fixed generator of the world is used, so
        the result is deterministic either way.
        """
        if abs_H_cam is None:
            abs_H_cam = self.world.abs_H_cam()
        abs_H_cam = check_H(abs_H_cam, "abs_H_cam")
        albedo = self.albedo(abs_H_cam)
        p = self.world.params
        if self.psf_sigma > 0:
            albedo = cv2.GaussianBlur(albedo, (0, 0), self.psf_sigma, borderType=cv2.BORDER_REFLECT)
        w, h = self.size
        uu = (np.arange(w, dtype=np.float32) - self._cx) ** 2
        vv = (np.arange(h, dtype=np.float32) - self._cy) ** 2
        r2 = (vv[:, None] + uu[None, :]) / np.float32((w * w + h * h) / 4)
        img = p.black_dn + (p.white_dn - p.black_dn) * albedo * (1 - p.vignetting * r2)
        if noise:
            rng = rng if rng is not None else self.world.rng("render-noise")
            sigma = np.sqrt(p.read_noise_dn ** 2 + p.shot_gain * np.maximum(img, 0))
            img = img + sigma * rng.standard_normal(img.shape, dtype=np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def albedo(self, abs_H_cam: np.ndarray) -> np.ndarray:
        """Box-filtered scene albedo (h, w) float32 seen from ``abs_H_cam`` (no optics, no noise)."""
        w, h = self.size
        ss = self.ss
        out = np.empty((h, w), np.float32)
        rows = max(1, CHUNK_SAMPLES // (w * ss * ss))
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            sub = self._albedo_rows(abs_H_cam, r0 * ss, r1 * ss)
            out[r0:r1] = sub.reshape(r1 - r0, ss, w, ss).mean(axis=(1, 3))
        return out

    def _albedo_rows(self, abs_H_cam: np.ndarray, j0: int, j1: int) -> np.ndarray:
        """Albedo at the sub-samples of sub-sample rows j0..j1."""
        world, p = self.world, self.world.params
        x, y = self._rays(j0, j1)
        R, C = abs_H_cam[:3, :3], abs_H_cam[:3, 3]
        dxa = R[0, 0] * x + R[0, 1] * y + R[0, 2]
        dya = R[1, 0] * x + R[1, 1] * y + R[1, 2]
        dza = R[2, 0] * x + R[2, 1] * y + R[2, 2]
        down = dza < -1e-9
        dza = np.where(down, dza, -1.0)
        # plate top face, then into PCS (its xy is the board frame)
        s_top = (p.plate_thickness_mm - C[2]) / dza
        ref_H_abs = inv_H(world.abs_H_ref)
        Px = C[0] + s_top * dxa
        Py = C[1] + s_top * dya
        A, t = ref_H_abs[:3, :3], ref_H_abs[:3, 3] + ref_H_abs[:3, 2] * p.plate_thickness_mm
        qx = A[0, 0] * Px + A[0, 1] * Py + t[0]
        qy = A[1, 0] * Px + A[1, 1] * Py + t[1]
        c = world.board_centre_ref()
        half = p.plate_half_size_mm
        plate = down & (s_top > 0) & (np.abs(qx - c[0]) <= half) & (np.abs(qy - c[1]) <= half)
        alb = np.full(x.shape, FLOOR_MEAN, np.float32)
        if plate.any():
            alb[plate] = self._plate_albedo(qx[plate], qy[plate], s_top[plate])
        floor = down & ~plate
        if floor.any():
            s_fl = -C[2] / dza[floor]
            alb[floor] = self._floor_albedo(C[0] + s_fl * dxa[floor], C[1] + s_fl * dya[floor], s_fl)
        return alb

    def _footprint_mm(self, s: np.ndarray) -> np.ndarray:
        """Approximate width of one sub-sample on the surface, for edge anti-aliasing."""
        return np.maximum(s / (self.model.f * self.ss), 1e-6)

    def _plate_albedo(self, qx: np.ndarray, qy: np.ndarray, s: np.ndarray) -> np.ndarray:
        tex = self._board_texture
        th, tw = tex.shape
        # texel centre k sits at (k + 0.5)/ppmm, so square edges fall on texel boundaries;
        # clipping keeps far-off coordinates in remap's fixed-point range
        mx = np.clip(qx * TEXTURE_PPMM - 0.5, -4, tw + 4).astype(np.float32).reshape(1, -1)
        my = np.clip(qy * TEXTURE_PPMM - 0.5, -4, th + 4).astype(np.float32).reshape(1, -1)
        val = np.empty(mx.shape[1], np.float32)
        step = 30000  # remap maps must stay below 32767 columns
        for i in range(0, mx.shape[1], step):
            val[i:i + step] = cv2.remap(tex, mx[:, i:i + step], my[:, i:i + step], cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=255).ravel()
        alb = DARK + (WHITE - DARK) * val / 255.0
        near = None
        for name, seat in self.world.plate().nests_ref_nst.items():
            r_out = NEST_RING_MM[1] + 1.0
            if near is None:
                near = np.empty(len(qx), bool)
            np.less(np.abs(qx - seat[0]) + np.abs(qy - seat[1]), 2 * r_out, out=near)
            if not near.any():
                continue
            r = np.hypot(qx[near] - seat[0], qy[near] - seat[1])
            wd = self._footprint_mm(s[near])
            ring = _coverage(r - NEST_RING_MM[1], wd)
            hole = _coverage(r - NEST_RING_MM[0], wd)
            a = alb[near]
            a = a * (1 - ring) + NEST_GREY[name] * (ring - hole) + NEST_HOLE_GREY * hole
            alb[near] = a
        return alb

    def _floor_albedo(self, X: np.ndarray, Y: np.ndarray, s: np.ndarray) -> np.ndarray:
        alb = np.full(len(X), FLOOR_MEAN)
        for kx, ky, ph, amp in self._floor_waves:
            alb += amp * np.sin(kx * X + ky * Y + ph)
        for mark in self.world.params.marks:
            reach = mark.size_mm * 1.5 + 0.5
            dX, dY = X - mark.x_mm, Y - mark.y_mm
            near = (np.abs(dX) < reach) & (np.abs(dY) < reach)
            if not near.any():
                continue
            dx, dy, wd = dX[near], dY[near], self._footprint_mm(s[near])
            if mark.kind == "dot":
                cov = _coverage(np.hypot(dx, dy) - mark.size_mm, wd)
                inner = DARK
            elif mark.kind == "cross":
                # box-filtered signs of dx, dy; dark where dx·dy > 0
                sx, sy = np.clip(2 * dx / wd, -1, 1), np.clip(2 * dy / wd, -1, 1)
                inner = (WHITE + DARK) / 2 - (WHITE - DARK) / 2 * sx * sy
                cov = (_coverage(np.abs(dx) - mark.size_mm, wd) * _coverage(np.abs(dy) - mark.size_mm, wd))
            else:
                raise ValueError(f"mark {mark.name!r}: unknown kind {mark.kind!r} (expected 'dot' or 'cross')")
            alb[near] = alb[near] * (1 - cov) + inner * cov
        return alb.astype(np.float32)
