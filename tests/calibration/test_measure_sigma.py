"""Issue #20: the mark's stated σ carries the heading term and the tracker's σ at its distance."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.compensation import Compensation, Stop, compensate, fit_heading_sigma
from calibration.frames import make_H, rot_z
from calibration.measure import (CHORD_HEADING_SIGMA_RAD, DEFAULT_SIGMA_T_MM, mark_to_abs, measure_mark,
                                 stated_tracker_sigma, tracker_sigma_mm)
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams
from tests.calibration.test_measure import calibrate


@pytest.fixture(scope="module")
def stop():
    world = World(WorldParams(seed=36))
    sim = Simulation(world, SimConfig(sigma_t_mm=0.0, mark_sigma_px=0.0, seed=36))
    res, scs = calibrate(sim)
    return res, scs, sim.validation().observations[2]


def test_tracker_sigma_is_half_the_mpe_at_the_distance():
    assert tracker_sigma_mm(0.0) == pytest.approx(0.0075, abs=1e-12)  # ½ · 15 µm
    assert tracker_sigma_mm(4900.0) == pytest.approx(0.5 * (0.015 + 0.006 * 4.9), abs=1e-12)  # 22.2 µm
    assert tracker_sigma_mm(4900.0) == pytest.approx(0.0222, abs=1e-6)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="distance"):
            tracker_sigma_mm(bad)
    assert stated_tracker_sigma(0.012, 4900.0) == (0.012, "dataset")
    assert stated_tracker_sigma(None, 4900.0) == (tracker_sigma_mm(4900.0), "distance")
    assert stated_tracker_sigma(None, None) == (DEFAULT_SIGMA_T_MM, "default")


def test_heading_term_grows_with_the_lever_arm_and_matches_a_monte_carlo(stop):
    """σ² gains (σ_ψ·r)², r the mark's horizontal offset from P_at; checked against a seeded Monte Carlo of
    the same mapping with the robot pose turned about the vertical through P_at."""
    res, scs, o = stop
    s_psi = CHORD_HEADING_SIGMA_RAD
    rng = np.random.default_rng(20)
    w, h = scs.size
    levers = []
    for uv in ([w / 2, h / 2], [0.05 * w, 0.05 * h], [0.95 * w, 0.9 * h]):
        base = measure_mark(uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, sigma_t_mm=0.0, sigma_px=0.0)
        m = measure_mark(uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, sigma_t_mm=0.0, sigma_px=0.0,
                         sigma_heading_rad=s_psi)
        assert base.std_mm == 0.0 and base.std_parts_mm["heading"] == 0.0
        r = float(np.linalg.norm((m.abs_P - m.abs_H_rob[:3, 3])[:2]))
        assert m.std_mm == pytest.approx(s_psi * r, rel=1e-4)
        assert m.std_parts_mm["heading"] == pytest.approx(m.std_mm, rel=1e-9)
        H = m.abs_H_rob
        pts = [mark_to_abs(uv, scs, res.rob_H_scn, make_H(rot_z(d) @ H[:3, :3], H[:3, 3]))[0][:2]
               for d in rng.normal(0.0, s_psi, 2000)]
        mc = float(np.sqrt(np.trace(np.cov(np.array(pts).T))))
        assert mc == pytest.approx(m.std_mm, rel=0.06), (mc, m.std_mm)  # 2000 samples: ~1.6 % 1σ
        levers.append((r, m.std_mm))
    r, s = np.array(levers).T
    assert np.ptp(r) > 50.0  # the image's corners lie at different lever arms
    np.testing.assert_allclose(s / r, s_psi, rtol=1e-4)


def test_heading_term_adds_in_quadrature_and_parts_rebuild_std(stop):
    res, scs, o = stop
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-8, 1e-8, 1e-8])
    kw = dict(sigma_t_mm=0.022, sigma_px=0.05, cov_rob_H_scn=cov)
    a = measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, **kw)
    b = measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, sigma_heading_rad=2.5e-4, **kw)
    np.testing.assert_array_equal(a.abs_P, b.abs_P)
    assert b.std_mm ** 2 == pytest.approx(a.std_mm ** 2 + b.std_parts_mm["heading"] ** 2, rel=1e-9)
    assert np.sqrt(sum(v ** 2 for v in b.std_parts_mm.values())) == pytest.approx(b.std_mm, rel=1e-9)
    assert b.to_dict()["std_parts_mm"]["tracker"] > 0
    with pytest.raises(ValueError, match="sigma_heading_rad"):
        measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, sigma_heading_rad=-1e-4)


def test_compensation_states_the_chord_or_the_fits_heading_sigma():
    P_prev, P_at = np.array([0.0, 0.0, 350.0]), np.array([200.0, 0.0, 350.0])
    H = make_H(np.eye(3), [200.0, -30.0, -350.0])  # a rob_H_scn-like pose (plane below the reflector)
    chord = compensate(Compensation(), Stop(P_prev, P_at), H)
    assert (chord.sigma_heading_rad, chord.heading_source) == (CHORD_HEADING_SIGMA_RAD, "chord")
    assert CHORD_HEADING_SIGMA_RAD == pytest.approx(250e-6)
    s = np.linspace(0.0, 200.0, 41)[1:-1]
    kappa = 2 * 0.2 / 200.0 ** 2  # a clear arc: 0.2 mm off the chord's line at the end
    e = kappa * s * (s - 200.0) / 2
    stream = np.column_stack([s, e, np.full_like(s, 350.0)])
    fit = compensate(Compensation(heading_fit=True), Stop(P_prev, P_at, stream=stream), H)
    assert fit.applied == ["heading_fit"] and fit.heading_source == "heading_fit"
    assert 0.0 <= fit.sigma_heading_rad < CHORD_HEADING_SIGMA_RAD
    assert fit_heading_sigma(1e-4, 0.010, 200.0) == pytest.approx(np.sqrt(1e-8 - 2 * (0.010 / 200) ** 2))
    assert fit_heading_sigma(1e-5, 0.010, 200.0) == 0.0  # below the chord's tracker part: nothing to add


def test_a_mark_corrected_by_a_stored_bias_carries_the_bias_own_covariance(stop):
    """The correction's uncertainty is a part of the mark's (GUM §3.2.4): added in ACS, named ``bias``."""
    res, scs, o = stop
    base = measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at)
    C = np.array([[4e-4, 1e-4], [1e-4, 2e-4]])
    m = measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, cov_bias_xy_mm2=C)
    assert m.cov_xy_mm2 == pytest.approx(base.cov_xy_mm2 + C)
    assert m.std_parts_mm["bias"] == pytest.approx(np.sqrt(6e-4)) and "bias" not in base.std_parts_mm
    assert np.array_equal(m.abs_P, base.abs_P)  # a σ, not a move
    with pytest.raises(ValueError, match="cov_bias_xy_mm2 must be a finite 2x2"):
        measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at,
                     cov_bias_xy_mm2=[[np.nan, 0], [0, 1]])
