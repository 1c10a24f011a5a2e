"""Separation (paper §2.3) and normals from the range image, on analytic captures."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.errors import UserError
from nearlight.estimator import separate
from nearlight.estimator.normals import normals_from_positions
from nearlight.synthetic import analytic_capture

FOUR = (0.0, 45.0, 90.0, 135.0)
EIGHTEEN = tuple(np.arange(18) * 10.0)


def _truth(capture):
    return capture.extra["truth_specular"].astype(float), capture.extra["truth_diffuse"].astype(float)


@pytest.mark.parametrize("angles", [FOUR, EIGHTEEN, (10.0, 70.0, 130.0)], ids=["4", "18", "3"])
def test_fit_recovers_is_and_id_exactly(angles, rng):
    # β varies per pixel (random phases): the fit must not depend on where β falls.
    beta = rng.uniform(0, 180, (48, 64))
    cap = analytic_capture(width=64, height=48, analyzer_angles_deg=angles, phase_deg=beta)
    spec, diff = separate(cap.stack, cap.analyzer_angles_deg, method="fit")
    ts, td = _truth(cap)
    # float32 stack: relative rounding 6e-8 of the brightest value (≈ 6): atol 1e-5 covers it.
    np.testing.assert_allclose(spec, ts, rtol=0, atol=1e-5)
    np.testing.assert_allclose(diff, td, rtol=0, atol=1e-5)


@pytest.mark.parametrize("angles", [FOUR, EIGHTEEN], ids=["4", "18"])
def test_maxmin_exact_when_samples_hit_the_extrema(angles):
    # β = 90° is one of the sampled angles and β ± 90° too, so max − min is exact.
    cap = analytic_capture(width=64, height=48, analyzer_angles_deg=angles, phase_deg=90.0)
    spec, diff = separate(cap.stack, cap.analyzer_angles_deg, method="maxmin")
    ts, td = _truth(cap)
    np.testing.assert_allclose(spec, ts, rtol=0, atol=1e-5)
    np.testing.assert_allclose(diff, td, rtol=0, atol=1e-5)


def test_maxmin_on_dense_stack_error_bound(rng):
    # Arbitrary β on an 18-angle (10°) stack: the samples nearest β and β + 90° are δ ≤ 5° away
    # (the same δ, since 90° is a multiple of 10°), so Imax = Id/2 + Is cos²δ and
    # Imin = Id/2 + Is sin²δ: specular is low by 2 Is sin²δ ≤ 1.5 % of Is, diffuse high by as much.
    beta = rng.uniform(0, 180, (48, 64))
    cap = analytic_capture(width=64, height=48, analyzer_angles_deg=EIGHTEEN, phase_deg=beta)
    spec, diff = separate(cap.stack, cap.analyzer_angles_deg, method="maxmin")
    ts, td = _truth(cap)
    bound = 2 * np.sin(np.radians(5.0)) ** 2
    assert np.all(spec <= ts + 1e-5)
    assert np.all(ts - spec <= bound * ts + 1e-5)
    np.testing.assert_allclose(diff - td, ts - spec, atol=1e-5)
    bright = ts > 0.1
    assert np.max((ts - spec)[bright] / ts[bright]) > 0.9 * bound  # the bound is reached


def test_separation_needs_enough_angles():
    stack = np.zeros((2, 4, 4, 3))
    with pytest.raises(UserError, match="at least 3 distinct angles"):
        separate(stack, np.array([0.0, 90.0]), method="fit")
    with pytest.raises(UserError, match="at least 2 distinct angles"):
        separate(stack[:1], np.array([0.0]), method="maxmin")
    with pytest.raises(UserError, match="separation: expected one of"):
        separate(stack, np.array([0.0, 90.0]), method="nope")


def test_normals_from_positions_board_exact_sphere_close():
    board = analytic_capture(width=64, height=48)
    N = normals_from_positions(board.P, board.camera.position)
    m = board.surface_mask
    # A plane: every 3x3 window is coplanar, so the fit is exact up to float32 positions.
    np.testing.assert_allclose(N[m], board.N[m], atol=1e-4)
    sphere = analytic_capture(shape="sphere", width=96, height=72)
    N = normals_from_positions(sphere.P, sphere.camera.position)
    m = sphere.surface_mask
    err = np.degrees(np.arccos(np.clip(np.sum(N[m] * sphere.N[m], axis=-1), -1, 1)))
    # Interior pixels: a plane through a 3x3 patch of a sphere is tilted by O(footprint²/R²): < 0.5°.
    # Silhouette pixels see few neighbours at grazing angles and can be far off.
    assert np.median(err) < 0.5
