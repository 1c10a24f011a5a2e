"""Dark pixels' specular from clipped readings (estimator/censored.py): closed forms and calibration."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.estimator.censored import (
    ReadingModel,
    censored_specular,
    level_and_specular,
    reading_model,
    specular_given_level,
)
from nearlight.estimator.noise import camera_noise, censored_pixels
from nearlight.estimator.separation import separate_capture
from nearlight.generator.analytic import analytic_capture
from nearlight.generator.noise import adc_counts, add_camera_noise
from nearlight.generator.scene import NoiseSpec
from nearlight.physics.polarization import analyzer_modulation
from nearlight.physics.reflectance import convert_bsdf

ANGLES = np.array([0.0, 45.0, 90.0, 135.0])
#: bench_lobes' high camera noise: 10 e read noise of a 5000 e full well, 10 bits (a step of ~0.49 read deviations).
HIGH = {"full_well": 5000, "read_noise": 10.0, "bits": 10, "saturation": "auto"}


def test_without_clipping_the_censored_fits_are_least_squares():
    # far from zero and without shot noise every reading is Gaussian of one variance: the
    # likelihood's maximum is the least-squares solution and the information is Σ c² / variance
    rng = np.random.default_rng(0)
    n = 500
    sensor = ReadingModel(gain=0.0, latent_var=0.01**2, step=0.001)
    beta = rng.uniform(0.0, np.pi, n)
    c = analyzer_modulation(ANGLES, beta)
    level = rng.uniform(5.0, 6.0, n)
    R = level + rng.uniform(0.5, 1.0, n) * c + 0.01 * rng.standard_normal(c.shape)
    s, var, ok = specular_given_level(R, c, level, sensor)
    assert ok.all()
    np.testing.assert_allclose(s, np.sum(c * (R - level), 0) / np.sum(c * c, 0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(var, (0.01**2 + 0.001**2 / 12) / np.sum(c * c, 0), rtol=1e-12)
    a, s2, ok2 = level_and_specular(R, c, sensor)
    assert ok2.all()
    X = np.stack([np.ones(len(ANGLES)), c[:, 0]], axis=1)  # one pixel's design, checked on each
    for i in (0, 1, n - 1):
        X[:, 1] = c[:, i]
        want = np.linalg.lstsq(X, R[:, i], rcond=None)[0]
        np.testing.assert_allclose([a[i], s2[i]], want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("level_reads", [0.0, 0.5, 1.0, 2.0])
def test_censored_specular_is_unbiased_and_calibrated_on_the_generators_readings(level_reads):
    # the generator's own ADC (Poisson shot noise, Gaussian read noise, clipping at 0, rounding) at
    # the high noise, a specular of 2 read deviations on a diffuse level of 0-2 of them, the level
    # known: 20 000 draws put the mean normalised error's standard error at 0.007, so its measured
    # 0.004-0.028 (0.0-2.0 read deviations) stays within 0.05, and the spread (0.976-1.009 measured,
    # standard error 0.005) within 5 %. The least-squares specular of the same readings is biased by
    # clipping: -0.36, -0.19, -0.09, -0.01 read deviations (measured)
    noise = NoiseSpec(full_well=5000, read_noise=10.0, bits=10, saturation=1.0)
    gain, step = 1.0 / 5000, 1.0 / 1023
    read = 10.0 * gain
    sensor = ReadingModel(gain, read**2, step)
    rng = np.random.default_rng(1)
    n = 20000
    s_true = 2.0 * read
    c = analyzer_modulation(ANGLES, rng.uniform(0.0, np.pi, n))
    level = level_reads * read + 0.5 * s_true  # a = Id/2 + Is/2
    mu = level + s_true * c
    R = adc_counts(mu, rng.standard_normal(mu.shape), rng.standard_normal(mu.shape), noise=noise, saturation=1.0) * step
    s, var, ok = specular_given_level(R, c, np.full(n, level), sensor)
    assert ok.all()
    z = (s - s_true) / np.sqrt(var)
    assert abs(np.mean(z)) < 0.05
    assert 0.95 < np.std(z) < 1.05
    least_squares = np.sum(c * (R - level), 0) / np.sum(c * c, 0)
    if level_reads == 0.0:
        assert np.mean(least_squares - s_true) < -0.25 * read


def test_reading_model_takes_the_adc_step_out_of_the_stated_read_variance():
    clean = analytic_capture(width=32, height=24, shape="board")
    cap = add_camera_noise(clean, noise=HIGH, seed=0)
    camera = camera_noise(cap)
    sensor = reading_model(cap, camera)
    step = cap.sensor.saturation / 1023
    assert sensor.step == pytest.approx(step, rel=1e-12)
    assert sensor.latent_var == pytest.approx((10.0 * camera.gain) ** 2, rel=1e-9)
    measured = camera_noise(cap.replace(sensor=None))
    assert reading_model(cap.replace(sensor=None), measured) == ReadingModel(measured.gain, measured.read_var, 0.0)


def test_censored_specular_of_a_dark_sphere_is_unbiased_where_the_separation_is_not():
    # bench_lobes' GGX sphere at high noise, 160×120: about half its pixels are dark. Over the lit
    # dark pixel-channels of 6 seeds (specular above a quarter read deviation, ~18 000), measured: the
    # normalised error's mean -0.006 and spread 1.012 (naive standard error 0.007; neighbouring pixels
    # share levels and phases, so 0.03 allows for that); the projected separation on the same pixels,
    # in the same units, -0.055: the bias that kept them out of the fit
    bsdf = convert_bsdf({"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.1}, "ggx")
    clean = analytic_capture(width=160, height=120, bsdf=bsdf, shape="sphere", lamp_position=(0.1, 0.1, 0.6))
    truth = separate_capture(clean, method="fit")[0]
    errors, separated = [], []
    for seed in range(6):
        cap = add_camera_noise(clean, noise=HIGH, seed=seed)
        camera = camera_noise(cap)
        dark = censored_pixels(cap, camera, cap.surface_mask)
        assert dark.sum() > 0.4 * cap.surface_mask.sum()
        out = censored_specular(cap, camera, dark, cap.surface_mask)
        assert out.ok.mean() > 0.97  # the rest have no neighbour with a level
        t = truth[dark]
        lit = out.ok[:, None] & (t > 0.25 * np.sqrt(camera.read_var))
        sd = np.sqrt(out.variance)
        errors.append(((out.values - t) / sd)[lit])
        separated.append(((separate_capture(cap, method="projected")[0][dark] - t) / sd)[lit])
    errors, separated = np.concatenate(errors), np.concatenate(separated)
    assert len(errors) > 15000
    assert abs(np.mean(errors)) < 0.03
    assert 0.95 < np.std(errors) < 1.05
    assert np.mean(separated) < -0.035


def test_censored_specular_of_no_dark_pixel_is_empty():
    clean = analytic_capture(width=32, height=24, shape="board")
    cap = add_camera_noise(clean, noise=HIGH, seed=0)
    out = censored_specular(cap, camera_noise(cap), np.zeros(cap.surface_mask.shape, bool), cap.surface_mask)
    assert out.values.shape == (0, 3) and out.variance.shape == (0, 3) and out.ok.shape == (0,)


def test_the_weighted_fit_reads_the_dark_pixels_it_measured():
    # weighted_fit_pixels puts the dark pixels censored_specular measured back into the fit with their
    # own values and variances (and the phase they were measured along, for several lamps); full
    # reports how many
    from nearlight.estimator import estimate
    from nearlight.estimator.noise import FLOOR
    from nearlight.estimator.observation import observation_of
    from nearlight.estimator.pixels import weighted_fit_pixels

    bsdf = convert_bsdf({"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.1}, "ggx")
    clean = analytic_capture(width=96, height=72, bsdf=bsdf, shape="sphere", lamp_position=(0.1, 0.1, 0.6))
    cap = add_camera_noise(clean, noise=HIGH, seed=0)
    obs = observation_of(cap, separation="projected")
    fit = weighted_fit_pixels(cap, obs, noise="auto", max_pixels=20000, saturation=None)
    camera = camera_noise(cap, surface=obs.surface)
    dark = censored_pixels(cap, camera, obs.surface)  # every surface pixel is fitted at this size
    assert (fit.use | dark).sum() == obs.surface.sum()
    out = censored_specular(cap, camera, dark, obs.surface)
    rows, cols = np.nonzero(dark)
    assert fit.measured.sum() == out.ok.sum() > 0.3 * obs.surface.sum()
    assert not (fit.measured & ~fit.use).any()
    np.testing.assert_array_equal(fit.specular[rows[out.ok], cols[out.ok]], out.values[out.ok])
    np.testing.assert_array_equal(fit.specular[~dark], obs.specular[~dark])  # the rest as separated
    floor = (FLOOR * np.nanmax(np.abs(fit.specular))) ** 2
    np.testing.assert_array_equal(fit.variance(cap, pixels=fit.use)[fit.measured[fit.use]],
                                  np.maximum(out.variance[out.ok], floor))
    np.testing.assert_array_equal(fit.measured_phase, out.phase[out.ok])
    est = estimate(cap, method="full", lobe="ggx")
    assert est.stages["full"]["n_dark_measured"] == fit.measured.sum()
    assert est.stages["full"]["n_pixels"] == fit.use.sum()
