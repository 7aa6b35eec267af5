"""The scene coordinate system (SCS, ``scn``): the rectified image on the floor.

Convention (paper, "Scene (SCS, scn)"), all in mm:

* The SCS xy-plane is the PCS xy-plane, i.e. the plate surface the robot stands on
  (its support plane). SCS z is the plane normal pointing *up*, toward the camera
  (PCS z points into the plate, so ``scn z = −ref z``).
* SCS x is the image column direction (+u) projected onto the plane; SCS y is the
  image row direction *reversed* (−v). With z up this is right-handed; x = +col,
  y = +row would be a mirror image.
* The origin is placed so that the whole image footprint (the pixel-edge outline of
  the image mapped onto the plane) lies in the positive xy-quadrant, touching both
  axes: ``0 <= x <= extent_mm[0]``, ``0 <= y <= extent_mm[1]``.

``scn_H_cam`` is fixed in the camera (and so in the robot): once made from one
referencing image it maps every later image onto the floor under the robot,
assuming the floor is the plane the robot stands on. Points are mapped analytically
(undistort → ray → plane), never through a resampled image.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError
from calibration.frames import check_H, inv_H, make_H

SCS_SCHEMA = 1


@dataclass
class Scs:
    """SCS of one camera: ``scn_H_cam``, the camera model and the image footprint."""

    scn_H_cam: np.ndarray
    model: CameraModel
    gsd_mm: float  # ground sample distance at the principal point, mm per pixel
    extent_mm: tuple[float, float]  # footprint bounding box: 0..x_max, 0..y_max

    def __post_init__(self) -> None:
        self.scn_H_cam = check_H(np.asarray(self.scn_H_cam, dtype=float), "scn_H_cam")
        if self.scn_H_cam[2, 3] <= 0:
            raise ValueError(f"scn_H_cam: the camera must be above the plane "
                             f"(z = {self.scn_H_cam[2, 3]:.3f} mm)")

    @property
    def size(self) -> tuple[int, int]:
        """Image size (w, h) of the camera model."""
        return self.model.size

    def image_to_scn(self, uv: np.ndarray) -> np.ndarray:
        """Map pixel coordinates (N, 2) of the distorted image to SCS xy (N, 2) on z = 0."""
        xy_n = self.model.undistort(uv)
        R, C = self.scn_H_cam[:3, :3], self.scn_H_cam[:3, 3]
        d = np.column_stack([xy_n, np.ones(len(xy_n))]) @ R.T
        with np.errstate(divide="ignore"):
            s = -C[2] / d[:, 2]
        bad = ~(s > 0)
        if bad.any():
            raise ValueError(f"image_to_scn: {int(bad.sum())} pixel ray(s) do not meet the plane in front of "
                             f"the camera, e.g. uv={np.asarray(uv, float).reshape(-1, 2)[bad][0]}")
        return C[:2] + s[:, None] * d[:, :2]

    # ------------------------------------------------------------------ files

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (lists), with a schema number."""
        return {"schema": SCS_SCHEMA, "scn_H_cam": self.scn_H_cam.tolist(), "model": self.model.to_dict(),
                "gsd_mm": self.gsd_mm, "extent_mm": list(self.extent_mm)}

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "scs") -> "Scs":
        """Inverse of :meth:`to_dict`; errors name ``source``."""
        if d.get("schema", SCS_SCHEMA) != SCS_SCHEMA:
            raise ValueError(f"{source}: SCS schema {d.get('schema')} is not supported "
                             f"(expected {SCS_SCHEMA})")
        try:
            return cls(np.array(d["scn_H_cam"], float), CameraModel.from_dict(d["model"], source),
                       float(d["gsd_mm"]), (float(d["extent_mm"][0]), float(d["extent_mm"][1])))
        except KeyError as exc:
            raise ValueError(f"{source}: missing field {exc}") from None


def _outline_uv(size: tuple[int, int], n: int = 200) -> np.ndarray:
    """Points along the outer pixel edges of an image of ``size``."""
    w, h = size
    u = np.linspace(-0.5, w - 0.5, n)
    v = np.linspace(-0.5, h - 0.5, n)
    return np.vstack([np.column_stack([u, np.full(n, -0.5)]), np.column_stack([u, np.full(n, h - 0.5)]),
                      np.column_stack([np.full(n, -0.5), v]), np.column_stack([np.full(n, w - 0.5), v])])


def make_scs(model: CameraModel, cam_H_ref: np.ndarray) -> Scs:
    """The SCS for a camera at ``cam_H_ref`` above the plate (see the module docstring)."""
    ref_H_cam = inv_H(check_H(cam_H_ref, "cam_H_ref"))
    if ref_H_cam[2, 3] >= 0:
        raise CalibrationError(f"camera is not above the plate surface (PCS z of the camera = "
                               f"{ref_H_cam[2, 3]:.3f} mm; PCS z points into the plate)")
    col = ref_H_cam[:3, 0]  # image column direction (camera x) in PCS
    x_axis = np.array([col[0], col[1], 0.0])
    if np.linalg.norm(x_axis) < 1e-3:
        raise CalibrationError("camera x axis is (nearly) perpendicular to the plate; the SCS is undefined")
    x_axis /= np.linalg.norm(x_axis)
    z_axis = np.array([0.0, 0.0, -1.0])
    ref_R_scn = np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis])
    # first with the origin at the PCS origin, then shift so the footprint touches both axes
    scn0_H_cam = inv_H(make_H(ref_R_scn, np.zeros(3), "ref_H_scn")) @ ref_H_cam
    tmp = Scs(scn0_H_cam, model, 1.0, (1.0, 1.0))
    outline = tmp.image_to_scn(_outline_uv(model.size))
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    scn_H_cam = scn0_H_cam.copy()
    scn_H_cam[:2, 3] -= lo
    tmp = Scs(scn_H_cam, model, 1.0, (1.0, 1.0))
    c = model.K[:2, 2]
    p = tmp.image_to_scn(np.array([c - [0.5, 0], c + [0.5, 0], c - [0, 0.5], c + [0, 0.5]]))
    gsd = 0.5 * (np.linalg.norm(p[1] - p[0]) + np.linalg.norm(p[3] - p[2]))
    return Scs(scn_H_cam, model, float(gsd), (float(hi[0] - lo[0]), float(hi[1] - lo[1])))
