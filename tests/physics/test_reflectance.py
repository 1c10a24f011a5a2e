"""Closed-form reflectance: hand-computed goldens and symmetries."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.physics.reflectance import (
    LOBES,
    beckmann_distribution,
    brdf_shape,
    diffuse_radiance,
    ggx_distribution,
    mirror_direction,
    normalize,
    shading_geometry,
    smith_g1,
    specular_radiance,
    ts_sigma,
)

TS = {"model": "torrance_sparrow", "ks": [0.2, 0.4, 0.8], "sigma": 0.1}
WARD = {"model": "ward", "rho_s": [0.05, 0.1, 0.2], "alpha": 0.15}
GGX = {"model": "ggx", "ks": [0.3, 0.2, 0.1], "alpha": 0.12}
BECKMANN = {"model": "beckmann", "ks": [0.3, 0.2, 0.1], "alpha": 0.12}
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


@pytest.mark.parametrize("bsdf", [TS, WARD, GGX, BECKMANN], ids=["ts", "ward", "ggx", "beckmann"])
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


@pytest.mark.parametrize("ndf", [ggx_distribution, beckmann_distribution], ids=["ggx", "beckmann"])
@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.6])
def test_microfacet_distribution_is_normalised(ndf, alpha):
    # ∫ D(θ) cos θ dω = 2π ∫ D(θ) cos θ sin θ dθ = 1 over the hemisphere; with
    # u = tan θ (dθ = du / (1 + u²)) the integrand is smooth on [0, ∞); the
    # trapezoid on 400k points up to u = 200 leaves < 1e-4 (GGX's tail beyond
    # u = 200 holds ~α²/200² of the mass).
    u = np.linspace(0.0, 200.0, 400_001)
    theta = np.arctan(u)
    f = ndf(np.cos(theta), alpha) * np.cos(theta) * np.sin(theta) / (1.0 + u * u)
    assert 2.0 * np.pi * np.trapezoid(f, u) == pytest.approx(1.0, abs=1e-4)


def test_beckmann_smith_matches_the_exact_term():
    # Walter et al. 2007: the rational form is within 0.35 % of the exact Smith
    # G1 = 2 / (1 + erf(a) + exp(-a²) / (a √π)), a = 1 / (α tan θ)
    from scipy.special import erf

    cos_t = np.cos(np.linspace(0.01, 1.55, 500))
    alpha = 0.3
    a = cos_t / (alpha * np.sqrt(1.0 - cos_t**2))
    exact = 2.0 / (1.0 + erf(a) + np.exp(-(a**2)) / (a * np.sqrt(np.pi)))
    np.testing.assert_allclose(smith_g1(cos_t, alpha, "beckmann"), exact, rtol=3.5e-3)
    # GGX's closed form against its own Λ: G1 = 1 / (1 + Λ), Λ = (−1 + √(1 + α² tan²θ)) / 2
    lam = (-1.0 + np.sqrt(1.0 + alpha**2 * (1.0 - cos_t**2) / cos_t**2)) / 2.0
    np.testing.assert_allclose(smith_g1(cos_t, alpha, "ggx"), 1.0 / (1.0 + lam), rtol=1e-12)


def test_microfacet_head_on_golden():
    # α = 0, cos = 1 (lamp and camera on the normal): G1 = 1, D = 1 / (π a²) for
    # both distributions, so f = ks / (4 π a²) and L = I/r² · f with r = 2
    cam, lamp = np.array([0, 0, 1.0]), np.array([0, 0, 2.0])
    for bsdf in (GGX, BECKMANN):
        want = 0.25 * np.array(bsdf["ks"]) / (4 * np.pi * 0.12**2)
        np.testing.assert_allclose(specular_radiance(ORIGIN, UP, cam, lamp, 1.0, bsdf), want, rtol=1e-12)


@pytest.mark.parametrize("model", sorted(LOBES))
def test_lobe_width_matches_torrance_sparrow_at_small_roughness(model):
    # at small roughness every lobe's shape near its peak is exp(−α² / 2σ²) with
    # σ = ts_sigma(model, roughness): the log-shape's curvature in α at α = 0,
    # taken by finite differences at cos θi = cos θr = 1; the O(a²) corrections
    # (the 1/cos⁴ of the distributions, tan² against α²) stay below 2 % at a
    # σ of 0.01 rad
    sigma = 0.01
    roughness = sigma / ts_sigma(model, 1.0)
    h = 1e-4
    alpha = np.array([0.0, h])
    logf = np.log(brdf_shape(model, np.ones(2), np.ones(2), alpha, roughness))
    curvature = -2.0 * (logf[1] - logf[0]) / h**2  # = 1 / σ² for exp(−α²/2σ²)
    assert 1.0 / np.sqrt(curvature) == pytest.approx(sigma, rel=0.02)


@pytest.mark.parametrize("model", sorted(LOBES))
def test_convert_bsdf_keeps_the_peak_and_round_trips(model):
    # head-on (α = 0, both cosines 1) the converted lobe reflects exactly what the
    # Torrance–Sparrow one does; converting back gives the original dict (float rounding)
    from nearlight.physics.reflectance import convert_bsdf

    cam, lamp = np.array([0, 0, 1.0]), np.array([0, 0, 2.0])
    ts = {**TS, "kd": [0.1, 0.1, 0.1]}
    other = convert_bsdf(ts, model)
    assert other["kd"] == ts["kd"] and other["model"] == model
    np.testing.assert_allclose(specular_radiance(ORIGIN, UP, cam, lamp, 1.0, other),
                               specular_radiance(ORIGIN, UP, cam, lamp, 1.0, ts), rtol=1e-12)
    back = convert_bsdf(other, "torrance_sparrow")
    np.testing.assert_allclose(back["ks"], ts["ks"], rtol=1e-12)
    assert back["sigma"] == pytest.approx(ts["sigma"], rel=1e-12)


def test_mitsuba_ts_sigma_of_microfacet_bsdfs():
    from nearlight.physics.reflectance import mitsuba_ts_sigma

    # Beckmann exp(−tan²θ/α²) = exp(−θ²/2σ²) at small θ: σ = α/√2, so α = 0.1·√2 gives σ = 0.1 (closed form);
    # pplastic, roughconductor and roughplastic default to Beckmann in Mitsuba 3
    for kind in ("pplastic", "roughconductor", "roughplastic"):
        assert mitsuba_ts_sigma({"type": kind, "alpha": 0.1 * np.sqrt(2.0)}) == pytest.approx(0.1, rel=1e-12)
    # GGX (α² + tan²θ)⁻² ∝ exp(−2θ²/α²) at small θ: σ = α/2, physics' own GGX width
    ggx = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.2}
    assert mitsuba_ts_sigma(ggx) == pytest.approx(0.1, rel=1e-12) == ts_sigma("ggx", 0.2)
    assert mitsuba_ts_sigma({"type": "pplastic"}) == pytest.approx(0.1 / np.sqrt(2.0))  # Mitsuba's default alpha 0.1
    # no isotropic microfacet roughness: no σ
    for bsdf in ({"type": "diffuse"}, {"type": "conductor"}, {"type": "roughconductor", "alpha_u": 0.1, "alpha_v": 0.2},
                 {"type": "pplastic", "alpha": {"type": "bitmap", "filename": "a.exr"}},
                 {"type": "roughconductor", "distribution": "phong", "alpha": 0.1}):
        assert mitsuba_ts_sigma(bsdf) is None
