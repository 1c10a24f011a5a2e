"""The intersectable sphere lamp (``nearlight_area_lamp`` on a ``sphere`` shape) against the sampled sphere lamp,
the point lamp, the filter's closed form and a perfect mirror's analytic image (generator/lamp.py).

Scenes are small Mitsuba dicts built here (64×48 px, ``path`` with max_depth 2: direct light only), traced through
pixel centres by :func:`nearlight.generator.render.trace_stokes`. Monte-Carlo comparisons are tests of bias: over
the lit pixels the mean relative difference must lie within 4 standard errors of zero (a one-sample t-test: the
chance a correct renderer fails is ~6e-5), with the spp and the measured per-pixel noise stated in each test.
Deterministic renders (a camera or a mirror looking at the lamp: no sampling is involved) are held to float32.
"""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.generator import lamp, render
from nearlight.physics.polarization import filter_axes

pytestmark = pytest.mark.render

#: The lamp: 0.33 m above the board's centre, its filter facing the centre.
POSITION = np.array([0.05, 0.1, 0.3])
FACING = -POSITION / np.linalg.norm(POSITION)
AXIS = [1.0, 2.0, 0.5]
INTENSITY = 2.0
LAMBERTIAN = {"type": "nearlight_bsdf", "kd": 0.5, "ks": 0.0}
GLOSSY = {"type": "nearlight_bsdf", "model": "torrance_sparrow", "roughness": 0.1, "ks": 1.0, "kd": 0.0,
          "polarization": "ideal"}  # fmt: skip
#: A perfect mirror: Mitsuba's conductor with unit reflectance for every polarization.
MIRROR = {"type": "conductor", "material": "none"}


@pytest.fixture(scope="module")
def mi():
    from nearlight.generator.llvm import mitsuba

    return mitsuba()


def lamp_dict(**kw) -> dict:
    return lamp.polarized_lamp(POSITION, INTENSITY, AXIS, FACING, **kw)


def sensor(mi, origin, target, *, fov: float = 40.0, size=(64, 48)) -> dict:
    return {"type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=list(origin), target=list(target), up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": size[0], "height": size[1], "rfilter": {"type": "box"},
                     "pixel_format": "luminance"}}  # fmt: skip


def board_scene(mi, bsdf: dict, lamp_: dict, *, camera=(0.0, -0.35, 0.45), fov: float = 40.0) -> dict:
    """A 30 cm square board in the plane z = 0 (normal +z) with ``bsdf``, lit by ``lamp_``."""
    return {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
            "sensor": sensor(mi, camera, (0, 0, 0), fov=fov),
            "board": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([0.15, 0.15, 1]), "bsdf": bsdf},
            "lamp": lamp_}  # fmt: skip


def trace(mi, d: dict, spp: int = 1, seed: int = 0) -> np.ndarray:
    return render.trace_stokes(mi, mi.load_dict(d), spp=spp, seed=seed)


def assert_unbiased(got: np.ndarray, ref: np.ndarray) -> None:
    """The mean relative difference of ``got`` from ``ref`` over pixels is within 4 of its standard errors."""
    rel = got / ref - 1
    mean, se = float(rel.mean()), float(rel.std() / np.sqrt(rel.size))
    assert abs(mean) <= 4 * se, (mean, se)


def test_the_intersectable_lamp_is_a_sphere_shape_carrying_the_area_emitter():
    sphere = lamp_dict(radius=0.02, intersectable=True)
    assert sphere["type"] == "sphere" and sphere["center"] == POSITION.tolist() and sphere["radius"] == 0.02
    assert sphere["emitter"] == {**lamp_dict(radius=0.02), "type": lamp.AREA_PLUGIN}
    assert sphere["bsdf"]["reflectance"]["value"] == 0.0  # black: the lamp reflects nothing
    assert lamp_dict(intersectable=False) == lamp_dict()  # the point emitter's dict as before
    with pytest.raises(ValueError, match="radius > 0"):
        lamp_dict(intersectable=True)


def test_emitter_samples_agree_with_the_emitters_pdf_and_radiance(mi, rng):
    """From 200 random points 2.5–40 cm from a 2 cm lamp: each sample lies on the sphere's visible side (outward
    normal, facing the point), its density is 1/Ω of the cap (Ω = 2π(1 − √(1 − (a/d)²)), float64 here), the
    scene's ``pdf_emitter_direction`` returns the same density for it (MIS sees one cone) and its weight is
    ``eval_emitter_direction / pdf`` (the filtered radiance over the density). Float32 tolerance: 1e-5 relative
    (measured at most 3e-6)."""
    import drjit as dr

    a = 0.02
    mscene = mi.load_dict({"type": "scene", "lamp": lamp_dict(radius=a, intersectable=True, extinction_ratio=30.0,
                                                              anisotropy_k=1.5)})  # fmt: skip
    n = 200
    u = rng.normal(size=(n, 3))
    ref = POSITION + u / np.linalg.norm(u, axis=1)[:, None] * rng.uniform(0.025, 0.4, n)[:, None]
    it = dr.zeros(mi.Interaction3f, n)
    it.p = mi.Point3f(*(ref[:, i] for i in range(3)))
    ds, weight = mscene.sample_emitter_direction(it, mi.Point2f(*rng.uniform(size=(2, n))), False)
    p, normal, d = (np.stack([np.asarray(c, float) for c in v], -1) for v in (ds.p, ds.n, ds.d))
    np.testing.assert_allclose(np.linalg.norm(p - POSITION, axis=1), a, rtol=1e-5)
    np.testing.assert_allclose(normal, (p - POSITION) / a, atol=1e-5)
    assert np.all(np.sum(normal * d, -1) < 0)  # the side facing the point
    dc = np.linalg.norm(POSITION - ref, axis=1)
    pdf = np.asarray(ds.pdf, float)
    np.testing.assert_allclose(pdf, 1 / (2 * np.pi * (1 - np.sqrt(1 - (a / dc) ** 2))), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(mscene.pdf_emitter_direction(it, ds), float), pdf, rtol=1e-5)
    value = mscene.eval_emitter_direction(it, ds)
    for i in range(4):
        for j in range(4):
            got, want = np.asarray(weight[i, j], float), np.asarray(value[i, j], float) / pdf
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * np.abs(want).max())


@pytest.mark.parametrize("radius", [0.02, 0.1])
def test_a_lambertian_board_sees_the_point_lamps_irradiance(mi, radius):
    """A uniform sphere wholly above the board's horizon lights a Lambertian surface as a point lamp of the same
    intensity at its centre (Lambert's sphere; S0 after the ideal filter is I/2 in every direction), so both sphere
    routes must equal the deterministic point-lamp render. 64 spp: measured per-pixel relative noise 0.2 % (2 cm)
    and 1.1 % (10 cm); tolerance 4 standard errors of the mean over the 1804 lit pixels (2e-4 and 1e-3). The 10 cm
    lamp (17° half-angle, 0.3 sr) makes BSDF-sampled rays hit it in up to ~8 % of the samples, so a double count
    (the lamp counted by both strategies) or wrong MIS weights fail the test (tried: ``pdf_direction`` 0, or 4× or
    ¼× the sampling density)."""
    point = trace(mi, board_scene(mi, LAMBERTIAN, lamp_dict()))[0]
    lit = point > 0
    assert lit.sum() > 1500
    for seed, intersectable in ((1, False), (2, True)):
        got = trace(mi, board_scene(mi, LAMBERTIAN, lamp_dict(radius=radius, intersectable=intersectable)), 64, seed)
        assert_unbiased(got[0][lit], point[lit])


def test_a_glossy_board_counts_the_lamp_once(mi):
    """Torrance–Sparrow (σ = 0.1, ideal polarization) under a 2 cm lamp: the intersectable route (emitter and BSDF
    sampling, combined by MIS) and the sampled sphere lamp (emitter sampling only) are independent estimates of the
    same image. 64 spp each, independent seeds: measured per-pixel relative difference 4.5 % (std), so over the 570
    bright pixels (S0 above 10 % of its peak) the mean of S0 and of the polarized part must agree within 4 standard
    errors (7.5e-3); counting the lamp twice would add ~100 %."""
    sampled = trace(mi, board_scene(mi, GLOSSY, lamp_dict(radius=0.02)), 64, seed=3)
    area = trace(mi, board_scene(mi, GLOSSY, lamp_dict(radius=0.02, intersectable=True)), 64, seed=4)
    bright = sampled[0] > 0.1 * sampled[0].max()
    assert bright.sum() > 300
    assert_unbiased(area[0][bright], sampled[0][bright])
    assert_unbiased(np.hypot(*area[1:])[bright], np.hypot(*sampled[1:])[bright])


@pytest.mark.parametrize("extinction, k, tilt_deg", [(None, 0.0, 0.0), (100.0, 2.0, 30.0)])
def test_a_camera_looking_at_the_lamp_sees_its_filtered_radiance(mi, extinction, k, tilt_deg):
    """The camera 20 cm from the lamp, ``tilt_deg`` off the filter's normal (and beam axis), looks at its centre:
    the centre pixel's ray meets the sphere head on, so S0 = L/2 · (1 + 1/ε) · cos^k(tilt) with L = I/(πa²), the
    degree of linear polarization (1 − 1/ε)/(1 + 1/ε) and the angle of polarization that of the filter's effective
    (Korger) transmission axis k × â projected on the image. One deterministic sample (no light is sampled);
    tolerance float32 (1e-5 relative)."""
    a = 0.02
    tilt = np.radians(tilt_deg)
    side = np.cross(FACING, [0, 0, 1])
    view = np.cos(tilt) * FACING + np.sin(tilt) * side / np.linalg.norm(side)  # lamp → camera
    camera = POSITION + 0.2 * view
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
         "sensor": sensor(mi, camera, POSITION, fov=20.0, size=(33, 25)),
         "lamp": lamp_dict(radius=a, intersectable=True, extinction_ratio=extinction, anisotropy_k=k)}  # fmt: skip
    S = trace(mi, d)[:, 12, 16]  # the image centre: the ray through the lamp's centre
    inv = 0.0 if extinction is None else 1 / extinction
    L = INTENSITY / (np.pi * a**2)
    assert S[0] == pytest.approx(L / 2 * (1 + inv) * np.cos(tilt) ** k, rel=1e-5)
    assert np.hypot(S[1], S[2]) / S[0] == pytest.approx((1 - inv) / (1 + inv), rel=1e-5)
    absorb = filter_axes(AXIS, FACING)[1]
    transmit = np.cross(view, absorb - absorb @ view * view)  # Korger's effective axis, normal to the ray
    right = np.cross(-view, [0, 0, 1])  # the image's horizontal; the Stokes frame's y is the image's up
    up = np.cross(right, -view)
    phi = np.arctan2(transmit @ up, transmit @ right)
    np.testing.assert_allclose(S[1:] / np.hypot(S[1], S[2]), [np.cos(2 * phi), np.sin(2 * phi)], atol=1e-5)


def test_a_mirror_shows_the_lamp(mi):
    """A perfect mirror (the plane z = 0) seen from (0, −0.3, 0.3), the 2 cm lamp at (0, 0.3, 0.3), out of the
    camera's view: every pixel whose pixel-centre ray, reflected analytically, meets the sphere shows S0 = L/2 (the
    ideal filter passes half of the unpolarized radiance L = I/(πa²) along every direction; the mirror reflects all
    of it), and every other pixel is black (a delta BSDF is never lit by emitter sampling). One deterministic sample;
    the lamp's image is exactly the predicted set of pixels, but for those whose reflected ray passes within
    1e-4·a of the sphere's silhouette (float32: none in this geometry), and its values equal L/2 to float32."""
    a, centre = 0.02, np.array([0.0, 0.3, 0.3])
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
         "sensor": sensor(mi, (0, -0.3, 0.3), (0, 0, 0), fov=20.0),
         "mirror": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([0.3, 0.3, 1]), "bsdf": MIRROR},
         "lamp": lamp.polarized_lamp(centre, INTENSITY, AXIS, -centre, radius=a, intersectable=True)}  # fmt: skip
    mscene = mi.load_dict(d)
    S = render.trace_stokes(mi, mscene, spp=1)
    ray = render.sensor_rays(mi, mscene.sensors()[0])
    o = np.stack([np.asarray(c, float) for c in ray.o], -1)
    v = np.stack([np.asarray(c, float) for c in ray.d], -1)
    hit = o - (o[:, 2] / v[:, 2])[:, None] * v  # on the mirror (every ray looks down, none misses the 60 cm square)
    r = v * [1, 1, -1]
    to_centre = centre - hit
    miss = np.linalg.norm(to_centre - np.sum(to_centre * r, -1)[:, None] * r, axis=-1) / a  # in radii
    sees = (miss < 1).reshape(S[0].shape)
    assert np.all(np.abs(miss - 1) > 1e-4)  # no pixel on the silhouette's float32 edge: the count is exact
    assert 40 < sees.sum() == (S[0] > 0).sum()
    assert np.array_equal(S[0] > 0, sees)
    L = INTENSITY / (np.pi * a**2)
    np.testing.assert_allclose(S[0][sees], L / 2, rtol=1e-5)
    assert S[0].flat[np.argmin(miss)] == pytest.approx(L / 2, rel=1e-5)  # the ray meeting the lamp's centre


def test_a_small_intersectable_lamp_tends_to_the_point_lamp(mi):
    """Radius 1 mm, 0.33 m from the board: on a Lambertian board the intersectable lamp equals the point lamp within
    0.1 % plus its Monte-Carlo error (64 spp: measured per-pixel relative noise 1e-4, from the lamp's 0.2° cap)."""
    point = trace(mi, board_scene(mi, LAMBERTIAN, lamp_dict()))[0]
    lit = point > 0
    got = trace(mi, board_scene(mi, LAMBERTIAN, lamp_dict(radius=1e-3, intersectable=True)), 64, seed=5)[0]
    rel = got[lit] / point[lit] - 1
    assert abs(rel.mean()) <= 1e-3 + 4 * rel.std() / np.sqrt(rel.size)
    assert np.abs(rel).max() <= 1e-3 + 5 * rel.std()
