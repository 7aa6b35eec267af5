"""Kabsch plate fit: exactness, proper rotations, residuals and nest-label checks."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.frames import apply_H, make_H, rot_x, rot_y, rot_z
from calibration.registration import describe_permutation, fit_plate, kabsch


def random_H(rng: np.random.Generator, scale: float = 1000.0) -> np.ndarray:
    R = rot_z(rng.uniform(-np.pi, np.pi)) @ rot_y(rng.uniform(-1, 1)) @ rot_x(rng.uniform(-np.pi, np.pi))
    return make_H(R, rng.uniform(-scale, scale, 3))


def triangle(side: float = 400.0, skew: float = 0.0) -> np.ndarray:
    """Nest centres in a plane z = 0 (an up-facing SCS); skew breaks the symmetry."""
    r = side / np.sqrt(3)
    a = np.radians([90.0, 210.0 + skew, 330.0])
    return np.column_stack([r * np.cos(a), r * np.sin(a), np.full(3, 19.05)])


def test_kabsch_exact_and_proper_for_random_poses():
    rng = np.random.default_rng(1)
    for _ in range(50):
        H = random_H(rng)
        A = rng.normal(size=(3, 3)) * 200
        fit = kabsch(A, apply_H(H, A))
        assert np.abs(fit.B_H_A - H).max() < 1e-9
        assert abs(np.linalg.det(fit.B_H_A[:3, :3]) - 1) < 1e-12
        assert fit.rms < 1e-9


def test_kabsch_noisy_coplanar_points_never_reflect():
    """Three points are rank 2: without the sign fix half the noisy fits would reflect."""
    rng = np.random.default_rng(2)
    A = triangle()
    for _ in range(200):
        H = random_H(rng)
        B = apply_H(H, A) + rng.normal(0, 0.01, size=(3, 3))
        fit = kabsch(A, B)
        assert np.linalg.det(fit.B_H_A[:3, :3]) > 0.999999
        assert fit.rms < 0.1
        # rotation close to the truth (σ/L ≈ 25 µrad)
        assert np.abs(fit.B_H_A[:3, :3] - H[:3, :3]).max() < 5e-4


def test_kabsch_residuals_and_rms():
    rng = np.random.default_rng(3)
    A = triangle()
    H = random_H(rng)
    noise = rng.normal(0, 0.02, size=(3, 3))
    fit = kabsch(A, apply_H(H, A) + noise)
    assert np.allclose(fit.residuals, apply_H(H, A) + noise - apply_H(fit.B_H_A, A))
    assert fit.rms == pytest.approx(np.sqrt(np.mean(np.sum(fit.residuals ** 2, axis=1))))
    # residuals of a least-squares rigid fit sum to zero (the centroids match)
    assert np.abs(fit.residuals.sum(axis=0)).max() < 1e-9


def test_kabsch_rejects_collinear_and_bad_shapes():
    A = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    with pytest.raises(CalibrationError, match="collinear"):
        kabsch(A, A)
    with pytest.raises(ValueError, match="A_P"):
        kabsch(np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        kabsch(np.full((3, 3), np.nan), np.zeros((3, 3)))


def _plate_case(seed: int, skew: float = 0.0, sigma: float = 0.01):
    rng = np.random.default_rng(seed)
    scn = triangle(skew=skew)
    H = random_H(rng)
    ab = apply_H(H, scn) + rng.normal(0, sigma, size=(3, 3))
    up = H[:3, 2]  # SCS z in ACS: toward the robot
    return scn, ab, H, up


def test_fit_plate_accepts_good_labels_and_reports_residuals():
    scn, ab, H, up = _plate_case(4)
    fit = fit_plate(scn, ab, 0.01, abs_up=up)
    assert np.abs(fit.abs_H_scn[:3, 3] - H[:3, 3]).max() < 0.05
    assert set(fit.residuals_mm) == {"red", "green", "blue"}
    assert fit.rms_mm < 0.03
    # the equilateral triangle cannot verify a cyclic relabelling: it must say so
    assert fit.label_check.startswith("ambiguous")
    d = fit.to_dict()
    assert d["rms_mm"] == fit.rms_mm


def test_fit_plate_unique_labels_for_asymmetric_triangle():
    scn, ab, _, up = _plate_case(5, skew=15.0)
    assert fit_plate(scn, ab, 0.01, abs_up=up).label_check == "unique"


@pytest.mark.parametrize("swap", [(1, 0, 2), (0, 2, 1), (2, 1, 0)])
def test_transposed_labels_detected_on_symmetric_plate(swap):
    scn, ab, _, up = _plate_case(6)
    with pytest.raises(CalibrationError, match="swapped"):
        fit_plate(scn, ab[list(swap)], 0.01, abs_up=up)


@pytest.mark.parametrize("perm", [(1, 0, 2), (1, 2, 0), (2, 0, 1)])
def test_any_relabelling_detected_on_asymmetric_plate(perm):
    scn, ab, _, up = _plate_case(7, skew=15.0)
    with pytest.raises(CalibrationError, match="swapped"):
        fit_plate(scn, ab[list(perm)], 0.01, abs_up=up)


def test_swap_message_names_the_swap():
    scn, ab, _, up = _plate_case(8, skew=15.0)
    with pytest.raises(CalibrationError, match="red<->green"):
        fit_plate(scn, ab[[1, 0, 2]], 0.01, abs_up=up)


def test_large_residual_without_better_labelling_raises():
    scn, ab, _, up = _plate_case(9, skew=15.0)
    ab[0] += [0.5, 0.0, 0.0]  # one nest measured 0.5 mm off
    with pytest.raises(CalibrationError, match="no relabelling fits"):
        fit_plate(scn, ab, 0.01, abs_up=up)


def test_upside_down_plate_detected_without_swap():
    scn, ab, _, up = _plate_case(10, skew=15.0)
    with pytest.raises(CalibrationError, match="upside down"):
        fit_plate(scn, ab, 0.01, abs_up=-up)


def test_describe_permutation():
    assert describe_permutation((0, 1, 2)) == "as labelled"
    assert describe_permutation((0, 2, 1)) == "green<->blue"
    assert describe_permutation((1, 2, 0)) == "red->green->blue->red"


def test_fit_plate_bad_sigma():
    scn, ab, _, up = _plate_case(11)
    with pytest.raises(ValueError, match="sigma_mm"):
        fit_plate(scn, ab, 0.0, abs_up=up)


def test_kabsch_many_is_kabsch_for_each_set_with_the_same_checks():
    from calibration.registration import kabsch_many

    rng = np.random.default_rng(7)
    A = np.array([triangle(skew=s) + rng.normal(0, 0.01, (3, 3)) for s in range(20)])
    B = np.array([apply_H(random_H(rng), a) + rng.normal(0, 0.01, (3, 3)) for a in A])
    H = kabsch_many(A, B)
    assert np.allclose(H, [kabsch(a, b).B_H_A for a, b in zip(A, B)], atol=1e-9)
    line = np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]])
    with pytest.raises(CalibrationError, match="collinear"):
        kabsch_many(np.array([A[0], line]), B[:2])
    with pytest.raises(ValueError, match="non-finite"):
        kabsch_many(A[:1], np.full((1, 3, 3), np.nan))
