"""The hand-held calibration board in the simulated world, and a simulated operator holding it.

The operator holds a small ChArUco board (``calibration.board.DEFAULT_BOARD``) under the
camera; its pose is given relative to the camera (CCS, mm), set through the sim-only bus
command ``sim.hold_board`` (:meth:`fakes.world.World.hold_board`). The renderer
(:mod:`fakes.render`) draws it over the scene: each sub-sample's viewing ray is
intersected with the board plane (as the plate's top face is), and the print's texture,
box-filtered over one sub-sample's footprint (so a pixel integrates its area),
looked up there.

Simplifications (stated, not tuned): the recipe starts by putting the robot on its
calibration stand, so while the board is held the camera sees it against the stand's
bench, drawn as a plain mid-grey surface (the floor and plate under the robot's simulated
pose are not drawn then); the board is perfectly flat and evenly lit, and no depth of
field is modelled. The print is exactly its nominal definition unless the world carries
``board_print_scale`` (true size / nominal size per board axis; the hook for a print that
differs from its file: the error profiles set it from the target's print error group,
fakes/effects.py; docs/accuracy.md).

:func:`answer_intrinsics_prompt` plays the operator for the ``intrinsics`` procedure: it
reads the view key in the prompt, holds the board in the recipe's nominal pose plus the
scatter of a person aiming by eye at a live view (assumed: ±4° tilt and turn, ±2° aim,
±4 mm distance, 1σ; no measured source), and answers. The demo and the tests use it.
"""
from __future__ import annotations

import math
import re
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import cv2
import numpy as np

from calibration.board import DEFAULT_BOARD, Board, detect_board_corners
from calibration.frames import make_H, rot_x, rot_y, rot_z
from calibration.intrinsics_recipe import CORNERS, RECIPE, SPECS, ViewSpec, reaches_corner
from calibration.target import make_board

#: texels per mm of the board print (squares must span whole texels)
PPMM = 100.0
#: white margin printed around the squares (a quiet zone for the outer markers), mm
MARGIN_MM = 3.0
#: albedo of the print (as the plate target's, fakes/render.py)
DARK, WHITE = 0.05, 0.92
#: albedo of the bench under the calibration stand (a plain mid-grey surface, as the floor's mean)
BENCH = 0.45
#: the simulated operator's 1σ scatter around the recipe's pose (assumed, see the docstring)
OPERATOR_SIGMA = {"tilt_deg": 4.0, "rot_deg": 4.0, "aim_deg": 2.0, "distance_mm": 4.0}
#: a World attribute (x, y): the true print's size / nominal size (see the module docstring)
PRINT_SCALE_ATTR = "board_print_scale"
_VIEW_TAG = re.compile(r"\[view ([\w+\-]+)\]")


@dataclass
class HeldBoard:
    """A printed board at ``cam_H_board`` (board frame = OpenCV board frame, origin at the first corner)."""

    board: Board
    cam_H_board: np.ndarray
    print_scale: tuple[float, float] = (1.0, 1.0)
    texture: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.texture = _texture(self.board)

    def overlay(self, x: np.ndarray, y: np.ndarray, alb: np.ndarray) -> np.ndarray:
        """The albedo seen along the rays (x, y, 1) (normalised CCS): the board where they meet it,
        else the bench (``alb``, the scene under the robot's pose, is not in view on the stand)."""
        # ray d = (x, y, 1) meets the board plane n·(P − t) = 0 at s·d, s = n·t / n·d (in front: s > 0)
        R, t = self.cam_H_board[:3, :3], self.cam_H_board[:3, 3]
        n = R[:, 2]
        nd = n[0] * x + n[1] * y + n[2]
        s = np.divide(float(n @ t), nd, out=np.full_like(nd, -1.0), where=np.abs(nd) > 1e-12)
        ok = s > 0
        # board coordinates of the hit point: Rᵀ(s·d − t)
        px, py, pz = s * x - t[0], s * y - t[1], s - t[2]
        qx = (R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz) / self.print_scale[0]
        qy = (R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz) / self.print_scale[1]
        bw, bh = self.board.board_size_mm()
        on = ok & (qx >= -MARGIN_MM) & (qx <= bw + MARGIN_MM) & (qy >= -MARGIN_MM) & (qy <= bh + MARGIN_MM)
        out = np.full_like(alb, np.float32(BENCH))  # the robot is on its stand: the bench is behind the board
        if not on.any():
            return out
        dist_mm = float(t @ n) / max(abs(float(n[2])), 1e-6)  # along the optical axis to the board
        tex = _prefiltered(self.board, self.texture, _footprint_texels(x, dist_mm))
        th, tw = tex.shape
        # texel k's centre sits at (k + 0.5)/PPMM − MARGIN_MM: square edges fall on texel boundaries
        mx = np.clip((qx + MARGIN_MM) * PPMM - 0.5, -4, tw + 4).astype(np.float32)
        my = np.clip((qy + MARGIN_MM) * PPMM - 0.5, -4, th + 4).astype(np.float32)
        val = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=255)
        out[on] = np.float32(DARK) + np.float32((WHITE - DARK) / 255.0) * val[on].astype(np.float32)
        return out


def _footprint_texels(x: np.ndarray, dist_mm: float) -> int:
    """The width of one sub-sample on the board, in texels, rounded to an odd count (a centred box).

    The sub-samples point-sample the print; a square edge then falls on a 1/SS-pixel grid and
    the detected corners are pulled towards it (measured at 1000x750, SS = 3: 0.07 px rms corner
    error, noise-free, and the fitted cx 3.5σ off; docs/accuracy.md). Box-filtering the print
    over one sub-sample's footprint makes the SS×SS mean the exact pixel-area integral the
    sensor takes (100 % fill factor). ``dist_mm`` is the board plane's depth along the optical axis.
    """
    xs = np.asarray(x).reshape(np.asarray(x).shape[0], -1) if np.ndim(x) > 1 else np.asarray(x)[None]
    step = float(np.median(np.abs(np.diff(xs, axis=-1)))) if xs.shape[-1] > 1 else 0.0
    k = int(round(abs(dist_mm) * step * PPMM))
    return max(1, k | 1)


_PREFILTERED: dict[tuple[Board, int], np.ndarray] = {}


def _prefiltered(board: Board, texture: np.ndarray, k: int) -> np.ndarray:
    """``texture`` box-filtered over k×k texels (k odd, so the box is centred; cached)."""
    if k <= 1:
        return texture
    with _TEXTURE_LOCK:
        tex = _PREFILTERED.get((board, k))
        if tex is None:
            tex = cv2.blur(texture, (k, k), borderType=cv2.BORDER_REPLICATE)
            tex.flags.writeable = False
            _PREFILTERED[(board, k)] = tex
        return tex


_TEXTURES: dict[Board, np.ndarray] = {}
_TEXTURE_LOCK = threading.Lock()


def _texture(board: Board) -> np.ndarray:
    """The print (squares plus the white margin) at PPMM texels per mm (cached per board)."""
    with _TEXTURE_LOCK:
        tex = _TEXTURES.get(board)
        if tex is None:
            ppsq = board.square_mm * PPMM
            if abs(ppsq - round(ppsq)) > 1e-9:
                raise ValueError(f"board {board.board_id!r}: square_mm={board.square_mm} "
                                 f"is not a whole number of texels at {PPMM} texels/mm")
            bw, bh = board.board_size_mm()
            m = round(MARGIN_MM * PPMM)
            tex = make_board(board).generateImage((round(bw * PPMM) + 2 * m, round(bh * PPMM) + 2 * m),
                                                  marginSize=m, borderBits=1)
            tex.flags.writeable = False
            _TEXTURES[board] = tex
        return tex


def board_pose(board: Board, x_mm: float, y_mm: float, z_mm: float, tilt_x_deg: float = 0.0,
               tilt_y_deg: float = 0.0, rot_deg: float = 0.0) -> np.ndarray:
    """cam_H_board with the board centre at CCS (x, y, z), oriented as in calibration.intrinsics_recipe."""
    if not z_mm > 0:
        raise ValueError(f"z_mm={z_mm}: the board must be in front of the camera (z > 0)")
    R = rot_z(math.radians(rot_deg)) @ rot_x(math.radians(tilt_x_deg)) @ rot_y(math.radians(tilt_y_deg))
    bw, bh = board.board_size_mm()
    centre = np.array([x_mm, y_mm, z_mm])
    return make_H(R, centre - R @ np.array([bw / 2, bh / 2, 0.0]), "cam_H_board")


def hold(world: Any, z_mm: float | None = None, x_mm: float = 0.0, y_mm: float = 0.0,
         tilt_x_deg: float = 0.0, tilt_y_deg: float = 0.0, rot_deg: float = 0.0,
         board: Board | None = None) -> dict[str, Any]:
    """Hold the board at that pose in ``world`` (a fakes.world.World, which calls this; ``z_mm`` None:
    take it away); returns what is held."""
    if z_mm is None:
        world.held_board = None
        return {"held": False}
    b = board or Board.from_dict(DEFAULT_BOARD)
    H = board_pose(b, x_mm, y_mm, z_mm, tilt_x_deg, tilt_y_deg, rot_deg)
    world.held_board = HeldBoard(b, H, tuple(getattr(world, PRINT_SCALE_ATTR, (1.0, 1.0))))
    return {"held": True, "board_id": b.board_id, "cam_H_board": H.tolist()}


def operator_pose(spec: ViewSpec, rng: np.random.Generator) -> dict[str, float]:
    """The pose a person following ``spec``'s instruction by eye ends up with (sim.hold_board args)."""
    s = OPERATOR_SIGMA
    ax = math.radians(spec.aim_x_deg + rng.normal(0, s["aim_deg"]))
    ay = math.radians(spec.aim_y_deg + rng.normal(0, s["aim_deg"]))
    z = spec.distance_mm + rng.normal(0, s["distance_mm"])
    return {"x_mm": z * math.tan(ax), "y_mm": z * math.tan(ay), "z_mm": z,
            "tilt_x_deg": spec.tilt_x_deg + rng.normal(0, s["tilt_deg"]),
            "tilt_y_deg": spec.tilt_y_deg + rng.normal(0, s["tilt_deg"]),
            "rot_deg": spec.rot_deg + rng.normal(0, s["rot_deg"])}


def answer_intrinsics_prompt(client: Any, question: str, rng: np.random.Generator) -> str:
    """Act on one prompt of the ``intrinsics`` procedure and return the answer to send.

    A view prompt (it names ``[view KEY]``): hold the board as the recipe says, answer
    ``ok``. The install question of a ``warn`` model: ``skip`` (a warn model is not
    installed without a person's yes). Anything else
    (the set-up prompt): take the board away and answer ``ok``.
    """
    m = _VIEW_TAG.search(question)
    if m and m.group(1) in SPECS:
        client.call("sim.hold_board", **operator_pose(SPECS[m.group(1)], rng))
        return "ok"
    if "Install" in question:
        return "skip"
    client.call("sim.hold_board")
    return "ok"


def recipe_images(world: Any, renderer: Any, rng: np.random.Generator, noise: np.random.Generator,
                  tries: int = 5) -> list[np.ndarray]:
    """The recipe's views rendered without ritad (benchmarks, calibration tests), checked as the
    procedure checks them: a corner view that misses its image corner is presented again."""
    board = Board.from_dict(DEFAULT_BOARD)
    images = []
    for spec in RECIPE:
        for _ in range(tries):
            world.hold_board(**operator_pose(spec, rng))
            image = renderer.render(rng=noise)
            if spec.key not in CORNERS or reaches_corner(detect_board_corners(image, board)[1], renderer.size,
                                                         spec.key):
                break
        images.append(image)
    world.hold_board()
    return images


Answer = Callable[[Any, str, np.random.Generator], "str | None"]


def run_intrinsics(client: Any, params: dict[str, Any], seed: int = 1, timeout: float = 600.0,
                   answer: Answer = answer_intrinsics_prompt, job: str | None = None) -> dict[str, Any]:
    """Post an ``intrinsics`` job (or resume ``job``) and play the operator until its result message.

    ``answer(client, question, rng)`` acts on each prompt and returns the answer (None: send
    none); the questions seen are returned under ``_prompts``.
    """
    rng = np.random.default_rng(seed)
    sub = client.subscriber(["calib.result", "calib.prompt"])
    try:
        time.sleep(0.2)  # the subscription reaches the daemon before the first prompt can
        if job is None:
            job = client.call("calib.start", procedure="intrinsics", params=params)["job"]
        else:
            client.call("calib.resume", job=job)
        prompts: list[str] = []
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            msg = sub.recv(1.0)
            if not msg or msg[1]["data"].get("job") != job:
                continue
            data = msg[1]["data"]
            if msg[0] == "calib.result":
                return {**data, "job": job, "_prompts": prompts}
            prompts.append(data["question"])
            reply = answer(client, data["question"], rng)
            if reply is not None:
                client.call("calib.answer", job=job, answer=reply)
        raise TimeoutError(f"intrinsics job {job} did not finish within {timeout:.0f} s")
    finally:
        sub.close()
        client.call("sim.hold_board")  # the operator puts the board away


__all__ = ["HeldBoard", "answer_intrinsics_prompt", "board_pose", "hold", "operator_pose", "recipe_images",
           "run_intrinsics"]
