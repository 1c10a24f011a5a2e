"""Rig nuisances: each one against a closed form, off values bit-identical to the code without them.

Clean renders are small (64×48, one pixel-centre sample: exact for direct
light) and shared by the module. Golden values come from the closed forms in
docs/physics.md and docs/scene-files.md ("Nuisances"), each named where used.
"""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.capture import RangeSensor, Rig, read_capture
from nearlight.generator import add_camera_noise, add_range_noise, load_scene, render_clean
from nearlight.generator.analytic import analytic_capture
from nearlight.generator.noise import noise_rngs
from nearlight.generator.nuisances import bilinear_shift, nuisance_rng, nuisances_of, through_rig, range_holes
from nearlight.generator.realism import PROFILES
from nearlight.generator.render import render_key
from nearlight.generator.scene import Nuisances
from nearlight.physics.camera import inverse_response, project, response, vignetting_gain
from nearlight.physics.polarization import analyzer_stack, aolp, linear_stokes

from .test_physics import SCENES, interior

SMALL = {"camera.resolution": [64, 48]}
MIRROR = {**SMALL, "material.kd": [0.0, 0.0, 0.0]}  # ideal polarization, no diffuse: fully polarized light
NOISE = {"full_well": 20000.0, "read_noise": 5.0, "bits": 12, "saturation": "auto"}


def _nz(**sections) -> Nuisances:
    return Nuisances.model_validate(sections)


@pytest.fixture(scope="module")
def mirror():
    scene = load_scene(SCENES / "ts_board.yaml", overrides=MIRROR)
    return scene, render_clean(scene, progress=False)


# --------------------------------------------------------------------------- off means off


def _same(a, b) -> None:
    for name in ("P", "N", "stack", "specular", "diffuse"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)
    assert sorted(a.extra) == sorted(b.extra)
    for k in a.extra:
        np.testing.assert_array_equal(a.extra[k], b.extra[k], err_msg=k)
    np.testing.assert_array_equal(a.camera.position, b.camera.position)


@pytest.mark.parametrize("nuisances", [None, Nuisances()])
def test_every_nuisance_off_is_exactly_camera_then_range_noise(nuisances):
    # The code path before nuisances existed: add_camera_noise, then add_range_noise, with the one seed.
    clean = analytic_capture(width=48, height=36)
    before = add_range_noise(add_camera_noise(clean, noise=NOISE, seed=5), sigma_m=0.001, seed=5)
    after = through_rig(clean, nuisances=nuisances, noise=NOISE, range_noise=0.001, seed=5)
    _same(after, before)
    assert after.rig == before.rig == Rig(range=RangeSensor(sigma_m=0.001, axis="ray", source="renderer"))


def test_off_values_written_explicitly_are_the_scene_without_them():
    plain = load_scene(SCENES / "ts_board.yaml", overrides=SMALL)
    explicit = load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "realism": "none",
        "nuisances": Nuisances().model_dump(mode="json"), "lamp.polarizer_extinction_ratio": None,
        "lamp.anisotropy_k": 0.0, "lamp.anisotropy_axis": None, "lamp.radius": 0.0})  # fmt: skip
    assert explicit == plain and plain.nuisances.off and plain.lamp_is_v1
    assert render_key(explicit) == render_key(plain)


def test_render_key_changes_with_lamp_nuisances_only():
    base = load_scene(SCENES / "ts_board.yaml", overrides=SMALL)
    key = render_key(base)
    # post-render nuisances: one render serves them all
    lamp_off = {"lamp.polarizer_extinction_ratio": None, "lamp.anisotropy_k": 0, "lamp.radius": 0}
    assert render_key(load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "realism": "rough", **lamp_off})) == key
    assert render_key(load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "lamp.anisotropy_k": 2})) != key
    assert render_key(load_scene(SCENES / "ts_board.yaml",
                                 overrides={**SMALL, "lamp.polarizer_extinction_ratio": 300})) != key  # fmt: skip
    assert render_key(load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "lamp.radius": 0.01})) != key
    assert render_key(load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "lamp.samples": 64})) == key  # a point


def test_which_nuisances_draw_from_the_seed():
    from nearlight.generator.nuisances import draws_from_seed

    assert not draws_from_seed(Nuisances())
    assert draws_from_seed(_nz(analyzer={"jitter_deg": 0.1})) and draws_from_seed(_nz(camera={"flicker": 0.01}))
    still = {"realism": "bench", "nuisances.analyzer.jitter_deg": 0, "nuisances.camera.flicker": 0}
    assert not draws_from_seed(load_scene(SCENES / "ts_board.yaml", overrides=still).nuisances)
    clean = analytic_capture(width=16, height=12)
    for nz in (_nz(analyzer={"extinction_ratio": 50, "offset_deg": 1}), _nz(range={"shift_px": [0.5, 0]})):
        assert not draws_from_seed(nz)
        np.testing.assert_array_equal(through_rig(clean, nuisances=nz, seed=1).stack, through_rig(clean, nuisances=nz, seed=2).stack)


def test_the_nuisance_stream_leaves_camera_and_range_noise_streams_alone():
    # SeedSequence children are keyed by their index: spawn(3)'s first two are spawn(2)'s.
    cam, rng_ = noise_rngs(7)
    a, b = (np.random.default_rng(c) for c in np.random.SeedSequence(7).spawn(3)[:2])
    assert np.array_equal(cam.standard_normal(5), a.standard_normal(5))
    assert np.array_equal(rng_.standard_normal(5), b.standard_normal(5))
    assert not np.array_equal(nuisance_rng(7).standard_normal(5), noise_rngs(7)[0].standard_normal(5))


V1_LAMP = "nearlight_lamp_v1_frozen"


def _register_v1_lamp(mi) -> None:
    """The point lamp's emitter exactly as it was before lamp nuisances existed (commit 67bf000), frozen here so the
    off path of today's emitter can be held to it bit for bit on this machine (a render's last bits depend on the CPU,
    so a stored golden image could not be compared across machines)."""
    import drjit as dr

    from nearlight.generator.bsdfs import zero_struct
    from nearlight.physics.polarization import filter_axes

    class FrozenV1Lamp(mi.Emitter):
        def __init__(self, props):
            super().__init__(props)
            self.position = mi.ScalarPoint3f(props.get("position"))
            self.intensity = float(props.get("intensity", 1.0))
            self.absorb = mi.ScalarVector3f(filter_axes(props.get("axis"), props.get("facing"))[1])
            self.m_flags = mi.EmitterFlags.DeltaPosition

        def sample_direction(self, it, sample, active=True):
            ds = zero_struct(mi, mi.DirectionSample3f)
            ds.p, ds.time, ds.pdf, ds.delta = mi.Point3f(self.position), it.time, 1.0, True
            d = ds.p - it.p
            ds.dist = dr.norm(d)
            ds.d = d / ds.dist
            fwd = -ds.d
            absorb = mi.Vector3f(self.absorb)
            transmit = dr.cross(fwd, dr.normalize(absorb - dr.dot(absorb, fwd) * fwd))
            pol = mi.mueller.rotate_mueller_basis_collinear(mi.mueller.linear_polarizer(1.0), fwd, transmit,
                                                            mi.mueller.stokes_basis(fwd))  # fmt: skip
            value = dr.select(active, self.intensity / dr.square(ds.dist), 0.0)
            return ds, mi.Spectrum(pol) * mi.depolarizer(mi.UnpolarizedSpectrum(value))

        def pdf_direction(self, it, ds, active=True):
            return mi.Float(0.0)

        def eval_direction(self, it, ds, active=True):
            return dr.zeros(mi.Spectrum)

        def eval(self, si, active=True):
            return dr.zeros(mi.Spectrum)

    mi.register_emitter(V1_LAMP, lambda props: FrozenV1Lamp(props))


@pytest.mark.render
@pytest.mark.parametrize("channel", [None, 0])
def test_the_lamp_with_every_nuisance_off_renders_bit_for_bit_as_before(channel):
    # The linear path (unit intensity) and the per-channel path (intensity 2, inter-reflection, 2 spp) of the bookend.
    import tempfile
    from pathlib import Path

    from nearlight.generator import render
    from nearlight.generator.llvm import mitsuba

    mi = mitsuba()
    _register_v1_lamp(mi)
    scene = load_scene(SCENES / "bookend.yaml", overrides={"camera.resolution": [48, 36], "capture.max_depth": 3})
    with tempfile.TemporaryDirectory() as scratch:
        d = render.scene_dict(mi, scene, part="full", channel=channel, scratch=Path(scratch))
        now = render.trace_stokes(mi, mi.load_dict(d), spp=2)
        assert d["lamp"]["type"] == "nearlight_lamp" and set(d["lamp"]) == {"type", "position", "intensity", "axis",
                                                                             "facing"}  # fmt: skip
        before = render.trace_stokes(mi, mi.load_dict({**d, "lamp": {**d["lamp"], "type": V1_LAMP}}), spp=2)
    assert now.max() > 0
    np.testing.assert_array_equal(now, before)


# --------------------------------------------------------------------------- analyzer


@pytest.mark.render
@pytest.mark.parametrize("eps", [30.0, 300.0])
def test_analyzer_extinction_ratio_is_malus_with_a_floor_on_a_mirror(mirror, eps):
    # Fully polarized light (an ideal-mode mirror lobe of a polarized lamp) through a polarizer of extinction ratio
    # eps: I(θ) = Imax [cos²(θ − β) + sin²(θ − β)/eps] (Malus's law with a floor), so Imin/Imax = 1/eps.
    scene, clean = mirror
    angles = np.arange(0.0, 180.0, 1.0)
    cap = through_rig(clean.replace(stack=analyzer_stack(np.stack([clean.extra[f"S{i}"] for i in range(3)]), angles),
                                analyzer_angles_deg=angles), nuisances=_nz(analyzer={"extinction_ratio": eps}))  # fmt: skip
    m = interior(clean.surface_mask) & (clean.extra["S0"][..., 0] > 0.05 * clean.extra["S0"][..., 0].max())
    I = cap.stack[:, m, 0].astype(float)
    F = linear_stokes(I, angles)  # the extrema of the fitted cos 2θ curve, not of the 1°-sampled images
    imax, imin = (F[0] + np.hypot(F[1], F[2])) / 2, (F[0] - np.hypot(F[1], F[2])) / 2
    np.testing.assert_allclose(imin / imax, 1 / eps, rtol=1e-4)
    beta = aolp(clean.extra["S1"][m, 0], clean.extra["S2"][m, 0])
    d = np.radians(angles)[:, None] - beta[None]
    malus = imax * (np.cos(d) ** 2 + np.sin(d) ** 2 / eps)
    np.testing.assert_allclose(I, malus, rtol=1e-4, atol=1e-6 * imax.max())
    assert cap.rig.analyzer_extinction_ratio == eps


@pytest.mark.render
def test_analyzer_offset_turns_the_measured_angle_of_polarization(mirror):
    # The rig believes the nominal angles; the filter sits `offset` further on, so the fitted AoLP is β − offset.
    scene, clean = mirror
    cap = through_rig(clean, nuisances=_nz(analyzer={"offset_deg": 10.0}))
    np.testing.assert_array_equal(cap.analyzer_angles_deg, clean.analyzer_angles_deg)
    m = interior(clean.surface_mask) & (clean.extra["S0"][..., 0] > 0.05 * clean.extra["S0"][..., 0].max())
    S = linear_stokes(cap.stack.astype(float), cap.analyzer_angles_deg)
    turned = np.angle(np.exp(2j * (aolp(S[1], S[2])[m] - aolp(clean.extra["S1"], clean.extra["S2"])[m]))) / 2
    np.testing.assert_allclose(np.degrees(turned[..., 0]), -10.0, atol=1e-3)
    assert cap.truth["nuisances"]["analyzer"]["angles_deg"] == (clean.analyzer_angles_deg + 10).tolist()


def test_analyzer_jitter_is_per_shot_from_the_seed():
    clean = analytic_capture(width=24, height=18, analyzer_angles_deg=list(np.arange(0, 180, 0.5)))
    a = through_rig(clean, nuisances=_nz(analyzer={"jitter_deg": 0.5}), seed=3)
    b = through_rig(clean, nuisances=_nz(analyzer={"jitter_deg": 0.5}), seed=3)
    c = through_rig(clean, nuisances=_nz(analyzer={"jitter_deg": 0.5}), seed=4)
    np.testing.assert_array_equal(a.stack, b.stack)
    assert not np.array_equal(a.stack, c.stack)
    actual = np.asarray(a.truth["nuisances"]["analyzer"]["angles_deg"])
    err = actual - clean.analyzer_angles_deg
    np.testing.assert_allclose(err, 0.5 * nuisance_rng(3).standard_normal(len(err)))
    assert abs(err.std() - 0.5) < 0.05  # 360 shots: the std of a std estimate is 0.5/sqrt(720) = 0.019
    S = linear_stokes(clean.stack.astype(float), clean.analyzer_angles_deg)  # the analytic capture is clean: exact
    np.testing.assert_allclose(a.stack, analyzer_stack(S, actual), rtol=1e-5, atol=1e-7)


# --------------------------------------------------------------------------- lamp (rendered)


@pytest.mark.render
def test_lamp_polarizer_extinction_ratio_leaks_the_crossed_light(mirror):
    # A lamp polarizer of extinction ratio eps passes I/2 (1 + 1/eps) of unpolarized light with DoLP
    # (1 − 1/eps)/(1 + 1/eps); an ideal-mode mirror keeps the DoLP, so the specular image has exactly that DoLP and
    # (1 + 1/eps) times the ideal lamp's S0.
    scene, clean = mirror
    eps = 50.0
    leaky = load_scene(SCENES / "ts_board.yaml", overrides={**MIRROR, "lamp.polarizer_extinction_ratio": eps})
    cap = render_clean(leaky, progress=False)
    m = interior(clean.surface_mask) & (clean.extra["S0"][..., 0] > 0.01 * clean.extra["S0"][..., 0].max())
    S0, S1, S2 = (cap.extra[f"S{i}"][m] for i in range(3))
    np.testing.assert_allclose(S0 / clean.extra["S0"][m], 1 + 1 / eps, rtol=1e-5)
    np.testing.assert_allclose(np.hypot(S1, S2) / S0, (eps - 1) / (eps + 1), rtol=1e-5)
    assert cap.rig.lamp_polarizer_extinction_ratio == eps
    assert cap.truth["lamps"][0]["polarizer_extinction_ratio"] == eps


@pytest.mark.render
def test_lamp_anisotropy_is_cos_power_about_its_axis(mirror):
    # I(θ) = I0 cos^k θ, θ from the beam axis: the image is the isotropic one times cos^k of the angle between
    # the axis and the direction from the lamp to each surface point (P), pixel by pixel.
    scene, clean = mirror
    axis = np.array([0.0, -0.3, -1.0])
    beam = load_scene(SCENES / "ts_board.yaml", overrides={**MIRROR, "lamp.anisotropy_k": 3.0,
                                                            "lamp.anisotropy_axis": axis.tolist()})  # fmt: skip
    cap = render_clean(beam, progress=False)
    m = interior(clean.surface_mask) & (clean.extra["S0"][..., 0] > 0.01 * clean.extra["S0"][..., 0].max())
    d = clean.P[m].astype(float) - np.asarray(scene.lamp.position)
    cos = d @ (axis / np.linalg.norm(axis)) / np.linalg.norm(d, axis=-1)
    np.testing.assert_allclose(cap.extra["S0"][m][:, 0] / clean.extra["S0"][m][:, 0], cos**3, rtol=1e-4)
    assert cap.truth["lamps"][0]["anisotropy"]["k"] == 3.0


@pytest.mark.render
def test_a_sphere_lamp_shrinks_to_the_point_lamp():
    # a -> 0: the sampled points of the sphere converge on its centre; at a = 0.1 mm, 0.5 m away, the diffuse image
    # agrees to float32 rounding and the specular one to the lobe's variation over 0.2 mrad (< 1 %).
    base = {**SMALL, "material.kd": [0.3, 0.3, 0.3]}
    point = render_clean(load_scene(SCENES / "ts_board.yaml", overrides=base), progress=False)
    tiny = render_clean(load_scene(SCENES / "ts_board.yaml", overrides={**base, "lamp.radius": 1e-4,
                                                                         "lamp.samples": 4}), progress=False)  # fmt: skip
    m = point.surface_mask
    np.testing.assert_allclose(tiny.extra["truth_diffuse"][m], point.extra["truth_diffuse"][m], rtol=3e-4)
    np.testing.assert_allclose(tiny.extra["truth_specular"][m], point.extra["truth_specular"][m], rtol=1e-2)
    assert tiny.truth["lamps"][0]["radius_m"] == 1e-4


@pytest.mark.render
def test_a_fully_visible_sphere_lamp_gives_the_point_lamps_lambertian_irradiance():
    # Classical result: a uniform sphere wholly above a Lambertian surface's horizon irradiates it exactly like a
    # point lamp of the same intensity at its centre. Monte Carlo over the lamp (64 samples, uniform in solid angle):
    # per-pixel relative noise about 0.2 % at a = 2 cm; the mean over the board is unbiased (bound 5e-4).
    base = {**SMALL, "material.ks": [0.0, 0.0, 0.0], "material.kd": [0.3, 0.3, 0.3]}
    point = render_clean(load_scene(SCENES / "ts_board.yaml", overrides=base), progress=False)
    sphere = render_clean(load_scene(SCENES / "ts_board.yaml", overrides={**base, "lamp.radius": 0.02,
                                                                           "lamp.samples": 64}), progress=False)  # fmt: skip
    m = point.surface_mask
    ratio = sphere.extra["truth_diffuse"][m] / point.extra["truth_diffuse"][m]
    assert abs(ratio.mean() - 1) < 5e-4 and np.percentile(np.abs(ratio - 1), 99) < 0.01
    # the specular highlight of a 2 cm lamp is blurred: lower peak, same place (it is not a point any more)
    spec = render_clean(load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "lamp.radius": 0.02,
                                                                         "lamp.samples": 64}), progress=False)  # fmt: skip
    p0 = render_clean(load_scene(SCENES / "ts_board.yaml", overrides=SMALL), progress=False)
    assert spec.extra["truth_specular"].max() < p0.extra["truth_specular"].max()


# --------------------------------------------------------------------------- surface (rendered)


@pytest.mark.render
@pytest.mark.parametrize("name", ["ts_board.yaml", "ward_board.yaml"])
def test_textured_albedo_and_roughness_follow_the_checker(name):
    # kd(p) = kd (1 + c s(p)) and roughness(p) = sigma (1 + r s(p)), s = ±1 the checker of nearlight.physics.texture
    # at the rendered point: the diffuse image is the untextured one times (1 + c s) (float32 rounding), the specular
    # one the closed form with the roughness of each pixel's cell (the generator's bounds: median 0.5 %, p99 3 %).
    # Pixels within 1 % of a period of a cell seam are left out (P and the BSDF's point differ in the last bits).
    from nearlight.generator.scene import placement
    from nearlight.physics.reflectance import specular_radiance
    from nearlight.physics.texture import cell_margin, checker_sign

    tex = {"period_m": 0.03, "kd_contrast": 0.4, "roughness_contrast": 0.3}
    plain = load_scene(SCENES / name, overrides=SMALL)
    scene = load_scene(SCENES / name, overrides={**SMALL, "material.texture": tex})
    a, b = render_clean(plain, progress=False), render_clean(scene, progress=False)
    frame = placement(scene.object)
    s = checker_sign(a.P, frame, 0.03)
    m = interior(a.surface_mask) & (cell_margin(a.P, frame, 0.03) > 0.01)
    assert (s[m] > 0).sum() > 100 and (s[m] < 0).sum() > 100
    np.testing.assert_allclose(b.extra["truth_diffuse"][m], a.extra["truth_diffuse"][m] * (1 + 0.4 * s[m])[:, None],
                               rtol=1e-5)  # fmt: skip
    truth = dict(b.truth["bsdf"])
    key = "sigma" if truth["model"] == "torrance_sparrow" else "alpha"
    ref = np.zeros_like(b.extra["truth_specular"], dtype=float)
    for sign in (-1.0, 1.0):
        bsdf = {**truth, key: truth[key] * (1 + 0.3 * sign)}
        spec = specular_radiance(a.P, a.N, a.camera.position, scene.lamp.position, np.asarray(scene.lamp.intensity) / 2,
                                 bsdf)  # fmt: skip
        ref[s == sign] = spec[s == sign]
    bright = m & (ref[..., 0] > 1e-3 * ref[..., 0].max())
    rel = np.abs(b.extra["truth_specular"][bright] - ref[bright]) / ref[bright]
    assert np.median(rel) <= 0.005 and np.percentile(rel, 99) <= 0.03, (np.median(rel), np.percentile(rel, 99))
    assert b.truth["bsdf"]["texture"] == {"pattern": "checker", **tex}
    assert render_key(scene) != render_key(plain)


# --------------------------------------------------------------------------- camera


def test_vignetting_and_response_are_exactly_invertible(rng):
    L = rng.uniform(0, 2, size=(3, 48, 64, 3))
    g = vignetting_gain(64, 48, 0.3)
    assert g.max() <= 1 and np.isclose(g.min(), 1 - 0.3 * (31.5**2 + 23.5**2) / (32**2 + 24**2))
    np.testing.assert_allclose(L * g[..., None] / g[..., None], L, rtol=1e-15)
    for gamma in (1.0, 0.45, 2.2):
        np.testing.assert_allclose(inverse_response(response(L, gamma, 2.5), gamma, 2.5), L, rtol=1e-12)
    assert response(L, 2.2, 2.5).max() <= 2.5 and np.allclose(response(np.array([0.0, 2.5]), 2.2, 2.5), [0, 2.5])


def test_camera_nuisances_on_the_recorded_images():
    clean = analytic_capture(width=32, height=24)
    nz = _nz(camera={"vignetting": 0.2, "gamma": 2.2, "flicker": 0.05, "white_balance": [1.2, 1.0, 0.8]})
    cap = through_rig(clean, nuisances=nz, seed=2)
    rec = cap.truth["nuisances"]["camera"]
    gains, white = np.asarray(rec["flicker_gains"]), rec["response_white"]
    np.testing.assert_allclose(gains, 1 + 0.05 * nuisance_rng(2).standard_normal(2 * len(gains))[len(gains):])
    linear = inverse_response(cap.stack.astype(float), 2.2, white)
    expect = clean.stack * gains[:, None, None, None] * vignetting_gain(32, 24, 0.2)[..., None] * [1.2, 1.0, 0.8]
    np.testing.assert_allclose(linear, expect, rtol=1e-5, atol=1e-6 * expect.max())
    assert "truth_specular" in cap.extra and np.array_equal(cap.extra["truth_specular"], clean.extra["truth_specular"])


# --------------------------------------------------------------------------- range finder


def test_range_holes_appear_only_where_asked():
    clean = analytic_capture(width=48, height=36, kd=(0.05, 0.05, 0.05))
    b = clean.stack.astype(float).mean(axis=(0, -1))
    peak = b[clean.surface_mask].max()
    for shiny, dark in ((0.5, 0.0), (None, 0.3), (0.8, 0.1)):
        cap = through_rig(clean, nuisances=_nz(range={"holes_shiny_above": shiny, "holes_dark_below": dark}))
        holes = clean.surface_mask & ~cap.surface_mask
        want = clean.surface_mask & (((b >= shiny * peak) if shiny else False) | (b < dark * peak))
        np.testing.assert_array_equal(holes, want)
        assert holes.any() and not holes.all()
        np.testing.assert_array_equal(cap.P[~holes], clean.P[~holes])  # range everywhere else, untouched
        np.testing.assert_array_equal(cap.extra["truth_P"], clean.P)
        assert cap.N is None and np.array_equal(cap.extra["truth_N"], clean.N, equal_nan=True)
        assert np.isfinite(cap.stack[:, holes]).all()  # the images still see the surface there
    assert range_holes(clean, shiny_above=None, dark_below=0.0).sum() == 0


@pytest.mark.parametrize("shift", [(0.3, 0.0), (0.0, -0.25), (0.4, 0.2), (1.0, -2.0)])
def test_misregistration_moves_P_by_the_requested_sub_pixel_amount(shift):
    # Where P lands in the image (project, the inverse of the camera rays) moves by exactly the shift: P of the
    # pixel at (col, row) is the surface point seen at (col + dx, row + dy), to the bilinear interpolation's error
    # on a smooth surface (second order: < 0.01 px here).
    clean = analytic_capture(width=64, height=48)
    cap = through_rig(clean, nuisances=_nz(range={"shift_px": list(shift)}))
    cam = clean.camera
    col, row, _ = project(cap.P.astype(float) - cam.position, cam.to_world, 64, 48, cam.fov_x_deg)
    ok = interior(clean.surface_mask, px=3) & np.isfinite(col)
    cols, rows = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5)
    np.testing.assert_allclose(col[ok] - cols[ok], shift[0], atol=0.01)
    np.testing.assert_allclose(row[ok] - rows[ok], shift[1], atol=0.01)
    if all(float(s).is_integer() for s in shift):  # whole pixels move exactly
        rolled = np.roll(clean.P, (-int(shift[1]), -int(shift[0])), (0, 1))
        np.testing.assert_array_equal(bilinear_shift(clean.P, *shift)[ok], rolled[ok])


def test_depth_quantisation_keeps_points_on_their_rays():
    clean = analytic_capture(width=32, height=24)
    q = 0.002
    cap = through_rig(clean, nuisances=_nz(range={"quantum_m": q}))
    m = clean.surface_mask
    ray0 = clean.P[m].astype(float) - clean.camera.position
    ray1 = cap.P[m].astype(float) - clean.camera.position
    d0, d1 = np.linalg.norm(ray0, axis=-1), np.linalg.norm(ray1, axis=-1)
    np.testing.assert_allclose(d1 / q, np.round(d1 / q), atol=2e-4)  # float32 positions
    assert np.abs(d1 - d0).max() <= q / 2 + 1e-6
    np.testing.assert_allclose(ray1 / d1[:, None], ray0 / d0[:, None], atol=1e-6)


def test_range_noise_and_quantisation_are_stated_in_rig_range():
    clean = analytic_capture(width=32, height=24)
    cap = through_rig(clean, nuisances=_nz(range={"quantum_m": 0.002}), range_noise=0.001, seed=3)
    assert cap.rig.range == RangeSensor(sigma_m=0.001, quantum_m=0.002, axis="ray", source="renderer")
    only_q = through_rig(clean, nuisances=_nz(range={"quantum_m": 0.002}))
    assert only_q.rig.range == RangeSensor(sigma_m=0.0, quantum_m=0.002, axis="ray", source="renderer")
    # neither: the rig states nothing (nor for holes or a shift alone: no error of the range itself)
    assert through_rig(clean, nuisances=_nz(range={"shift_px": [0.5, 0.0]})).rig.range is None
    assert through_rig(clean).rig.range is None
    # add_range_noise on its own (the sweeps) states its sigma, keeping a stated quantisation
    assert add_range_noise(clean, sigma_m=0.0005, seed=1).rig.range == RangeSensor(sigma_m=0.0005, source="renderer")
    again = add_range_noise(only_q, sigma_m=0.0005, seed=1)
    assert again.rig.range == RangeSensor(sigma_m=0.0005, quantum_m=0.002, axis="ray", source="renderer")
    assert add_range_noise(clean, sigma_m=0.0, seed=1).rig.range is None


# --------------------------------------------------------------------------- calibration


def test_camera_pose_error_is_what_the_estimator_sees_and_truth_keeps_the_true_pose():
    clean = analytic_capture(width=32, height=24)
    cap = through_rig(clean, nuisances=_nz(calibration={"position_m": [0.002, 0, -0.001], "rotation_deg": [0, 0.5, 0]}))
    np.testing.assert_allclose(cap.camera.position - clean.camera.position, [0.002, 0, -0.001])
    cos = np.dot(cap.camera.to_world[:3, 2], clean.camera.to_world[:3, 2])
    assert np.isclose(np.degrees(np.arccos(np.clip(cos, -1, 1))), 0.5, atol=1e-4) or np.isclose(
        np.degrees(np.arccos(np.dot(cap.camera.to_world[:3, 0], clean.camera.to_world[:3, 0]))), 0.5, atol=1e-4)
    assert cap.truth["camera"]["position"] == clean.camera.position.tolist()
    np.testing.assert_array_equal(cap.P, clean.P)  # the range finder's points are where they are


# --------------------------------------------------------------------------- profiles, truth, the written capture


def test_realism_profiles_expand_and_explicit_keys_win():
    for name in PROFILES:
        s = load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "realism": name})
        assert s.realism == name and (s.nuisances.off == (name == "none"))
        assert load_scene(s.model_dump(mode="json")) == s
    s = load_scene(SCENES / "ts_board.yaml", overrides=["realism=bench", "nuisances.analyzer.jitter_deg=0"])
    assert s.nuisances.analyzer.jitter_deg == 0 and s.nuisances.analyzer.extinction_ratio == 300
    realism, nz = nuisances_of(s.model_dump(mode="json"))
    assert realism == "bench" and nz == s.nuisances


@pytest.mark.render
def test_a_bench_capture_records_every_nuisance_and_still_estimates(tmp_path):
    from nearlight.estimator import estimate
    from nearlight.generator import render_capture

    scene = load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "realism": "bench", "capture.noise": NOISE})
    cap = read_capture(render_capture(scene, tmp_path / "cap", progress=False))
    n = cap.truth["nuisances"]
    assert n["realism"] == "bench" and n["analyzer"]["extinction_ratio"] == 300 and len(n["analyzer"]["angles_deg"]) == 8
    assert cap.truth["camera"]["position"] == list(scene.camera.position)
    assert cap.rig.analyzer_extinction_ratio == 300 and cap.rig.lamp_polarizer_extinction_ratio == 300
    assert (~cap.surface_mask & (cap.extra["mask"] > 0)).any()  # holes on the highlight
    est = estimate(cap.replace(truth=None), method="full")  # the estimator never needs truth
    assert np.all(np.isfinite(est.lamp_position))


def test_render_and_a_sweep_task_with_the_same_seed_see_the_same_nuisances(tmp_path, monkeypatch):
    # The one seed rule, nuisances included: `nearlight render --set realism=bench --set capture.seed=3` and a sweep
    # task with seed 3 on the same scene make the same capture. No Mitsuba: an analytic capture stands in for the render.
    from nearlight.evaluation.engine.tasks import noisy_capture
    from nearlight.generator import pipeline

    clean = analytic_capture(width=64, height=48, analyzer_angles_deg=np.arange(8) * 22.5)
    scene = load_scene(SCENES / "ts_board.yaml", overrides={
        **SMALL, "realism": "rough", "capture.seed": 3, "capture.noise": NOISE, "capture.range_noise_m": 0.001})
    monkeypatch.setattr(pipeline, "render_clean", lambda *a, **k: clean)
    rendered = read_capture(pipeline.render_capture(scene, tmp_path / "cap", progress=False))
    task = {"scene": scene.model_dump(mode="json"), "noise": NOISE, "range_noise": 0.001, "seed": 3}
    swept = noisy_capture(clean, task)
    assert np.array_equal(rendered.stack, swept.stack)
    assert np.array_equal(rendered.P, swept.P, equal_nan=True)
    np.testing.assert_array_equal(rendered.camera.position, swept.camera.position)
    assert rendered.truth["nuisances"] == swept.truth["nuisances"]
    assert not np.array_equal(swept.stack, noisy_capture(clean, {**task, "seed": 4}).stack)
