"""Separation (paper §2.3) and normals from the range image, on analytic captures."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.errors import UserError
from nearlight.estimator import separate
from nearlight.generator.analytic import analytic_capture

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


def test_projected_is_exact_for_smooth_phase_and_unbiased_under_noise():
    # Noise-free, β constant (the default 0°): the neighbourhood phase is β exactly.
    cap = analytic_capture(width=64, height=48, analyzer_angles_deg=FOUR, phase_deg=37.0)
    spec, diff = separate(cap.stack, cap.analyzer_angles_deg, method="projected")
    ts, td = _truth(cap)
    np.testing.assert_allclose(spec, ts, atol=1e-5)
    np.testing.assert_allclose(diff, td, atol=1e-5)
    # White noise s on 8 angles: the coefficients b, c have sd s·sqrt(2/8) = s/2, so the "fit"
    # amplitude of a pixel with no specular is Rayleigh with mean (s/2)·sqrt(π/2), i.e. its
    # specular 2·that ≈ 1.25 s; "projected" is unbiased. Over 40 seeds × 1629 dark pixels × 3
    # channels (each sample sd s), the mean's standard error is ≈ s / 440: |mean| < s/20 is a
    # 20 sd bound that still sits 25x below the fit's bias.
    rng = np.random.default_rng(11)
    sharp = {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.03}
    cap = analytic_capture(width=64, height=48, analyzer_angles_deg=tuple(np.arange(8) * 22.5), bsdf=sharp)
    stack = cap.stack.astype(float)
    s = 0.05
    dark = cap.surface_mask & (cap.extra["truth_specular"].max(axis=-1) < 1e-3 * s)
    means = {"fit": [], "projected": []}
    for _ in range(40):
        noisy = stack + rng.normal(0.0, s, stack.shape)
        for method in means:
            means[method].append(separate(noisy, cap.analyzer_angles_deg, method=method)[0][dark].mean())
    assert dark.sum() > 500
    assert np.mean(means["fit"]) == pytest.approx(s * np.sqrt(np.pi / 2), rel=0.05)
    assert abs(np.mean(means["projected"])) < s / 20


def test_separation_needs_enough_angles():
    stack = np.zeros((2, 4, 4, 3))
    with pytest.raises(UserError, match="at least 3 distinct angles"):
        separate(stack, np.array([0.0, 90.0]), method="fit")
    with pytest.raises(UserError, match="at least 2 distinct angles"):
        separate(stack[:1], np.array([0.0]), method="maxmin")
    with pytest.raises(UserError, match="separation: expected one of"):
        separate(stack, np.array([0.0, 90.0]), method="nope")


def test_range_noise_is_measured_from_fourth_differences():
    # the fourth differences of the range measure Gaussian range noise (0.2 mm on a
    # 320×240 board: ~70k runs, so the robust estimate's relative standard error is
    # well under 1 %; 5 % allowed) and are blind to a noise-free sphere's curvature
    # (below 1e-6 m)
    from nearlight.estimator.range_error import range_noise
    from nearlight.generator.noise import add_range_noise

    board = analytic_capture(width=320, height=240)
    noisy = add_range_noise(board, sigma_m=2e-4, seed=0)
    assert range_noise(noisy.P, noisy.camera.position) == pytest.approx(2e-4, rel=0.05)
    sphere = analytic_capture(width=320, height=240, shape="sphere")
    assert range_noise(sphere.P, sphere.camera.position) < 1e-6
