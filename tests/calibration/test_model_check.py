"""The camera-model check inside the referencing verdict.

Rendered images at the CI size (1000x750). The correct model and
the bad ones are the test's *inputs*: the bad models are the world's lens with fx, fy
scaled and the distortion kept (a focal length that does not match its distortion),
which is the mistake a model check must catch; truth is otherwise only
used to score.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from calibration.camera_model import CameraModel
from calibration.model_check import ModelCheckGates, check_camera_model, model_sigma_f
from calibration.referencing import board_corners_ref, reference, rob_H_cam_error
from calibration.target import detect_corners, pose_from_corners
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams

STREAMS = ("calib0", "calib1", "calib2")  # three visits: random heading, image noise and tracker noise each


@pytest.fixture(scope="module")
def visits():
    """One world, three rendered referencing visits with their detected corners."""
    sim = Simulation(World(WorldParams(seed=1)), SimConfig(seed=1, render=True, size=(1000, 750)))
    out = []
    for stream in STREAMS:
        obs = sim.calibration(stream=stream)
        ids, uv = detect_corners(obs.image, sim.plate)
        out.append((obs, ids, uv))
    return sim, out


def scaled_focal(model: CameraModel, s: float, self_consistent: bool = False) -> CameraModel:
    """``model`` with fx, fy × s; distortion kept, or (self_consistent) rescaled to give the same pixels."""
    K = model.K.copy()
    K[:2, :2] *= s
    d = model.dist.copy()
    if self_consistent:  # x_d = x·(1 + k1 r² + k2 r⁴ + k3 r⁶) + tangential terms, with x → x/s
        d *= [s ** 2, s ** 4, s, s, s ** 6]
    return CameraModel(K, d, model.size)


def referencing(sim, obs, ids, uv, model, **kw):
    cam_ref = pose_from_corners(ids, uv, model, sim.plate)  # what reference(image=...) does after detection
    return reference(model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, cam_ref=cam_ref,
                     sigma_t_mm=sim.cfg.sigma_t_mm, mc_samples=0, **kw)


def test_correct_model_gives_no_false_alarm(visits):
    sim, runs = visits
    for obs, ids, uv in runs:
        res = reference(sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, image=obs.image,
                        sigma_t_mm=sim.cfg.sigma_t_mm, mc_samples=0)
        mc = res.model_check
        assert mc is not None and mc.verdict == "ok", mc.messages
        assert res.verdict == "ok", res.messages
        assert mc.focal.significance < ModelCheckGates().min_significance
        # the check can see what matters at this size: a 45 µm height error is resolvable
        assert mc.focal.resolvable_height_mm < ModelCheckGates().fail_height_mm
        d = res.to_dict()["model_check"]
        assert d["verdict"] == "ok" and set(d) >= {"focal_refit", "radial_pattern"}


@pytest.mark.parametrize("s", [0.995, 1.005, 0.99, 1.01, 0.98, 1.02])
def test_focal_error_with_kept_distortion_is_caught_naming_the_camera_model(visits, s):
    sim, runs = visits
    gates = ModelCheckGates()
    for k, (obs, ids, uv) in enumerate(runs):
        res = referencing(sim, obs, ids, uv, scaled_focal(sim.model, s))
        mc = res.model_check
        f, r = mc.focal, mc.radial
        t_z = rob_H_cam_error(res.rob_H_cam, sim.world.rob_H_cam)["t_z_mm"]  # scoring only
        print(f"\nf x {s}: visit {k}: refit {100 * (f.scale - 1):+.3f} % ± {100 * f.sigma:.3f} % "  # pytest -s
              f"({f.significance:.0f}σ vs {gates.min_significance:g}σ), height change "
              f"{1000 * f.height_change_mm:+.0f} µm vs {1000 * gates.fail_height_mm:.0f} µm; radial F "
              f"{r.f_ratio:.0f} vs {gates.radial_min_f_ratio:g}, peak {1000 * r.peak_plate_mm:.1f} µm vs "
              f"{1000 * gates.radial_warn_plate_mm:.0f} µm; reprojection RMS {res.rms_px:.3f} px; "
              f"t_z error {1000 * t_z:.0f} µm")
        assert res.verdict in ("warn", "fail"), res.messages
        named = [m for m in res.messages if m.startswith("camera model:")]
        assert named and all("ritactl intrinsics" in m for m in named), res.messages
        # the refit finds the error it was given, within its σ and the true model's own offset
        assert abs(f.scale * s - 1) < 5 * f.sigma + 0.001


def test_self_consistent_wrong_focal_is_invisible_in_one_planar_view(visits):
    """The z/f degeneracy the docs describe: same residuals, distance scaled by s, verdict ok.

    Only the model's own calibration uncertainty can flag such a model (next test).
    """
    sim, runs = visits
    obs, ids, uv = runs[0]
    good = pose_from_corners(ids, uv, sim.model, sim.plate)
    for s in (0.99, 1.01):
        model = scaled_focal(sim.model, s, self_consistent=True)
        bad = pose_from_corners(ids, uv, model, sim.plate)
        assert abs(bad.rms_px - good.rms_px) < 1e-4
        assert bad.cam_H_ref[2, 3] / good.cam_H_ref[2, 3] == pytest.approx(s, abs=1e-4)
        # lateral position on the target is unchanged: a GSD-vs-drive check is blind too
        assert np.abs(bad.cam_H_ref[:2, 3] - good.cam_H_ref[:2, 3]).max() < 0.01
        mc = check_camera_model(model, board_corners_ref(sim.plate, ids), uv, bad.cam_H_ref)
        assert mc.verdict == "ok"


def test_model_std_flags_an_uncertain_focal_length(visits):
    sim, runs = visits
    obs, ids, uv = runs[0]
    model = sim.model
    base = model.to_dict()
    f = model.K[0, 0]
    # a near-nadir intrinsics run reports f to ±0.5 %: 3σ is ~450 µm of camera height
    loose = {**base, "std": {"fx": 0.005 * f, "fy": 0.004 * f, "cx": 1.0}}
    res = referencing(sim, obs, ids, uv, model, model_dict=loose)
    assert res.verdict == "warn" and any(m.startswith("camera model: its calibration gives the focal length")
                                         and "ritactl intrinsics" in m for m in res.messages), res.messages
    assert res.model_check.model_sigma_f == pytest.approx(0.005)
    tight = {**base, "std": {"fx": 0.0002 * f, "fy": 0.0002 * f}}  # 3σ: ~18 µm
    assert referencing(sim, obs, ids, uv, model, model_dict=tight).verdict == "ok"
    # an old file without std, or with no usable σ in it: no finding
    assert model_sigma_f(base) is None
    assert model_sigma_f({**base, "std": {"fx": "n/a", "fy": None}}) is None
    res = referencing(sim, obs, ids, uv, model, model_dict=base)
    assert res.verdict == "ok" and any(m.startswith("camera model (note): camera height not resolved by this model")
                                       for m in res.messages), res.messages


@pytest.mark.parametrize("s", [0.95, 0.99, 1.01, 1.05])
@pytest.mark.parametrize("with_std", [False, True])
def test_a_self_consistent_wrong_focal_length_never_gives_an_uncovered_camera_height(visits, s, with_std):
    """f × s with the distortion rescaled to give the same pixels: rob_H_cam's t_z is off by
    (s − 1) × the camera height, which no image of the plate shows. The result is either `warn`, or its
    stated t_z σ covers the error within 3σ. With a std in the model, it is an honest one for this
    model: an intrinsics calibration that ended 1 % off states about 1 %, not 0.02 %."""
    sim, runs = visits
    obs, ids, uv = runs[0]
    model = scaled_focal(sim.model, s, self_consistent=True)
    f = model.K[0, 0]
    doc = {**model.to_dict(), "std": {"fx": abs(s - 1) * f, "fy": abs(s - 1) * f}} if with_std else model.to_dict()
    cam_ref = pose_from_corners(ids, uv, model, sim.plate)
    res = reference(model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, cam_ref=cam_ref,
                    sigma_t_mm=sim.cfg.sigma_t_mm, mc_samples=100, model_dict=doc)
    err = rob_H_cam_error(res.rob_H_cam, sim.world.rob_H_cam)["t_z_mm"]
    assert err > 0.2 * abs(s - 1) / 0.01 * 0.3 * 0.5  # the degeneracy is real: ~0.3 mm per 1 % here
    sigma_z = float(res.uncertainty.std_t_mm[2])
    assert res.verdict == "warn" or err <= 3 * sigma_z, (res.verdict, err, sigma_z, res.messages)


def test_check_rejects_mismatched_inputs():
    model = CameraModel(np.array([[470.0, 0, 500], [0, 470.0, 375], [0, 0, 1]]), np.zeros(5), (1000, 750))
    with pytest.raises(ValueError, match="need >= 8 matching corners"):
        check_camera_model(model, np.zeros((5, 3)), np.zeros((4, 2)), np.eye(4))


def test_runaway_refit_only_notes_that_it_cannot_vouch():
    """Corners no focal length explains (a random scatter) give no finding against the model, only a note."""
    model = CameraModel(np.array([[470.0, 0, 500], [0, 470.0, 375], [0, 0, 1]]), np.zeros(5), (1000, 750))
    rng = np.random.default_rng(3)
    obj = np.column_stack([rng.uniform(0, 30, 40), rng.uniform(0, 20, 40), np.zeros(40)])
    H = np.eye(4)
    H[:3, 3] = [-15.0, -10.0, 30.0]
    mc = check_camera_model(model, obj, rng.uniform(0, 1000, (40, 2)), H)
    assert mc.focal.significance == 0 and not np.isfinite(mc.focal.sigma)
    assert not any("focal length is" in m for m in mc.messages)
    assert any(m.startswith("camera model (note): no focal length") for m in mc.messages), mc.messages
    d = mc.to_dict()  # JSON-safe: the refit's infinite σ is null, not Infinity
    assert d["focal_refit"]["sigma"] is None and d["focal_refit"]["scale"] == 1.0
    json.dumps(d, allow_nan=False)
