"""An independent dataset writer: a referencing dataset made only from docs/datasets.md and the schemas.

Nothing of the project's calibration or simulator is imported (no ``calibration``,
no ``fakes``): the scene, the frames, the pinhole projection and the ChArUco rendering
(``CharucoBoard.generateImage`` + ``cv2.warpPerspective``) are this file's own, so a
test that recomputes its folder checks the documented contract, not shared code.

Conventions used, each as docs/datasets.md states them:
* PCS: OpenCV board frame, origin at the board's outer corner, x columns, y rows, z into the plate;
* SMR centre = nest seat − smr_offset_mm along PCS z;
* camera frame: OpenCV (x right, y down, z forward), integer pixel coordinates = pixel centres;
* robot frame: origin at the reflector at P0, x along P0→P1 projected onto the nest plane,
  z the nest-triangle normal turned toward the reflector.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

BOARD = {"cols": 40, "rows": 30, "square": 2.0, "marker": 1.5, "dict": "DICT_5X5_1000"}
SIZE = (1280, 960)
K = np.array([[600.0, 0.0, 639.5], [0.0, 600.0, 479.5], [0.0, 0.0, 1.0]])
SEATS = {"red": [-20.0, -20.0, 0.0], "green": [110.0, -20.0, 0.0], "blue": [-20.0, 85.0, 0.0]}
DELTA = 19.05


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _H(R: np.ndarray, t: Any) -> np.ndarray:
    H = np.eye(4)
    H[:3, :3], H[:3, 3] = R, t
    return H


def _apply(H: np.ndarray, p: Any) -> np.ndarray:
    return H[:3, :3] @ np.asarray(p, float) + H[:3, 3]


def render(cam_H_ref: np.ndarray, ppmm: float = 40.0, supersample: int = 4, psf_px: float = 1.0,
           b: dict[str, Any] = BOARD) -> np.ndarray:
    """8-bit image of the board ``b`` seen by the pinhole camera K (no distortion), lens blur ``psf_px``
    (σ)."""
    board = cv2.aruco.CharucoBoard((b["cols"], b["rows"]), b["square"], b["marker"],
                                   cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, b["dict"])))
    w_px, h_px = round(b["cols"] * b["square"] * ppmm), round(b["rows"] * b["square"] * ppmm)
    flat = board.generateImage((w_px, h_px), marginSize=0, borderBits=1)
    # board pixel (centre convention) -> board mm on z = 0 -> camera pixel -> supersampled pixel
    S = np.array([[1 / ppmm, 0, 0.5 / ppmm], [0, 1 / ppmm, 0.5 / ppmm], [0, 0, 1]])
    P = K @ np.column_stack([cam_H_ref[:3, 0], cam_H_ref[:3, 1], cam_H_ref[:3, 3]])
    s = supersample
    A = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1]])
    big = cv2.warpPerspective(flat, A @ P @ S, (SIZE[0] * s, SIZE[1] * s), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=255)
    img = cv2.resize(big, SIZE, interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(img, (0, 0), psf_px) if psf_px > 0 else img


def scene(move_mm: float = 200.0) -> dict[str, Any]:
    """Poses and points of one referencing visit, every one in ACS (z up), mm."""
    abs_H_ref = _H(_rot("z", 25.0) @ _rot("x", 0.4) @ np.diag([1.0, -1.0, -1.0]), [1200.0, -300.0, 15.0])
    ref_H_cam = _H(_rot("x", 1.2) @ _rot("y", -0.8) @ _rot("z", 3.0), [40.0, 30.0, -30.0])
    abs_H_cam = abs_H_ref @ ref_H_cam
    smr = {n: _apply(abs_H_ref, np.array(p) - [0, 0, DELTA]) for n, p in SEATS.items()}
    P0 = _apply(abs_H_ref, [-60.0, 30.0, -300.0])
    drive = _apply(abs_H_ref, [math.cos(0.3), math.sin(0.3), 0.0]) - abs_H_ref[:3, 3]
    P1 = P0 + move_mm * drive
    # the robot frame as documented
    n = np.cross(smr["blue"] - smr["red"], smr["green"] - smr["red"])
    n /= np.linalg.norm(n)
    if n @ (P0 - np.mean(list(smr.values()), axis=0)) < 0:
        n = -n
    v = P1 - P0
    x = v - (v @ n) * n
    x /= np.linalg.norm(x)
    abs_H_rob = _H(np.column_stack([x, np.cross(n, x), n]), P0)
    return {"cam_H_ref": np.linalg.inv(ref_H_cam), "smr": smr, "P0": P0, "P1": P1,
            "rob_H_cam": np.linalg.inv(abs_H_rob) @ abs_H_cam}


ABS_H_TRK = _H(_rot("z", -40.0), [-2500.0, 800.0, 1200.0])


def point(abs_xyz: np.ndarray) -> dict[str, Any]:
    """A tracker point with both frames and the tracker pose, as the docs describe."""
    x, y, z = np.linalg.inv(ABS_H_TRK)[:3] @ [*abs_xyz, 1.0]
    return {"x": float(x), "y": float(y), "z": float(z), "abs_xyz": [float(v) for v in abs_xyz],
            "abs_H_trk": ABS_H_TRK.tolist(), "std": [0.005, 0.005, 0.005]}


#: a warm light on the neutral board, so colour images are not trivially grey (R, G, B gains)
LIGHT_RGB = (1.0, 0.9, 0.75)
#: (row, column) of each colour in the 2x2 cell of a BayerRG mosaic (row 0 = R G, row 1 = G B)
BAYER_RG = {"R": ((0, 0),), "G": ((0, 1), (1, 0)), "B": ((1, 1),)}


def as_camera_image(grey: np.ndarray, pixel_format: str) -> np.ndarray:
    """The rendered board as a camera of ``pixel_format`` gives it, stored as docs/datasets.md says.

    Colour images are R, G, B in the returned array (and in the PNG file).
    """
    rgb = np.dstack([grey.astype(float) * g for g in LIGHT_RGB])
    if pixel_format == "RGB8":
        return np.round(rgb).astype(np.uint8)
    mosaic = np.empty(grey.shape)
    for c, cells in BAYER_RG.items():
        for dy, dx in cells:
            mosaic[dy::2, dx::2] = rgb[dy::2, dx::2, "RGB".index(c)]
    if pixel_format == "BayerRG8":
        return np.round(mosaic).astype(np.uint8)
    if pixel_format == "BayerRG12p":  # 12-bit values, stored in a 16-bit PNG
        return np.round(mosaic * 4095 / 255).astype(np.uint16)
    raise ValueError(f"writer: no pixel format {pixel_format!r}")


def write_referencing(root: Path, *, move_mm: float = 200.0, bits: int = 8,
                      pixel_format: str | None = None) -> np.ndarray:
    """Write a referencing dataset folder; return the true rob_H_cam.

    ``pixel_format`` None writes no pixel format (an old dataset: 8- or 16-bit grey by ``bits``).
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    sc = scene(move_mm)
    img = render(sc["cam_H_ref"])
    if bits == 16:
        img = img.astype(np.uint16) * 257
    if pixel_format is not None:
        img = as_camera_image(img, pixel_format)
    cv2.imwrite(str(root / "run0.png"), img[:, :, ::-1] if img.ndim == 3 else img)  # OpenCV writes BGR
    plate = {"schema": 1, "plate_id": "WRITER-1", "board_cols": BOARD["cols"], "board_rows": BOARD["rows"],
             "square_mm": BOARD["square"], "marker_mm": BOARD["marker"], "aruco_dict": BOARD["dict"],
             "nests_ref_nst": SEATS, "smr_offset_mm": DELTA}
    header = {"shape": list(img.shape), "dtype": "|u1" if img.dtype == np.uint8 else "<u2"}
    if pixel_format is not None:
        header["pixel_format"] = pixel_format
    state = {"schema": 1, "procedure": "referencing",
             "obs": {"plate": plate, "camera_model": {"K": K.tolist(), "dist": [0.0] * 5, "size": list(SIZE)},
                     "sigma_t_mm": 0.010, "nests": {n: point(p) for n, p in sc["smr"].items()},
                     "runs": [{"tag": "run0", "image": "run0.png", "header": header,
                               "P0": point(sc["P0"]), "P1": point(sc["P1"])}]}}
    (root / "state.json").write_text(json.dumps(state, indent=1))
    # the manifest lists each image with its header sidecar, as the worker writes them
    (root / "run0.json").write_text(json.dumps({"camera": header, "image_file": "run0.png"}))
    (root / "dataset.json").write_text(json.dumps({"schema": 1, "kind": "procedure:referencing", "meta": {},
                                                   "entries": [{"name": "run0", "json": "run0.json",
                                                                "image": "run0.png"}]}))
    return sc["rob_H_cam"]


# --------------------------------------------------------------------------- experiment

#: the reflector's height above the support plane in the scene (PCS z of P0 above the surface)
REFLECTOR_HEIGHT = 300.0


def render_dot(cam_H_abs: np.ndarray, mark_abs: np.ndarray, radius_mm: float, ppmm: float = 50.0,
               supersample: int = 4, psf_px: float = 1.0) -> np.ndarray:
    """8-bit image of a dark disc on a grey floor (the plane ACS z = mark z) seen by the camera K."""
    half = 10.0
    n = round(2 * half * ppmm)
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) / ppmm - half
    patch = np.where(np.hypot(xx, yy) <= radius_mm, 40, 200).astype(np.uint8)
    # patch pixel -> floor (u, v) mm around the mark -> camera pixel -> supersampled pixel
    S = np.array([[1 / ppmm, 0, 0.5 / ppmm - half], [0, 1 / ppmm, 0.5 / ppmm - half], [0, 0, 1]])
    P = K @ np.column_stack([cam_H_abs[:3, 0], cam_H_abs[:3, 1], _apply(cam_H_abs, mark_abs)])
    s = supersample
    A = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1]])
    big = cv2.warpPerspective(patch, A @ P @ S, (SIZE[0] * s, SIZE[1] * s), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=200)
    img = cv2.resize(big, SIZE, interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(img, (0, 0), psf_px) if psf_px > 0 else img


def write_experiment(root: Path, calibration: dict[str, Any], rob_H_cam: np.ndarray, mark_abs: Any, *,
                     headings=(0.0, 180.0), reps: int = 2, bits: int = 8, sigma_t_mm: float | None = 0.010) -> None:
    """An experiment folder: the robot upright on a level floor (ACS z), stops around ``mark_abs``.

    ``calibration`` is the referencing result.json the stops are measured with;
    ``rob_H_cam`` is the writer's own truth, which makes the images.
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    M = np.asarray(mark_abs, float)
    c, d = rob_H_cam[:3, 3], rob_H_cam[:3, 2]
    foot = c + (-REFLECTOR_HEIGHT - c[2]) / d[2] * d  # optical axis on the support plane, robot frame
    stops = []
    for k, psi in enumerate(headings):
        for r in range(reps):
            R = _rot("z", psi + 0.3 * r)
            P_at = np.array([*(M[:2] - (R @ foot)[:2] + [0.4 * r, -0.3 * r]), M[2] + REFLECTOR_HEIGHT])
            P_prev = P_at - 200.0 * R[:, 0]
            abs_H_cam = _H(R, P_at) @ rob_H_cam
            img = render_dot(np.linalg.inv(abs_H_cam), M, 0.4)
            if bits == 16:
                img = img.astype(np.uint16) * 257
            name = f"stop-{len(stops):03d}-k{k}-r{r}.png"
            cv2.imwrite(str(root / name), img)
            stops.append({"image": name, "k": k, "rep": r, "P_prev": point(P_prev), "P_at": point(P_at),
                          "header": {"shape": [SIZE[1], SIZE[0]], "dtype": "|u1" if bits == 8 else "<u2"}})
    state = {"schema": 1, "procedure": "experiment",
             "obs": {"calibration": calibration, "kind": "dot", "mark_size_mm": 0.4, "stops": stops,
                     **({} if sigma_t_mm is None else {"sigma_t_mm": sigma_t_mm})}}
    (root / "state.json").write_text(json.dumps(state, indent=1))


# --------------------------------------------------------------------------- intrinsics

#: the hand-held board of docs/datasets.md, "Intrinsics board definition" (the values it shows)
INTRINSICS_BOARD = {"schema": 1, "board_id": "RITA-INTRINSICS-1", "board_cols": 12, "board_rows": 9,
                    "square_mm": 4.0, "marker_mm": 3.0, "aruco_dict": "DICT_4X4_100", "notes": ""}
#: (tilt about the board's x, about its y, turn about the line of sight) in degrees, and where the board's
#: centre appears (fraction of the image from its centre, x and y): tilted views fix the focal length
#: (a board seen square-on leaves it coupled to the distance), views in the corners the distortion there
VIEW_TILTS = ((0, 0, 0, 0.0, 0.0), (25, 0, 0, 0.0, 0.0), (-25, 0, 0, 0.0, 0.0), (0, 25, 0, 0.0, 0.0),
              (0, -25, 0, 0.0, 0.0), (20, 20, 10, 0.0, 0.0), (-20, 20, -10, 0.0, 0.0),
              (15, -20, 30, 0.0, 0.0), (0, 0, 0, -0.3, -0.3), (0, 0, 0, 0.3, -0.3), (0, 0, 0, -0.3, 0.3),
              (0, 0, 0, 0.3, 0.3))


def write_intrinsics(root: Path, distance_mm: float = 60.0) -> None:
    """An intrinsics folder: the board seen by the camera K from ``distance_mm`` at each of VIEW_TILTS."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    bd = INTRINSICS_BOARD
    b = {"cols": bd["board_cols"], "rows": bd["board_rows"], "square": bd["square_mm"],
         "marker": bd["marker_mm"], "dict": bd["aruco_dict"]}
    centre = np.array([b["cols"] * b["square"] / 2, b["rows"] * b["square"] / 2, 0.0])
    views, entries = [], []
    for i, (tx, ty, rz, fx, fy) in enumerate(VIEW_TILTS):
        R = _rot("z", rz) @ _rot("y", ty) @ _rot("x", tx)  # camera axes in the board frame; z toward it
        # the camera moved sideways so that the centre projects at (fx, fy) of the image's width and height
        side = -distance_mm * (fx * SIZE[0] * R[:, 0] + fy * SIZE[1] * R[:, 1]) / K[0, 0]
        ref_H_cam = _H(R, centre - distance_mm * R[:, 2] + side)
        img = render(np.linalg.inv(ref_H_cam), ppmm=20.0, b=b)
        name = f"view-{i:02d}"
        cv2.imwrite(str(root / f"{name}.png"), img)
        header = {"shape": list(img.shape), "dtype": "|u1"}
        (root / f"{name}.json").write_text(json.dumps({"camera": header, "image_file": f"{name}.png"}))
        key = f"view-{tx:+d}-{ty:+d}-{rz:+d}-{fx:+}-{fy:+}"
        views.append({"image": f"{name}.png", "header": header, "key": key})
        entries.append({"name": name, "json": f"{name}.json", "image": f"{name}.png"})
    state = {"schema": 1, "procedure": "intrinsics", "obs": {"board": bd, "views": views, "skipped": []}}
    (root / "state.json").write_text(json.dumps(state, indent=1))
    (root / "dataset.json").write_text(json.dumps({"schema": 1, "kind": "procedure:intrinsics", "meta": {},
                                                   "entries": entries}))
