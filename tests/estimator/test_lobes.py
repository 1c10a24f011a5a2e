"""The lobe families' derivatives (estimator/lobes.py) against finite differences of the physics module's shapes."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.estimator.lobes import FAMILIES, radiance_and_log_derivatives
from nearlight.physics.reflectance import brdf_shape, peak_shape

ROUGHNESS = {"torrance_sparrow": 0.12, "ward": 0.17, "beckmann": 0.17, "ggx": 0.24}


def _F(model, c, cos_i, cos_r, a):
    return brdf_shape(model, cos_i, cos_r, np.arccos(c), a) * cos_i


@pytest.mark.parametrize("model", FAMILIES)
def test_log_derivatives_match_central_differences(model, rng):
    # geometry inside the lobe and away from grazing (cos ≥ 0.3), where the
    # central differences (step 1e-6) are accurate to ~1e-8 relative; the
    # Beckmann Smith term switches branch at a = 1.6 (its derivative jumps
    # there), so no sample sits within a step of it
    n = 200
    c = rng.uniform(0.93, 0.9999, n)
    cos_i, cos_r = rng.uniform(0.3, 0.99, n), rng.uniform(0.3, 0.99, n)
    a = ROUGHNESS[model]
    F, d_c, d_i, d_a = radiance_and_log_derivatives(model, cos_i, cos_r, np.arccos(c), a)
    np.testing.assert_allclose(F, _F(model, c, cos_i, cos_r, a), rtol=1e-12)
    h = 1e-6
    num_c = (_F(model, c + h, cos_i, cos_r, a) - _F(model, c - h, cos_i, cos_r, a)) / (2 * h) / F
    num_i = (_F(model, c, cos_i + h, cos_r, a) - _F(model, c, cos_i - h, cos_r, a)) / (2 * h) / F
    num_a = (_F(model, c, cos_i, cos_r, a + h) - _F(model, c, cos_i, cos_r, a - h)) / (2 * h) / F
    scale_c = np.max(np.abs(num_c))
    np.testing.assert_allclose(d_c, num_c, rtol=1e-6, atol=1e-7 * scale_c)
    np.testing.assert_allclose(d_i, num_i, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(d_a, num_a, rtol=1e-6, atol=1e-7 * np.max(np.abs(num_a)))


@pytest.mark.parametrize("model", FAMILIES)
def test_log_derivative_in_c_is_finite_at_the_mirror_direction(model):
    # at α = 0 (c = 1) every family is smooth in c: a finite derivative, the
    # one-sided difference's limit
    one = np.ones(1)
    _, d_c, _, _ = radiance_and_log_derivatives(model, 0.8 * one, 0.8 * one, np.zeros(1), ROUGHNESS[model])
    a = ROUGHNESS[model]
    h = 1e-7
    num = (np.log(_F(model, one, 0.8 * one, 0.8 * one, a)) - np.log(_F(model, one - h, 0.8 * one, 0.8 * one, a))) / h
    assert np.isfinite(d_c[0]) and d_c[0] == pytest.approx(num[0], rel=1e-4)


def test_peak_shape():
    # head-on: TS 1; Ward and the microfacets 1 / (4π a²) (D = 1/(π a²), G1 = 1)
    assert peak_shape("torrance_sparrow", 0.1) == pytest.approx(1.0)
    for model in ("ward", "ggx", "beckmann"):
        assert peak_shape(model, 0.2) == pytest.approx(1.0 / (4 * np.pi * 0.04), rel=1e-12)
