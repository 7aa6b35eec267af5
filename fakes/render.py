"""Synthetic images of what Rita's nadir camera sees in the simulated world.

Per-pixel ray casting (exact for any distortion model): every pixel is sampled SS×SS times; each
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

The undistorted rays are cached per (lens, size, SS), shared by renderers of
different worlds, as float32 *residuals* from the pinhole mapping (small numbers,
so float32 keeps ~1e-8 relative precision); the large grids also on disk, for the
next process with the same camera (fakes/ray_store.py). Above 16 M sub-samples the residual is
computed at pixel centres only and interpolated bilinearly for the sub-samples
(error < 1e-4 px at 4024×3036, far below what any detector resolves), which keeps
a full-sensor render under 800 MB peak.
"""
from __future__ import annotations

import inspect
import math
import threading

import cv2
import numpy as np

from calibration.camera_model import UNDISTORT_CRITERIA, CameraModel
from calibration.frames import apply_H, check_H, inv_H
from calibration.target import make_board
from fakes import ray_store
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
#: ray caches kept for reuse by later renderers with the same lens and size
RAY_CACHE_SIZE = 3
_RAY_CACHE: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
_RAY_LOCK = threading.Lock()


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
    ref_P = world.effects.board_true(np.asarray(board.getChessboardCorners(), dtype=float))  # as printed
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


def _to_floor(Hf: np.ndarray, xf: np.ndarray, yf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ray (x, y) → (valid, X, Y) on the floor in ACS, through the floor's ray→plane map ``Hf``."""
    df = _affine(Hf[2], xf, yf)
    okf = df > 1e-12
    df = np.where(okf, df, 1.0)
    X = _affine(Hf[0], xf, yf)
    X /= df
    Y = _affine(Hf[1], xf, yf)
    Y /= df
    return okf, X, Y


Box = tuple[float, float, float, float]  # (x min, x max, y min, y max) of a set of points


def _floor_box(Hf: np.ndarray, box: Box) -> Box | None:
    """(X min, X max, Y min, Y max) on the floor of every ray in ``box`` (x0, x1, y0, y1), or None.

    Where the floor is in front of all four corner rays it is in front of every ray between them (the
    denominator is affine in x, y), and the ray→plane map takes the box to the convex quadrilateral of
    the corners' images: its extent bounds every ray's. Else None (the caller takes X, Y's own)."""
    x0, x1, y0, y1 = box
    q = np.array([[x0, y0, 1.0], [x0, y1, 1.0], [x1, y0, 1.0], [x1, y1, 1.0]]) @ Hf.T
    if np.any(q[:, 2] <= 1e-12):
        return None
    X, Y = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
    return float(X.min()), float(X.max()), float(Y.min()), float(Y.max())


def _affine(row: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``row[0]·x + row[1]·y + row[2]``, the same operations in the same order, in place (fewer passes)."""
    out = np.multiply(x, row[0])
    out += np.multiply(y, row[1])
    out += row[2]
    return out


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
        # true seat centres (PCS xy) for the nest rings: the plate *definition* may be biased
        self._nest_xy = {n: P[:2].copy() for n, P in world.nests_ref_true().items()}
        self._floor_waves = self._make_floor_waves()
        self._boxes: dict[tuple[int, int, int, int], Box] = {}
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
        """Residuals of the undistorted rays from the pinhole mapping, on a node grid.

        They depend only on the lens and the size, so renderers of different worlds
        with the same camera share them (a small LRU cache; seconds saved per renderer).
        """
        w, h = self.size
        m = self.ss if w * h * self.ss ** 2 <= EXACT_CACHE_LIMIT else 1
        self._m = m
        key = (self.model.K.tobytes(), self.model.dist.tobytes(), w, h, m)
        with _RAY_LOCK:
            hit = _RAY_CACHE.pop(key, None)
            if hit is not None:
                _RAY_CACHE[key] = hit
        if hit is None:
            hit = self._stored_residuals(key, m)
            with _RAY_LOCK:
                _RAY_CACHE[key] = hit
                while len(_RAY_CACHE) > RAY_CACHE_SIZE:
                    _RAY_CACHE.pop(next(iter(_RAY_CACHE)))
        self._dx, self._dy = hit

    def _stored_residuals(self, key: tuple, m: int) -> tuple[np.ndarray, np.ndarray]:
        """The residuals from the file another process wrote (fakes/ray_store.py), else computed (and
        written, for a grid worth it)."""
        w, h = self.size
        shape = (h * m + 2, w * m + 2)
        if shape[0] * shape[1] < ray_store.MIN_NODES:
            return self._compute_residuals(m)
        try:  # the computation itself is part of the key: an edit to it never reads an older file
            source = inspect.getsource(Renderer._compute_residuals)
        except OSError:  # no source to key on (a frozen build): computed, as before
            return self._compute_residuals(m)
        name = ray_store.file_name((*key, repr(UNDISTORT_CRITERIA), source))
        hit = ray_store.load(name, shape)
        if hit is None:
            hit = self._compute_residuals(m)
            ray_store.store(name, *hit)
        return hit

    def _compute_residuals(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Undistort the node grid (spacing 1/m px) and keep x, y minus the pinhole mapping."""
        w, h = self.size
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
        dx.flags.writeable = False  # shared between renderers
        dy.flags.writeable = False
        return dx, dy

    def _rays(self, j0: int, j1: int, k0: int, k1: int) -> tuple[np.ndarray, np.ndarray]:
        """Normalised undistorted (x, y) of sub-sample rows j0..j1, columns k0..k1 (float64)."""
        ss, m = self.ss, self._m
        u = (np.arange(k0, k1) + 0.5) / ss - 0.5
        v = (np.arange(j0, j1) + 0.5) / ss - 0.5
        if m == ss:  # the cache holds every sub-sample (plus a one-node margin)
            rx = self._dx[j0 + 1:j1 + 1, k0 + 1:k1 + 1]
            ry = self._dy[j0 + 1:j1 + 1, k0 + 1:k1 + 1]
        else:
            # nodes sit at pixel centres (node i = pixel i − 1); cv2.resize with linear
            # interpolation samples a block of nodes exactly at the sub-sample offsets
            # (dst centre (i + 0.5)/ss − 0.5); the block keeps one node beyond every
            # sub-sample used, so resize's edge clamping never reaches the slice
            p0, p1 = j0 // ss, -(-j1 // ss)
            q0, q1 = k0 // ss, -(-k1 // ss)
            size = ((q1 - q0 + 2) * ss, (p1 - p0 + 2) * ss)
            rows = slice(j0 - p0 * ss + ss, j1 - p0 * ss + ss)
            cols = slice(k0 - q0 * ss + ss, k1 - q0 * ss + ss)
            rx = cv2.resize(self._dx[p0:p1 + 2, q0:q1 + 2], size, interpolation=cv2.INTER_LINEAR)[rows, cols]
            ry = cv2.resize(self._dy[p0:p1 + 2, q0:q1 + 2], size, interpolation=cv2.INTER_LINEAR)[rows, cols]
        x = (u[None, :] - self._cx) / self._fx + rx
        y = (v[:, None] - self._cy) / self._fy + ry
        return x, y

    # ------------------------------------------------------------------ render

    def _check_roi(self, roi: tuple[int, int, int, int] | None) -> tuple[int, int, int, int]:
        w, h = self.size
        if roi is None:
            return 0, 0, w, h
        x, y, rw, rh = (int(v) for v in roi)
        if rw < 1 or rh < 1 or x < 0 or y < 0 or x + rw > w or y + rh > h:
            raise ValueError(f"roi={roi} (x, y, w, h) is not inside the {w}x{h} image")
        return x, y, rw, rh

    def render(self, abs_H_cam: np.ndarray | None = None, rng: np.random.Generator | None = None,
               noise: bool = True, roi: tuple[int, int, int, int] | None = None, bits: int = 8) -> np.ndarray:
        """Render one uint8 (h, w) image from camera pose ``abs_H_cam`` (default: the world's).

        ``bits`` > 8 quantises the same signal finer (uint16, one 8-bit DN = 2^(bits−8) DN),
        as a 12-bit ADC delivers it (Mono12p, BayerRG12p); noise is unchanged in 8-bit DN.

        ``rng`` drives the noise; without one a fixed generator of the world is used, so
        the result is deterministic either way. ``roi`` = (x, y, w, h) renders only that
        window (like a sensor ROI; noise-free it equals the same window of a full render).
        """
        if abs_H_cam is None:
            abs_H_cam = self.world.abs_H_cam()
        abs_H_cam = check_H(abs_H_cam, "abs_H_cam")
        x, y, rw, rh = self._check_roi(roi)
        w, h = self.size
        # render a margin around the window so the PSF sees the same neighbourhood
        mg = int(math.ceil(4 * self.psf_sigma)) + 1
        ax, ay = max(0, x - mg), max(0, y - mg)
        bx, by = min(w, x + rw + mg), min(h, y + rh + mg)
        albedo = self.albedo(abs_H_cam, (ax, ay, bx - ax, by - ay))
        p = self.world.params
        if self.psf_sigma > 0:
            albedo = cv2.GaussianBlur(albedo, (0, 0), self.psf_sigma, borderType=cv2.BORDER_REFLECT)
        albedo = albedo[y - ay:y - ay + rh, x - ax:x - ax + rw]
        uu = (np.arange(x, x + rw, dtype=np.float32) - self._cx) ** 2
        vv = (np.arange(y, y + rh, dtype=np.float32) - self._cy) ** 2
        r2 = (vv[:, None] + uu[None, :]) / np.float32((w * w + h * h) / 4)
        img = p.black_dn + (p.white_dn - p.black_dn) * albedo * (1 - p.vignetting * r2)
        if noise:
            rng = rng if rng is not None else self.world.rng("render-noise")
            sigma = np.sqrt(p.read_noise_dn ** 2 + p.shot_gain * np.maximum(img, 0))
            img = img + sigma * rng.standard_normal(img.shape, dtype=np.float32)
        if bits != 8:
            return np.clip(np.rint(img * np.float32(2 ** (bits - 8))), 0, 2 ** bits - 1).astype(np.uint16)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def albedo(self, abs_H_cam: np.ndarray, roi: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Box-filtered scene albedo float32 seen from ``abs_H_cam`` (no optics, no noise)."""
        x, y, rw, rh = self._check_roi(roi)
        ss = self.ss
        out = np.empty((rh, rw), np.float32)
        rows = max(1, CHUNK_SAMPLES // (rw * ss * ss))
        for r0 in range(y, y + rh, rows):
            r1 = min(y + rh, r0 + rows)
            sub = self._albedo_rows(abs_H_cam, r0 * ss, r1 * ss, x * ss, (x + rw) * ss)
            out[r0 - y:r1 - y] = sub.reshape(r1 - r0, ss, rw, ss).mean(axis=(1, 3))
        return out

    @staticmethod
    def _plane_homography(plane_H_cam: np.ndarray) -> np.ndarray:
        """3x3 map from a ray (x, y, 1) in CCS to homogeneous xy on the plane z = 0 of ``plane``.

        The third row is R₂·d: the ray meets the plane in front of the camera where
        its sign is opposite to the camera's z in that frame.
        """
        R, t = plane_H_cam[:3, :3], plane_H_cam[:3, 3]
        return np.vstack([t[0] * R[2] - t[2] * R[0], t[1] * R[2] - t[2] * R[1], R[2]]) * -np.sign(t[2])

    def _albedo_rows(self, abs_H_cam: np.ndarray, j0: int, j1: int, k0: int, k1: int) -> np.ndarray:
        """Albedo at the sub-samples of sub-sample rows j0..j1 and columns k0..k1.

        Work whose result is thrown away is skipped, the rest is computed as before (the same
        elementwise operations on the same values: tests/fakes/test_render_identical.py keeps the
        former version and checks equality bit for bit): a held board hides the scene, a chunk
        without the plate needs no plate texture, one without floor no floor."""
        world = self.world
        x, y = self._rays(j0, j1, k0, k1)
        held = world.held_board  # a calibration board the operator holds under the lens (fakes/board.py)
        if held is not None:  # the board or the bench behind it: the scene is not in view
            return held.overlay(x, y, np.empty(x.shape, np.float32))
        # plate top face = PCS z = 0 (the board frame), via a ray→plane homography
        ref_H_cam = inv_H(world.abs_H_ref) @ abs_H_cam
        c = world.board_centre_ref()
        half = world.params.plate_half_size_mm
        box = self._ray_box((j0, j1, k0, k1), x, y)
        on_plate = self._plate_may_be_seen(ref_H_cam, c, half, box)
        if on_plate:
            H = self._plane_homography(ref_H_cam)
            den = H[2, 0] * x + H[2, 1] * y + H[2, 2]
            ok = den > 1e-12
            den = np.where(ok, den, 1.0)
            qx = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / den
            qy = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / den
            plate = ok & (np.abs(qx - c[0]) <= half) & (np.abs(qy - c[1]) <= half)
            on_plate = bool(plate.any())
        if on_plate:  # else every sub-sample gets the floor's albedo below
            alb = self._plate_albedo(qx, qy, ref_H_cam[2, 3])
            floor = ~plate
            if not floor.any():
                return alb
        # the floor texture is smooth (wavelengths >= 1.5 mm, many pixels): evaluate
        # it once per pixel (middle sub-sample) rather than per sub-sample
        Hf = self._plane_homography(world.effects.floor_view_H(abs_H_cam))  # floor at its local height
        ss, k = self.ss, self.ss // 2
        _, Xc, Yc = _to_floor(Hf, x[k::ss, k::ss], y[k::ss, k::ss])
        tex = np.repeat(np.repeat(self._floor_texture(Xc, Yc), ss, axis=0), ss, axis=1)
        if on_plate:
            okf, X, Y = _to_floor(Hf, x[floor], y[floor])
            marks = self._floor_marks(tex[floor], X, Y, abs_H_cam[2, 3], _floor_box(Hf, box))
            alb[floor] = np.where(okf, marks, FLOOR_MEAN)
            return alb
        # all floor: the same values in the same (C) order as the boolean selection, without copies
        okf, X, Y = _to_floor(Hf, x.ravel(), y.ravel())
        return np.where(okf, self._floor_marks(tex.ravel(), X, Y, abs_H_cam[2, 3], _floor_box(Hf, box)),
                        FLOOR_MEAN).astype(np.float32).reshape(x.shape)

    def _ray_box(self, chunk: tuple[int, int, int, int], x: np.ndarray, y: np.ndarray) -> Box:
        """(x min, x max, y min, y max) of a chunk's rays: they depend on the chunk and the lens alone, so
        each chunk's box is taken at its first render and kept."""
        box = self._boxes.get(chunk)
        if box is None:
            box = self._boxes[chunk] = (float(x.min()), float(x.max()), float(y.min()), float(y.max()))
        return box

    @staticmethod
    def _plate_may_be_seen(ref_H_cam: np.ndarray, c: np.ndarray, half: float, box: Box) -> bool:
        """False only if no ray (x, y, 1) in ``box`` (a chunk's rays' extent) can meet the plate's top face.

        With the plate, grown by 1 mm (far above any rounding), wholly in front of the camera, the rays
        that meet it fill the convex quadrilateral of its projected corners; a chunk whose rays' box
        misses that quadrilateral's box sees no plate. Else (a corner behind the camera) it may."""
        g = half + 1.0
        corners = np.array([[c[0] + sx * g, c[1] + sy * g, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
        cam = apply_H(inv_H(ref_H_cam), corners)
        if np.any(cam[:, 2] <= 1e-6):
            return True
        u, v = cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2]
        x0, x1, y0, y1 = box
        return not (x1 < u.min() or x0 > u.max() or y1 < v.min() or y0 > v.max())

    def _width_mm(self, height_mm: float) -> float:
        """Approximate width of one sub-sample on a surface ``height_mm`` below the camera."""
        return max(abs(height_mm) / (self.model.f * self.ss), 1e-6)

    def _plate_albedo(self, qx: np.ndarray, qy: np.ndarray, height_mm: float) -> np.ndarray:
        """Board texture, white plate and nest rings at PCS xy (2-D arrays of one chunk)."""
        tex = self._board_texture
        th, tw = tex.shape
        bx, by = self.world.effects.board_nominal(qx, qy)  # the print's own scale and shear
        # texel centre k sits at (k + 0.5)/ppmm, so square edges fall on texel boundaries;
        # clipping keeps far-off coordinates in remap's fixed-point range
        mx = np.clip(bx * TEXTURE_PPMM - 0.5, -4, tw + 4).astype(np.float32)
        my = np.clip(by * TEXTURE_PPMM - 0.5, -4, th + 4).astype(np.float32)
        val = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=255)
        alb = np.float32(DARK) + np.float32((WHITE - DARK) / 255.0) * val.astype(np.float32)
        lo_x, hi_x, lo_y, hi_y = qx.min(), qx.max(), qy.min(), qy.max()
        wd = self._width_mm(height_mm)
        r_out = NEST_RING_MM[1] + 1.0
        for name, seat in self._nest_xy.items():
            if not (lo_x - r_out < seat[0] < hi_x + r_out and lo_y - r_out < seat[1] < hi_y + r_out):
                continue
            near = (np.abs(qx - seat[0]) < r_out) & (np.abs(qy - seat[1]) < r_out)
            if not near.any():
                continue
            r = np.hypot(qx[near] - seat[0], qy[near] - seat[1])
            ring = _coverage(r - NEST_RING_MM[1], wd)
            hole = _coverage(r - NEST_RING_MM[0], wd)
            alb[near] = (alb[near] * (1 - ring) + self._ring_albedo(name) * (ring - hole)
                         + NEST_HOLE_GREY * hole)
        return alb

    def _ring_albedo(self, name: str) -> float:
        """Albedo of nest ``name``'s ring (a colour renderer returns one channel's)."""
        return NEST_GREY[name]

    def _floor_texture(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Smooth seeded floor albedo at ACS xy."""
        alb = np.full(X.shape, FLOOR_MEAN)
        for kx, ky, ph, amp in self._floor_waves:
            alb += amp * np.sin(kx * X + ky * Y + ph)
        return alb

    def _floor_marks(self, alb: np.ndarray, X: np.ndarray, Y: np.ndarray, height_mm: float,
                     extent: Box | None = None) -> np.ndarray:
        """Draw the floor marks over the floor albedo ``alb`` at ACS xy (1-D arrays) inside ``extent``
        (X min, X max, Y min, Y max; None: taken from X and Y)."""
        wd = self._width_mm(height_mm)
        alb = alb.astype(np.float64)
        # the chunk's extent on the floor, to pass over marks out of it without a full pass each;
        # the 1 mm margin dwarfs any rounding of X − x_mm, and a NaN bound skips nothing
        lo_x, hi_x, lo_y, hi_y = extent if extent is not None else (X.min(), X.max(), Y.min(), Y.max())
        for mark in self.world.params.marks:
            reach = mark.size_mm * 1.5 + 0.5
            if (hi_x < mark.x_mm - reach - 1.0 or lo_x > mark.x_mm + reach + 1.0
                    or hi_y < mark.y_mm - reach - 1.0 or lo_y > mark.y_mm + reach + 1.0):
                continue  # as `near` would be all False below
            dX, dY = X - mark.x_mm, Y - mark.y_mm
            near = (np.abs(dX) < reach) & (np.abs(dY) < reach)
            if not near.any():
                continue
            dx, dy = dX[near], dY[near]
            if mark.kind == "dot":
                cov = _coverage(np.hypot(dx, dy) - mark.size_mm, wd)
                inner = DARK
            elif mark.kind == "cross":
                # box-filtered signs of dx, dy; dark where dx·dy > 0
                sx, sy = np.clip(2 * dx / wd, -1, 1), np.clip(2 * dy / wd, -1, 1)
                inner = (WHITE + DARK) / 2 - (WHITE - DARK) / 2 * sx * sy
                cov = (_coverage(np.abs(dx) - mark.size_mm, wd) * _coverage(np.abs(dy) - mark.size_mm, wd))
            else:
                raise ValueError(f"mark {mark.name!r}: unknown kind {mark.kind!r} "
                                 f"(expected 'dot' or 'cross')")
            alb[near] = alb[near] * (1 - cov) + inner * cov
        return alb.astype(np.float32)
