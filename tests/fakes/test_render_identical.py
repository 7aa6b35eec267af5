"""The renderer's skipped work changes no pixel: fakes/render.py against its former version, bit for bit.

``Renderer._albedo_rows`` skips what its result never used (the scene behind a held board, the plate
texture of a chunk without the plate, marks outside a chunk's extent on the floor); the version
before that change is kept here, verbatim but for its names, and both must give the same float32
albedo, on views with the plate and floor, floor only (a mark in view or none), a held board, the
paper+imu world (printed target's scale, floor height) and the colour renderer. Small chunks
(``CHUNK_SAMPLES``) make chunks of each kind inside one view.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import fakes.render as render
from calibration.frames import inv_H
from fakes.colour import ColourRenderer
from fakes.profiles import world as profile_world
from fakes.render import DARK, FLOOR_MEAN, WHITE, Renderer, _coverage
from fakes.world import World, WorldParams

SIZE = (200, 150)


def former_albedo_rows(self: Any, abs_H_cam: np.ndarray, j0: int, j1: int, k0: int, k1: int) -> np.ndarray:
    world, p = self.world, self.world.params
    x, y = self._rays(j0, j1, k0, k1)
    ref_H_cam = inv_H(world.abs_H_ref) @ abs_H_cam
    H = self._plane_homography(ref_H_cam)
    den = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    ok = den > 1e-12
    den = np.where(ok, den, 1.0)
    qx = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / den
    qy = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / den
    c = world.board_centre_ref()
    half = p.plate_half_size_mm
    plate = ok & (np.abs(qx - c[0]) <= half) & (np.abs(qy - c[1]) <= half)
    alb = self._plate_albedo(qx, qy, ref_H_cam[2, 3])
    floor = ~plate
    if floor.any():
        Hf = self._plane_homography(world.effects.floor_view_H(abs_H_cam))

        def to_floor(xf: np.ndarray, yf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            df = Hf[2, 0] * xf + Hf[2, 1] * yf + Hf[2, 2]
            okf = df > 1e-12
            df = np.where(okf, df, 1.0)
            X = (Hf[0, 0] * xf + Hf[0, 1] * yf + Hf[0, 2]) / df
            return okf, X, (Hf[1, 0] * xf + Hf[1, 1] * yf + Hf[1, 2]) / df

        ss, k = self.ss, self.ss // 2
        _, Xc, Yc = to_floor(x[k::ss, k::ss], y[k::ss, k::ss])
        tex = np.repeat(np.repeat(self._floor_texture(Xc, Yc), ss, axis=0), ss, axis=1)
        okf, X, Y = to_floor(x[floor], y[floor])
        alb[floor] = np.where(okf, former_floor_marks(self, tex[floor], X, Y, abs_H_cam[2, 3]), FLOOR_MEAN)
    held = world.held_board
    return alb if held is None else held.overlay(x, y, alb)


def former_floor_marks(self: Any, alb: np.ndarray, X: np.ndarray, Y: np.ndarray,
                       height_mm: float) -> np.ndarray:
    wd = self._width_mm(height_mm)
    alb = alb.astype(np.float64)
    for mark in self.world.params.marks:
        reach = mark.size_mm * 1.5 + 0.5
        dX, dY = X - mark.x_mm, Y - mark.y_mm
        near = (np.abs(dX) < reach) & (np.abs(dY) < reach)
        if not near.any():
            continue
        dx, dy = dX[near], dY[near]
        if mark.kind == "dot":
            cov = _coverage(np.hypot(dx, dy) - mark.size_mm, wd)
            inner = DARK
        else:
            sx, sy = np.clip(2 * dx / wd, -1, 1), np.clip(2 * dy / wd, -1, 1)
            inner = (WHITE + DARK) / 2 - (WHITE - DARK) / 2 * sx * sy
            cov = (_coverage(np.abs(dx) - mark.size_mm, wd) * _coverage(np.abs(dy) - mark.size_mm, wd))
        alb[near] = alb[near] * (1 - cov) + inner * cov
    return alb.astype(np.float32)


def both(r: Renderer, H: np.ndarray, monkeypatch: pytest.MonkeyPatch) -> tuple[np.ndarray, np.ndarray]:
    """(albedo now, albedo of the former version) of one view."""
    now = r.albedo(H)
    with monkeypatch.context() as m:
        m.setattr(Renderer, "_albedo_rows", former_albedo_rows)
        before = r.albedo(H)
    return now, before


def views(world: World) -> dict[str, np.ndarray]:
    """abs_H_cam of the plate in view (plate and floor), each mark at the footprint, and bare floor."""
    on_plate = world.pose_with_target_in_view(world.plate_yaw_deg + 60.0)
    out = {"plate": world.abs_H_rob(on_plate) @ world.rob_H_cam}
    for m in world.params.marks:  # the mark a little off the footprint: part of it in a chunk's edge
        pose = world.pose_with_footprint_at(m.x_mm + 0.7, m.y_mm - 0.4, 30.0)
        out[m.name] = world.abs_H_rob(pose) @ world.rob_H_cam
    out["floor"] = world.abs_H_rob(world.pose_with_footprint_at(2000.0, 1000.0, 0.0)) @ world.rob_H_cam
    return out


@pytest.mark.parametrize("profile", ["ideal", "paper+imu"])
def test_albedo_equals_the_former_version_bit_for_bit(profile: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(render, "CHUNK_SAMPLES", 40_000)  # several chunks per view, of each kind
    world = profile_world(profile, seed=7)
    for name, H in views(world).items():
        for r in (Renderer(world, SIZE), ColourRenderer(world, SIZE)):
            now, before = both(r, H, monkeypatch)
            assert now.dtype == before.dtype == np.float32
            assert np.array_equal(now, before), (profile, name, type(r).__name__)
    kinds = {name: float(np.ptp(Renderer(world, SIZE).albedo(H))) for name, H in views(world).items()}
    # the marks were in view (a dark dot or cross on the floor texture), the bare floor only its texture
    assert min(kinds["M1"], kinds["M2"]) > 0.3 > kinds["floor"] > 0.0, kinds


def test_held_board_albedo_equals_the_former_version(monkeypatch: pytest.MonkeyPatch) -> None:
    world = World(WorldParams(seed=5))
    world.hold_board(z_mm=60.0, tilt_x_deg=12.0, rot_deg=20.0)
    now, before = both(Renderer(world, SIZE), world.abs_H_cam(), monkeypatch)
    assert np.array_equal(now, before)
    assert np.ptp(now) > 0.5  # the board's squares are in view

