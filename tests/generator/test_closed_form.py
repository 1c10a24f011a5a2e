"""The closed-form renderer (generator/closed_form.py) against Mitsuba, pixel by pixel, and against limit cases.

Golden values: Mitsuba's own renders of the same scene files (``render_clean``, 96×72, one pixel-centre sample,
exact for direct light), channel by channel: the specular and diffuse truth images, the full S0, S1, S2 and the
specular phase. Both compute the same physics; what separates them is Mitsuba's float32 arithmetic (a few
hundred float32 operations per pixel: ~1e-5 relative, measured 0.2–12e-6 median, p99 ≤ 9.6e-5 over these scenes
on an Intel Xeon, 2026-12-07). Bounds: median ≤ 1e-4 and 99th percentile ≤ 1e-3 relative error over the pixels
above 1 % of the channel's peak, largest absolute error ≤ 1e-4 of the S0 peak, the same object mask and P within
1e-5 m, and the phase within 1e-3° where the specular is above a tenth of its peak: ten times the float32
spread, and far inside the issue's acceptance (0.5 % median, 3 % p99, 0.05°), so that a wrong sign or a missed
factor (a 1e-3 effect at least) cannot hide. Every scene below is one a study uses: the shipped scenes and the
nuisances, lobes, polarization modes and textures the sweeps vary.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nearlight.errors import UserError
from nearlight.generator import load_scene
from nearlight.generator.closed_form import (
    QUADRATURE_RTOL,
    closed_form_arrays,
    fresnel_amplitudes,
    not_covered,
    reflected_states,
    render_closed_form,
)
from nearlight.physics.polarization import specular_aolp

SCENES = Path(__file__).resolve().parents[2] / "scenes"
SMALL = {"camera.resolution": [96, 72]}

#: (scene file, overrides): every covered object, lobe family, polarization mode and lamp nuisance.
CASES = {
    "ts-board": ("ts_board.yaml", {}),
    "ward-board-fresnel": ("ward_board.yaml", {"material.polarization": "fresnel"}),
    "sphere": ("sphere.yaml", {}),
    "cylinder-body-highlight": ("cylinder.yaml", {"lamp.position": [0.06, -0.30, 0.06]}),
    "bookend-shadowed": ("bookend.yaml", {}),
    "bookend-fresnel-extinction": ("bookend.yaml", {"material.polarization": "fresnel",
                                                    "lamp.polarizer_extinction_ratio": 5.0}),
    "board-beam-extinction": ("ts_board.yaml", {"lamp.polarizer_extinction_ratio": 20.0, "lamp.anisotropy_k": 4.0}),
    "board-tilted-beam-fresnel": ("ts_board.yaml", {"lamp.anisotropy_k": 3.0, "lamp.anisotropy_axis": [0.0, -0.3, -1.0],
                                                    "material.polarization": "fresnel", "material.eta": 1.7}),
    "board-texture": ("ts_board.yaml", {"material.texture": {"period_m": 0.03, "kd_contrast": 0.5,
                                                             "roughness_contrast": 0.4}}),
    "two-lamps": ("two_lamps.yaml", {}),
    "board-jittered-camera": ("ts_board.yaml", {"camera.jitter_px": 0.5, "capture.seed": 3}),
    "sphere-ggx": ("sphere.yaml", {"material": {"model": "ggx", "ks": [0.5, 0.4, 0.3], "alpha": 0.15,
                                                "kd": [0.2, 0.2, 0.2]}}),
    "sphere-beckmann-fresnel": ("sphere.yaml", {"material": {"model": "beckmann", "ks": [0.5, 0.4, 0.3], "alpha": 0.15,
                                                             "kd": [0.2, 0.2, 0.2], "polarization": "fresnel"}}),
}  # fmt: skip


def _phase(S1: np.ndarray, S2: np.ndarray) -> np.ndarray:
    return 0.5 * np.arctan2(S2, S1)


@pytest.fixture(scope="module", params=sorted(CASES))
def pair(request):
    from nearlight.generator import render_clean

    name, over = CASES[request.param]
    scene = load_scene(SCENES / name, overrides={**SMALL, **over})
    return render_clean(scene, progress=False), render_closed_form(scene)


@pytest.mark.render
def test_geometry_matches_mitsuba(pair):
    mitsuba, closed = pair
    assert np.array_equal(mitsuba.surface_mask, closed.surface_mask)
    m = mitsuba.surface_mask
    assert np.abs(mitsuba.P[m] - closed.P[m]).max() < 1e-5  # metres; float32 hit points at ~0.5 m
    assert np.abs(mitsuba.N[m] - closed.N[m]).max() < 1e-3  # Mitsuba's cylinder normals: float32 from the hit


@pytest.mark.render
@pytest.mark.parametrize("channel", ["truth_specular", "truth_diffuse", "S0", "S1", "S2"])
def test_every_channel_matches_mitsuba(pair, channel):
    mitsuba, closed = pair
    m = mitsuba.surface_mask
    got, ref = closed.extra[channel][m], mitsuba.extra[channel][m]
    peak = np.abs(mitsuba.extra["S0"][m]).max()
    assert np.abs(got - ref).max() <= 1e-4 * peak
    big = np.abs(ref) > 1e-2 * np.abs(ref).max()
    if big.any():
        rel = np.abs(got - ref)[big] / np.abs(ref)[big]
        assert np.median(rel) <= 1e-4 and np.percentile(rel, 99) <= 1e-3, (np.median(rel), np.percentile(rel, 99))
    np.testing.assert_allclose(closed.stack[:, m], mitsuba.stack[:, m], rtol=0, atol=1e-4 * peak)  # the analyzer stack


@pytest.mark.render
def test_specular_phase_matches_mitsuba(pair):
    mitsuba, closed = pair
    spec = mitsuba.extra["truth_specular"].sum(-1)
    bright = mitsuba.surface_mask & (spec > 0.1 * spec.max())
    assert bright.sum() >= 10, "each case's specular is in view"
    d = _phase(closed.extra["S1"], closed.extra["S2"]) - _phase(mitsuba.extra["S1"], mitsuba.extra["S2"])
    d = np.degrees(np.angle(np.exp(2j * d[bright])) / 2)
    assert np.abs(d).max() <= 1e-3


@pytest.mark.render
def test_the_capture_is_mitsubas_but_for_its_renderer():
    """Same truth, rig and metadata as Mitsuba's capture; the generator record names the renderer."""
    from nearlight.generator import render_clean

    scene = load_scene(SCENES / "ts_board.yaml", overrides=SMALL)
    mitsuba, closed = render_clean(scene, progress=False), render_closed_form(scene)
    assert closed.truth == mitsuba.truth and closed.rig == mitsuba.rig
    assert closed.meta["generator"]["renderer"] == "closed-form" and "renderer" not in mitsuba.meta["generator"]
    assert closed.meta["generator"]["render_key"] != mitsuba.meta["generator"]["render_key"]
    np.testing.assert_allclose(closed.camera.to_world, mitsuba.camera.to_world, atol=1e-6)


# --------------------------------------------------------------------------- limit cases, no Mitsuba


def test_fresnel_amplitudes_limit_cases():
    eta = 1.5
    rs, rp = fresnel_amplitudes(np.array([1.0]), eta)
    assert rs[0] == pytest.approx((eta - 1) / (eta + 1)) and rp[0] == pytest.approx((eta - 1) / (eta + 1))
    brewster = np.cos(np.arctan(eta))
    assert fresnel_amplitudes(np.array([brewster]), eta)[1][0] == pytest.approx(0.0, abs=1e-12)
    # the intensity reflectances are Fresnel's: Rs = sin²(θi − θt)/sin²(θi + θt), Rp = tan²(θi − θt)/tan²(θi + θt)
    ti = np.radians(np.array([10.0, 40.0, 70.0, 85.0]))
    tt = np.arcsin(np.sin(ti) / eta)
    rs, rp = fresnel_amplitudes(np.cos(ti), eta)
    np.testing.assert_allclose(rs**2, np.sin(ti - tt) ** 2 / np.sin(ti + tt) ** 2, rtol=1e-12)
    np.testing.assert_allclose(rp**2, np.tan(ti - tt) ** 2 / np.tan(ti + tt) ** 2, rtol=1e-12)
    assert rp[-1] < 0 < rp[0]  # beyond Brewster's angle the p field turns over


def test_ideal_mirror_is_speculars_one_home_phase():
    """The ideal mode's reflected field has the angle physics.polarization.specular_aolp computes (measured against
    renders there), at every pixel of a board seen obliquely; fresnel mode turns it by degrees."""
    scene = load_scene(SCENES / "ts_board.yaml", overrides=SMALL)
    arrays = closed_form_arrays(scene)
    m = np.isfinite(arrays["P"]).all(-1)
    S = arrays["stokes_specular"][..., 0]
    lamp, up = scene.lamp, arrays["to_world"][:3, 1]
    want = specular_aolp(arrays["P"][m], scene.camera.position, up, lamp.position, lamp.polarizer_axis,
                         scene.object.position)  # fmt: skip
    lit = S[0][m] > 1e-6 * S[0][m].max()
    d = np.angle(np.exp(2j * (_phase(S[1][m], S[2][m]) - want)))[lit] / 2
    assert np.degrees(np.abs(d)).max() < 1e-4  # the Stokes images are float32: atan2 of them to ~1e-6°
    fresnel = closed_form_arrays(load_scene(SCENES / "ts_board.yaml", overrides={**SMALL,
                                                                                  "material.polarization": "fresnel"}))
    F = fresnel["stokes_specular"][..., 0]
    turn = np.degrees(np.abs(np.angle(np.exp(2j * (_phase(F[1][m], F[2][m]) - want)))[lit] / 2))
    assert turn.max() > 1.0  # the test above could see a Fresnel mode that did nothing


def test_a_mirror_keeps_the_energy_and_a_field_normal_to_the_view():
    rng = np.random.default_rng(3)
    k = rng.normal(size=(500, 3))
    k /= np.linalg.norm(k, axis=1, keepdims=True)
    v = rng.normal(size=(500, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    e = np.cross(k, rng.normal(size=(500, 3)))
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    (out, w), = reflected_states(k, v, [(e, 0.5)], fresnel_eta=None)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.sum(out * v, axis=1), 0.0, atol=1e-12)
    assert np.all(w == 0.5)
    # unpolarized light (two orthogonal states of equal weight) keeps its energy through the normalised Fresnel
    # matrix (M00 = 1), however the states lie
    f = np.cross(k, e)
    states = list(reflected_states(k, v, [(e, 0.5), (f, 0.5)], fresnel_eta=1.5))
    total = sum(w * np.sum(o * o, axis=1) for o, w in states)
    np.testing.assert_allclose(total, 1.0, rtol=1e-12)


@pytest.mark.parametrize("over, reason", [
    ({"object": {"type": "torus"}}, "object.type torus"),
    ({"material": {"model": "mitsuba", "bsdf": {"type": "diffuse"}}}, "material.model mitsuba"),
])  # fmt: skip
def test_what_it_does_not_cover_is_named(over, reason):
    scene = load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, **over})
    assert any(line.startswith(reason) for line in not_covered(scene)), not_covered(scene)
    with pytest.raises(UserError, match=reason):
        closed_form_arrays(scene)


def test_interreflections_are_mitsubas_only_where_the_object_is_concave():
    assert not not_covered(load_scene(SCENES / "sphere.yaml", overrides={**SMALL, "capture.max_depth": 4}))
    concave = load_scene(SCENES / "bookend.yaml", overrides={**SMALL, "capture.max_depth": 4})
    assert not_covered(concave) == ["capture.max_depth 4: interreflections of a concave object (Monte Carlo)"]


def test_a_camera_that_sees_nothing_and_a_lamp_inside_are_one_line():
    away = load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "camera.look_at": [0.0, -1.0, 0.55]})
    with pytest.raises(UserError, match="camera: sees no part of the object"):
        closed_form_arrays(away)
    inside = load_scene(SCENES / "sphere.yaml", overrides={**SMALL, "lamp.position": [0.0, 0.01, 0.0]})  # r = 5 cm
    with pytest.raises(UserError, match="lamp.position: .* is inside the object"):
        closed_form_arrays(inside)


# --------------------------------------------------------------------------- sphere lamps


def _sphere_lamp(name: str, radius: float, **over) -> dict:
    return closed_form_arrays(load_scene(SCENES / name, overrides={**SMALL, "lamp.radius": radius, **over}))


def test_a_sphere_lamp_shrinks_to_the_point_lamp():
    """As a → 0 the sphere lamp's image tends to the point lamp's, the difference falling as a² (the cone's
    half-angle squared): 2.7e-5 of the peak at 1 mm and 2.8e-7 at 0.1 mm, 0.45 m from the board."""
    point = closed_form_arrays(load_scene(SCENES / "ts_board.yaml", overrides=SMALL))
    m = np.isfinite(point["P"]).all(-1)
    ref = point["stokes_specular"][:, m]
    gaps = [np.abs(_sphere_lamp("ts_board.yaml", a)["stokes_specular"][:, m] - ref).max() / np.abs(ref).max()
            for a in (1e-3, 1e-4)]
    assert gaps[0] < 1e-4 and gaps[1] < 1e-6
    assert 50 < gaps[0] / gaps[1] < 200  # a² (100) over a decade of radius


def test_a_sphere_lamp_lights_a_lambertian_surface_as_its_centre_would():
    """A uniform spherical source wholly above a surface point's horizon gives it the irradiance of a point source
    of the same intensity at its centre (Lambert's sphere; the filter's S0 is the same along every direction): the
    diffuse image of a 5 cm lamp equals the point lamp's to the quadrature's tolerance."""
    point = closed_form_arrays(load_scene(SCENES / "ts_board.yaml", overrides=SMALL))
    big = _sphere_lamp("ts_board.yaml", 0.05)
    m = np.isfinite(point["P"]).all(-1)
    ref = point["stokes_diffuse"][0][m]
    assert np.abs(big["stokes_diffuse"][0][m] - ref).max() <= 2 * QUADRATURE_RTOL * ref.max()
    assert big["quadrature_error"][0] <= QUADRATURE_RTOL
    assert np.abs(big["stokes_specular"][:, m] - point["stokes_specular"][:, m]).max() > 1e-3 * ref.max()  # it blurs


@pytest.mark.render
@pytest.mark.parametrize("name, radius", [("ts_board.yaml", 0.02), ("sphere.yaml", 0.03), ("bookend.yaml", 0.02)])
def test_a_sphere_lamp_agrees_with_mitsubas_monte_carlo(name, radius):
    """Mitsuba samples the same cone by Monte Carlo (16 spp × 64 lamp samples at 64×48): per pixel the two differ by
    its noise (measured median 0.3–1.4 % on bright specular pixels), so the test is of bias: over the bright pixels
    of each channel the mean relative difference is within 4 standard errors of zero (a 1 % bias would stand at
    about 5), and the median within the noise's 3 %."""
    from nearlight.generator import render_clean

    over = {"camera.resolution": [64, 48], "lamp.radius": radius, "lamp.samples": 64}
    closed = render_closed_form(load_scene(SCENES / name, overrides=over))
    mitsuba = render_clean(load_scene(SCENES / name, overrides={**over, "capture.spp": 16}), progress=False)
    m = mitsuba.surface_mask
    for channel in ("truth_specular", "truth_diffuse", "S1", "S2"):
        ref, got = mitsuba.extra[channel][m], closed.extra[channel][m]
        bright = np.abs(ref) > 0.1 * np.abs(ref).max()
        rel = (got - ref)[bright] / np.abs(ref)[bright]
        assert len(rel) > 50, channel
        assert abs(rel.mean()) <= 4 * rel.std() / np.sqrt(len(rel)), (channel, rel.mean(), rel.std())
        assert np.median(np.abs(rel)) <= 0.03, channel
    assert closed.meta["generator"]["quadrature_error"][0] <= QUADRATURE_RTOL


def test_a_sphere_lamp_that_reaches_the_object_is_one_line():
    with pytest.raises(UserError, match=r"lamp.radius: 0.5 m reaches the object"):  # the lamp is 0.45 m up
        _sphere_lamp("ts_board.yaml", 0.5)
