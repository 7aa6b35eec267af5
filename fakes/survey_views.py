"""Whole-plate colour photographs for the plate survey, taken with a separate "survey camera".

The survey camera is any photo camera the operator has (docs/operations.md, "Plate
survey"); its intrinsics live only here and are never handed to the product, which
calibrates the camera from the same photographs (the plate's ChArUco patches).

Camera (:class:`SurveyCamera`): a 24 MP APS-C DSLR with a 35 mm prime: 6000×4000 px of
3.9 µm (23.5 mm / 6000, the usual APS-C width), so f = 35 / 0.0039 ≈ 8970 px; the
principal point a few pixels off centre; a modest barrel distortion (k1 = −0.06, below
the robot lens's −0.12). Renders are made at a reduced size
(same field of view, focal length scaled), which makes every feature fewer pixels
wide than on the real sensor: the detection has it harder, not easier.

Scene: the plate top face (PCS z = 0) as a plane, ray cast per sub-sample as in
fakes/render.py: a neutral grey plate, the main target (averaged
to 4 texels/mm: its 2 mm squares are below the survey resolution), the survey
patches (exactly where the plate definition puts them: one print), and the three
nests: a coloured ring (red, green, blue; inner/outer radius 9/14 mm, the radii of
fakes/render.py) around a dark seat, centred on the *true* seats (the plate
definition's nests may be biased). Beyond the plate the floor is a flat grey.
Imaging: box filter, Gaussian PSF, vignetting, black/white levels and shot + read
noise per channel with the ranges of the robot camera's (docs/accuracy.md, "The nominal world");
no Bayer mosaic (a DSLR delivers demosaiced RGB), no chromatic aberration, depth of field or JPEG.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.camera_model import UNDISTORT_CRITERIA, CameraModel
from calibration.frames import check_H, make_H
from calibration.patches import Patch
from calibration.target import make_board
from fakes.render import NEST_RING_MM, Renderer, _coverage
from fakes.world import World

#: linear RGB reflectance of the anodised nest rings (any saturated colour works; the
#: detector thresholds relative to the measured contrast)
RING_RGB = {"red": (0.70, 0.10, 0.08), "green": (0.10, 0.55, 0.15), "blue": (0.08, 0.15, 0.65)}
SEAT_GREY, PLATE_GREY, FLOOR_GREY = 0.12, 0.50, 0.35
DARK, WHITE = 0.05, 0.92  # printed black and white, as fakes/render.py
PATCH_PPMM, MAIN_PPMM = 20.0, 4.0  # texture resolution of the patches and the (averaged) main target
FOLDER = "survey"  # under data_dir/sim/
BLOCK_SAMPLES = 2_000_000  # sub-samples per row block of a render (bounds the working memory)


@dataclass(frozen=True)
class SurveyCamera:
    """The survey camera's truth (full sensor) and the imaging constants."""

    full_size: tuple[int, int] = (6000, 4000)
    focal_px: float = 35.0 / 0.0039
    principal_offset_px: tuple[float, float] = (14.0, -9.0)
    dist: tuple[float, float, float, float, float] = (-0.06, 0.04, 1e-4, -1.5e-4, 0.0)
    psf_sigma_px: float = 0.8  # at the render size
    levels_dn: tuple[float, float] = (20.0, 225.0)  # black, white
    noise: tuple[float, float] = (2.0, 0.05)  # read noise DN, shot-noise gain (σ² = read² + gain·DN)
    vignetting: float = 0.15  # relative fall-off at the image corner

    def model(self, size: tuple[int, int]) -> CameraModel:
        s = size[0] / self.full_size[0]
        K = np.array([[self.focal_px * s, 0, (size[0] - 1) / 2 + self.principal_offset_px[0] * s],
                      [0, self.focal_px * s, (size[1] - 1) / 2 + self.principal_offset_px[1] * s], [0, 0, 1]])
        return CameraModel(K, np.array(self.dist), size)


def look_at(eye: np.ndarray, target: np.ndarray, roll_deg: float) -> np.ndarray:
    """ref_H_cam of a camera at ``eye`` (PCS) looking at ``target``, rolled about its axis."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z])
    a = math.radians(roll_deg)
    Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    return make_H(R @ Rz, eye, "ref_H_cam")


#: off-normal angle of the photographs, degrees: oblique views separate the focal length from
#: the distance (Zhang 2000: views of one plane must not be parallel). Measured (8 views,
#: seeds 2 and 5): 15–45° gave worst seat errors of 45 and 33 µm, 25–50° 20 and 33 µm; 6 views
#: at 5–35° left f uncertain by 0.2 % and a nest 90 µm uncertain
TILT_DEG = (25.0, 50.0)


def survey_poses(world: World, model: CameraModel, n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``n`` camera poses 0.9–1.4 m from the nests' centre, :data:`TILT_DEG` off the plate normal,
    every nest and patch in view (a hand-held photographer walking around the plate)."""
    nests = np.array(list(world.nests_ref_true().values()))
    centre = nests.mean(axis=0) * [1, 1, 0]
    keep = np.vstack([nests * [1, 1, 0]] + [_patch_outline(Patch(**{**q, "origin_mm": tuple(q["origin_mm"])}))
                                             for q in world.plate().patches])
    out: list[np.ndarray] = []
    for _ in range(200 * n):
        az = 2 * math.pi * (len(out) + rng.uniform(-0.3, 0.3)) / n
        tilt, dist = math.radians(rng.uniform(*TILT_DEG)), rng.uniform(900, 1400)
        # PCS z points into the plate: the camera stands at negative z
        eye = centre + dist * np.array([math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az),
                                        -math.cos(tilt)])
        H = look_at(eye, centre + [*rng.normal(0, 30, 2), 0], rng.uniform(-180, 180))
        cam_P = (keep - H[:3, 3]) @ H[:3, :3]
        uv = model.project(cam_P)
        w, h = model.size
        m = 0.03 * w  # margin
        if np.all((uv.min(axis=1) > m) & (uv[:, 0] < w - m) & (uv[:, 1] < h - m)):
            out.append(H)
            if len(out) == n:
                return out
    raise RuntimeError(f"survey_poses: could not place {n} views with the whole plate in view")


def _patch_outline(p: Patch) -> np.ndarray:
    w, h = p.cols * p.square_mm, p.rows * p.square_mm
    return np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]]) + [*p.origin_mm, 0]


class SurveyRenderer:
    """RGB uint8 images of ``world``'s plate seen by a :class:`SurveyCamera` at one render size."""

    def __init__(self, world: World, size: tuple[int, int] = (2400, 1600), camera: SurveyCamera | None = None,
                 supersampling: int = 2) -> None:
        self.world, self.cam, self.ss = world, camera or SurveyCamera(), int(supersampling)
        self.model = self.cam.model((int(size[0]), int(size[1])))
        plate = world.plate()
        self.patches = [Patch(**{**q, "origin_mm": tuple(q["origin_mm"])}) for q in plate.patches]
        self._tex = [self._texture(p.board(plate.aruco_dict), p.cols * p.square_mm, p.rows * p.square_mm,
                                   PATCH_PPMM, PATCH_PPMM) for p in self.patches]
        bw, bh = plate.board_size_mm()
        self._main = self._texture(make_board(plate), bw, bh, 100.0, MAIN_PPMM)
        self._main_mm = (bw, bh)
        self._seats = {n: P[:2] for n, P in world.nests_ref_true().items()}
        self._xy = self._rays()

    @staticmethod
    def _texture(board: cv2.aruco.CharucoBoard, w_mm: float, h_mm: float, ppmm: float, out_ppmm: float
                 ) -> np.ndarray:
        """Albedo texture at ``out_ppmm`` texels/mm, area-averaged from a ``ppmm`` print (sharp edges)."""
        img = board.generateImage((round(w_mm * ppmm), round(h_mm * ppmm)), marginSize=0, borderBits=1)
        if out_ppmm != ppmm:
            # uint8 averaging rounds to 1/255: the main target is only scenery in these views
            img = cv2.resize(img, (round(w_mm * out_ppmm), round(h_mm * out_ppmm)),
                             interpolation=cv2.INTER_AREA)
        return (DARK + (WHITE - DARK) / 255.0 * img.astype(np.float32)).astype(np.float32)

    def _rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Normalised undistorted coordinates of every sub-sample (float32, computed once, in row blocks)."""
        w, h = self.model.size
        ss = self.ss
        u = (np.arange(w * ss) + 0.5) / ss - 0.5
        v = (np.arange(h * ss) + 0.5) / ss - 0.5
        x = np.empty((len(v), len(u)), np.float32)
        y = np.empty_like(x)
        step = max(1, BLOCK_SAMPLES // len(u))
        for r0 in range(0, len(v), step):
            uu, vv = np.meshgrid(u, v[r0:r0 + step])
            pts = np.column_stack([uu.ravel(), vv.ravel()]).reshape(-1, 1, 2)
            xy = cv2.undistortPoints(pts, self.model.K, self.model.dist, criteria=UNDISTORT_CRITERIA)
            x[r0:r0 + step] = xy[:, 0, 0].reshape(uu.shape)
            y[r0:r0 + step] = xy[:, 0, 1].reshape(uu.shape)
        return x, y

    def albedo(self, ref_H_cam: np.ndarray) -> np.ndarray:
        """Box-filtered RGB albedo (h, w, 3) seen from ``ref_H_cam``, in row blocks (bounded memory)."""
        H = Renderer._plane_homography(check_H(ref_H_cam, "ref_H_cam"))
        w, h = self.model.size
        out = np.empty((h, w, 3), np.float32)
        rows = max(1, BLOCK_SAMPLES // (w * self.ss * self.ss))
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            sl = slice(r0 * self.ss, r1 * self.ss)
            out[r0:r1] = self._albedo_block(H, self._xy[0][sl], self._xy[1][sl])
        return out

    def _albedo_block(self, H: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        den = H[2, 0] * x + H[2, 1] * y + H[2, 2]
        ok = den > 1e-12
        den = np.where(ok, den, 1.0)
        qx = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / den
        qy = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / den
        # one sub-sample's width on the plate (mm), for the rings' edge coverage
        wd = float(np.median(np.hypot(np.diff(qx[::8, ::64], axis=1), np.diff(qy[::8, ::64], axis=1)))) / 64
        rgb = np.repeat(self._grey(qx, qy, ok)[..., None], 3, axis=2)
        for name, seat in self._seats.items():
            self._ring(rgb, qx, qy, seat, RING_RGB[name], max(wd, 1e-6))
        ss = self.ss
        return rgb.reshape(x.shape[0] // ss, ss, x.shape[1] // ss, ss, 3).mean(axis=(1, 3))

    def _grey(self, qx: np.ndarray, qy: np.ndarray, ok: np.ndarray) -> np.ndarray:
        c = self.world.board_centre_ref()
        half = self.world.params.plate_half_size_mm
        on = ok & (np.abs(qx - c[0]) <= half) & (np.abs(qy - c[1]) <= half)
        grey = np.where(on, np.float32(PLATE_GREY), np.float32(FLOOR_GREY)).astype(np.float32)
        for (ox, oy), tex, ppmm, (w_mm, h_mm) in [((0.0, 0.0), self._main, MAIN_PPMM, self._main_mm)] + [
                (p.origin_mm, t, PATCH_PPMM, (p.cols * p.square_mm, p.rows * p.square_mm))
                for p, t in zip(self.patches, self._tex)]:
            inside = on & (qx >= ox) & (qx < ox + w_mm) & (qy >= oy) & (qy < oy + h_mm)
            rows = np.flatnonzero(inside.any(axis=1))
            if not len(rows):
                continue
            sl = slice(rows[0], rows[-1] + 1)
            mx = ((qx[sl] - ox) * ppmm - 0.5).astype(np.float32)
            my = ((qy[sl] - oy) * ppmm - 0.5).astype(np.float32)
            val = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            grey[sl] = np.where(inside[sl], val, grey[sl])
        return grey

    @staticmethod
    def _ring(rgb: np.ndarray, qx: np.ndarray, qy: np.ndarray, seat: np.ndarray, colour: tuple[float, ...],
              wd: float) -> None:
        r_in, r_out = NEST_RING_MM
        near = (np.abs(qx - seat[0]) < r_out + 1) & (np.abs(qy - seat[1]) < r_out + 1)
        if not near.any():
            return
        r = np.hypot(qx[near] - seat[0], qy[near] - seat[1])
        ring = _coverage(r - r_out, wd)[:, None]
        hole = _coverage(r - r_in, wd)[:, None]
        rgb[near] = rgb[near] * (1 - ring) + np.asarray(colour, np.float32) * (ring - hole) + SEAT_GREY * hole

    def render(self, ref_H_cam: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One RGB uint8 (h, w, 3) photograph from ``ref_H_cam`` with noise drawn from ``rng``."""
        c = self.cam
        alb = self.albedo(ref_H_cam).astype(np.float32)
        alb = cv2.GaussianBlur(alb, (0, 0), c.psf_sigma_px, borderType=cv2.BORDER_REFLECT)
        w, h = self.model.size
        K = self.model.K
        uu = (np.arange(w, dtype=np.float32) - K[0, 2]) ** 2
        vv = (np.arange(h, dtype=np.float32) - K[1, 2]) ** 2
        r2 = ((vv[:, None] + uu[None, :]) / np.float32((w * w + h * h) / 4))[..., None]
        black, white = c.levels_dn
        img = black + (white - black) * alb * (1 - c.vignetting * r2)
        sigma = np.sqrt(c.noise[0] ** 2 + c.noise[1] * np.maximum(img, 0))
        img = img + sigma * rng.standard_normal(img.shape, dtype=np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def render_views(world: World, n: int = 8, size: tuple[int, int] = (2400, 1600),
                 seed_name: str = "survey") -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(RGB images, true ref_H_cam) of ``n`` whole-plate views; deterministic per world seed."""
    r = SurveyRenderer(world, size)
    rng = world.rng(seed_name)
    poses = survey_poses(world, r.model, n, rng)
    return [r.render(H, rng) for H in poses], poses


def install(world: World, data_dir: str | Path, n: int = 8,
            size: tuple[int, int] = (2400, 1600)) -> list[Path]:
    """Write ``n`` survey photographs as PNG into ``data_dir/sim/survey/`` (atomically); their paths."""
    from daemon.bus.storage import atomic_write_bytes

    images, _ = render_views(world, n, size)
    folder = Path(data_dir) / "sim" / FOLDER
    for old in folder.glob("survey_*.png"):  # a previous, larger set must not mix in
        old.unlink()
    out = []
    for k, img in enumerate(images):
        ok, buf = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        if not ok:
            raise RuntimeError("survey: PNG encoding failed")
        out.append(atomic_write_bytes(folder / f"survey_{k:02d}.png", buf.tobytes()))
    return out
