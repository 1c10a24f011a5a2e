"""Closed-form reflectance: hand-computed goldens and symmetries."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.physics.reflectance import (
    diffuse_radiance,
    mirror_direction,
    normalize,
    shading_geometry,
    specular_radiance,
)

TS = {"model": "torrance_sparrow", "ks": [0.2, 0.4, 0.8], "sigma": 0.1}
WARD = {"model": "ward", "rho_s": [0.05, 0.1, 0.2], "alpha": 0.15}
ORIGIN, UP = np.zeros(3), np.array([0.0, 0.0, 1.0])


def test_head_on_golden():
    # camera 1 m and lamp 2 m straight above: alpha = 0, cos = 1, r = 2, so
    # TS radiance = I/4 * ks (paper eq. 6 with cos θr = 1, exp(0) = 1)
    # Ward radiance = I/4 * rho_s / (4 pi alpha^2) (eq. 19 with tan 0 = 0)
    cam, lamp, intensity = np.array([0, 0, 1.0]), np.array([0, 0, 2.0]), 3.0
    np.testing.assert_allclose(specular_radiance(ORIGIN, UP, cam, lamp, intensity, TS), 0.75 * np.array(TS["ks"]))
    want = 0.75 * np.array(WARD["rho_s"]) / (4 * np.pi * 0.15**2)
    np.testing.assert_allclose(specular_radiance(ORIGIN, UP, cam, lamp, intensity, WARD), want)
    np.testing.assert_allclose(diffuse_radiance(ORIGIN, UP, cam, lamp, intensity, [0.5, 0.5, 0.5]), 0.75 * 0.5 / np.pi)


def test_off_specular_angles_golden():
    # view along +z, light at 60° from the normal: the half vector sits at 30°,
    # so alpha = 30° = pi/6; cos θi = 1/2, cos θr = 1
    cam = np.array([0, 0, 1.0])
    lamp = np.array([np.sin(np.pi / 3), 0, np.cos(np.pi / 3)])
    g = shading_geometry(ORIGIN, UP, cam, lamp)
    assert g.alpha == pytest.approx(np.pi / 6)
    assert g.cos_i == pytest.approx(0.5)
    assert g.cos_r == pytest.approx(1.0)
    # eq. 6: L = (I/r^2) Ks / cos θr exp(-α²/2σ²), r = 1
    want = np.array(TS["ks"]) * np.exp(-((np.pi / 6) ** 2) / (2 * 0.1**2))
    np.testing.assert_allclose(specular_radiance(ORIGIN, UP, cam, lamp, 1.0, TS), want)


@pytest.mark.parametrize("bsdf", [TS, WARD], ids=["ts", "ward"])
def test_brdf_is_reciprocal(rng, bsdf):
    # f(i, r) = f(r, i): recover f = L r² / cos θi for both placements and compare
    P = rng.normal(scale=0.05, size=(50, 3))
    N = normalize(np.array([0, 0, 1.0]) + rng.normal(scale=0.1, size=(50, 3)))
    a, b = np.array([0.1, 0.0, 0.5]), np.array([-0.1, 0.05, 0.4])
    ga, gb = shading_geometry(P, N, a, b), shading_geometry(P, N, b, a)
    fa = specular_radiance(P, N, a, b, 1.0, bsdf) * (ga.r**2 / ga.cos_i)[:, None]
    fb = specular_radiance(P, N, b, a, 1.0, bsdf) * (gb.r**2 / gb.cos_i)[:, None]
    np.testing.assert_allclose(fa, fb, rtol=1e-12)


def test_nothing_reflected_from_behind():
    cam, lamp = np.array([0, 0, 1.0]), np.array([0, 0, -1.0])
    assert np.all(specular_radiance(ORIGIN, UP, cam, lamp, 1.0, TS) == 0)
    assert np.all(diffuse_radiance(ORIGIN, UP, cam, lamp, 1.0, [1, 1, 1]) == 0)


def test_mirror_direction_reflects_the_view(rng):
    N = normalize(rng.normal(size=(20, 3)))
    V = normalize(N + rng.normal(scale=0.5, size=(20, 3)))
    L = mirror_direction(N, V)
    np.testing.assert_allclose(np.linalg.norm(L, axis=-1), 1.0)
    np.testing.assert_allclose(np.sum(N * L, -1), np.sum(N * V, -1))  # θi = θr
    # the half vector of L and V is the normal: alpha = 0
    np.testing.assert_allclose(normalize(L + V), N, atol=1e-12)
