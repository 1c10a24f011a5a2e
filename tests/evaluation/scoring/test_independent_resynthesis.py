"""The grading re-synthesis: a second implementation that agrees with the first, and its defined edges.

``nearlight.evaluation.scoring.independent_resynthesis`` is written apart from ``nearlight.physics.reflectance`` on purpose
(a grading oracle must not share code with what it grades); these tests hold the two to each other, to
float64 rounding, on random geometry and on analytic captures.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from nearlight.estimator import Estimate, estimate, render_specular
from nearlight.estimator.distant import distant_specular
from nearlight.evaluation.scoring import independent_resynthesis as resynthesis
from nearlight.evaluation.scoring.metrics import score, truth_estimate
from nearlight.evaluation.scoring.independent_resynthesis import resynthesize, ts_specular_distant, ts_specular_near
from nearlight.generator.analytic import DEFAULT_BSDF, analytic_capture
from nearlight.physics.polarization import through_polarizer
from nearlight.physics.reflectance import LOBES, brdf_shape, convert_bsdf, specular_radiance

#: Two float64 implementations of one formula: they differ by rounding only. Measured: ≤ 4e-14 relative
#: (α by arccos against atan2 near α = 0, Ks / cos θr against Ks cos θi / (cos θi cos θr)). Every family, 200
#: random draws each (the seed of ``rng``), on pixels above 1e-6 of the peak: ≤ 7e-13 relative for a near lamp
#: (Ward 5.8e-13, GGX 4.2e-13, Beckmann 5.9e-13, Torrance–Sparrow 5.8e-13); under a distant light up to 7e-12, at
#: a grazing view (cos θr = 3e-6), where both sides' 1/cos θr amplifies the dot product's 1e-16 absolute rounding.
RTOL = 1e-10


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _random_scene(rng, n=4000):
    """Points near the origin, unit normals towards +z-ish, a camera and a lamp above: most points lit."""
    P = rng.uniform(-0.2, 0.2, size=(n, 3)) * [1, 1, 0.1]
    N = _unit(rng.normal(size=(n, 3)) * [0.3, 0.3, 1.0] + [0, 0, 1.0])
    camera = np.array([0.05, -0.35, 0.5])
    lamp = rng.uniform([-0.2, -0.2, 0.1], [0.2, 0.3, 0.6])
    return P, N, camera, lamp


def _close(a, b):
    """Equal to RTOL, and zero exactly where the other is zero (both say "unlit" on the same pixels)."""
    a, b = np.asarray(a), np.asarray(b)
    assert np.array_equal(a == 0, b == 0)
    # far in the lobe's tail values reach denormals, where a relative tolerance means nothing
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=1e-12 * float(np.max(np.abs(b))))


def test_near_lamp_agrees_with_physics_reflectance_on_random_geometry(rng):
    for _ in range(20):
        P, N, camera, lamp = _random_scene(rng)
        ks, sigma = rng.uniform(0.1, 2.0, size=3), float(rng.uniform(0.02, 0.4))
        ours = ts_specular_near(P, N, camera, lamp, ks, sigma)
        theirs = specular_radiance(P, N, camera, lamp, 1.0, {"model": "torrance_sparrow", "ks": ks, "sigma": sigma})
        assert 0.3 < np.mean(ours[:, 0] > 0) < 1.0  # the draw lights most points, not all
        _close(ours, theirs)


def test_distant_light_agrees_with_the_distant_baselines_model_on_random_geometry(rng):
    for _ in range(20):
        _, N, _, _ = _random_scene(rng)
        light, view = _unit(rng.normal(size=3) + [0, 0, 1.5]), _unit(rng.normal(size=3) + [0, 0, 1.5])
        ks, sigma = rng.uniform(0.1, 2.0, size=3), float(rng.uniform(0.02, 0.4))
        _close(ts_specular_distant(N, light, view, ks, sigma), distant_specular(N, light, view, ks, sigma))


@pytest.mark.parametrize("shape", ["board", "sphere"])
def test_resynthesize_agrees_with_the_estimators_render_specular(shape, rng):
    cap = analytic_capture(shape=shape, width=64, height=48, lamp_intensity=3.0)
    truth = truth_estimate(cap)
    estimates = [truth]
    for _ in range(5):  # near estimates around the truth
        estimates.append(Estimate(method="near", lamp_position=truth.lamp_position + rng.normal(scale=0.05, size=3),
                                  ks=truth.ks * rng.uniform(0.5, 2.0, size=3), sigma=truth.sigma * rng.uniform(0.5, 2.0)))
    for _ in range(5):  # distant estimates: directions near the mirror configuration
        estimates.append(Estimate(method="distant", lamp_position=truth.lamp_position, ks=truth.ks,
                                  sigma=truth.sigma * rng.uniform(0.5, 2.0),
                                  light_model={"type": "distant",
                                               "light_direction": _unit(rng.normal(scale=0.2, size=3) + [0, 0.4, 1]),
                                               "view_direction": _unit(rng.normal(scale=0.2, size=3) + [0, -0.6, 1])}))
    estimates += [estimate(cap, method="distant", sanity=False), estimate(cap, method="paper-init")]  # as written
    assert estimates[-2].light_model["type"] == "distant"
    for est in estimates:
        _close(resynthesize(cap, est), render_specular(cap, est))


@pytest.mark.parametrize("shape", ["board", "sphere"])
def test_the_truth_estimate_reproduces_the_analytic_truth_image(shape):
    cap = analytic_capture(shape=shape, width=64, height=48, lamp_intensity=3.0)
    ours = resynthesize(cap, truth_estimate(cap))
    observed = cap.extra["truth_specular"].astype(float)
    # The capture holds P, N and truth_specular in float32 (relative 2^-24 = 6e-8): P and N move α by ~1e-7 rad,
    # which changes exp(-α²/2σ²) by (α/σ²)·1e-7 relative: ≤ 1e-5 where the lobe is above 1e-9 of its peak
    # (α ≤ 6.4σ, σ = 0.1; measured ≤ 3e-6). Below that the truth is compared in absolute terms.
    np.testing.assert_allclose(ours, observed, rtol=1e-5, atol=1e-9 * observed.max())
    assert np.array_equal(ours == 0, observed == 0)


def test_resynthesis_imports_neither_the_estimator_nor_physics_reflectance():
    """The point of the module: it shares no code with the forward model it grades."""
    tree = ast.parse(Path(resynthesis.__file__).read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add("." * node.level + (node.module or ""))
    assert imported <= {"__future__", "typing", "numpy"}, imported


@pytest.mark.parametrize("field", ["lamp_position", "ks", "sigma", "light_direction", "view_direction"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_estimate_renders_nan_on_every_surface_pixel(field, bad):
    cap = analytic_capture(width=32, height=24)
    est = truth_estimate(cap)
    if field in ("light_direction", "view_direction"):
        est.light_model = {"type": "distant", "light_direction": [0.0, 0.3, 1.0], "view_direction": [0.0, -0.6, 1.0]}
        est.light_model[field] = [0.0, bad, 1.0]
    elif field == "sigma":
        est.sigma = bad
    else:
        value = getattr(est, field).copy()
        value[1] = bad
        setattr(est, field, value)
    img = resynthesize(cap, est)
    assert np.all(np.isnan(img[cap.surface_mask])) and np.all(img[~cap.surface_mask] == 0)


def test_sigma_zero_is_the_mirror_limit_and_the_sign_of_sigma_does_not_matter():
    N = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    # first normal: exact mirror (α = 0); second: light tilted (α > 0)
    light, view = np.array([0.0, 0.6, 0.8]), np.array([0.0, -0.6, 0.8])
    mirror = ts_specular_distant(N[:1], light, view, 1.0, 0.0)
    off = ts_specular_distant(N[1:], _unit(light + [0.1, 0, 0]), view, 1.0, 0.0)
    assert mirror[0, 0] == pytest.approx(1 / 0.8, rel=1e-15)  # lobe 1, Ks / cos θr
    assert np.all(off == 0)
    assert np.array_equal(ts_specular_distant(N, light, view, 1.0, -0.1), ts_specular_distant(N, light, view, 1.0, 0.1))


def test_a_lamp_on_a_surface_point_makes_that_pixel_nan_only():
    P = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    N = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    img = ts_specular_near(P, N, [0.0, -0.3, 0.5], P[0], [1.0, 1.0, 1.0], 0.1)
    assert np.all(np.isnan(img[0])) and np.all(img[1] == 0)  # the other point: lamp in its plane, unlit


def test_unknown_light_models_and_missing_normals_are_refused():
    cap = analytic_capture(width=32, height=24)
    est = truth_estimate(cap)
    est.light_model = {"type": "area"}
    with pytest.raises(ValueError, match="light_model.type"):
        resynthesize(cap, est)
    with pytest.raises(ValueError, match="normals"):
        resynthesize(cap.replace(N=None), truth_estimate(cap))


# ---------------------------------------------------------------------------------------------------------------
# Every lobe family: the BSDF dict ``full`` reports in ``stages["full"]["bsdf"]``.

#: The four families, and the ones with a lobe of their own shape (not Torrance–Sparrow's).
MODELS = ("torrance_sparrow", "ward", "ggx", "beckmann")
NORMALISED = ("ward", "ggx", "beckmann")


def _family_bsdf(model, rng):
    """A random BSDF dict of ``model``: colour in [0.1, 2], roughness wide enough to reach the lobe's tail."""
    colour_key, roughness_key = LOBES[model].colour_key, LOBES[model].roughness_key
    rough = float(rng.uniform(0.02, 0.4)) if model == "torrance_sparrow" else float(rng.uniform(0.03, 0.6))
    return {"model": model, colour_key: rng.uniform(0.1, 2.0, size=3), roughness_key: rough}


def _full_estimate(lamp_position, bsdf, *, light_model=None):
    """A fake ``full`` estimate: its own BSDF dict in ``stages["full"]["bsdf"]``, ``ks``/``sigma`` its
    Torrance–Sparrow equivalent (as ``full`` reports them)."""
    ts = convert_bsdf(bsdf, "torrance_sparrow")
    return Estimate(method="full", lamp_position=lamp_position, ks=ts["ks"], sigma=ts["sigma"],
                    stages={"full": {"lobe": bsdf["model"], "bsdf": dict(bsdf)}},
                    light_model=light_model or {"type": "point"})


def _close_to_the_tail(a, b):
    """:func:`_close`, but where both values lie below 1e-290 (the lobe's far tail, where one side may
    underflow to 0 and the other to a denormal) a zero need not match a zero: the absolute tolerance holds."""
    a, b = np.asarray(a), np.asarray(b)
    big = (np.abs(a) > 1e-290) | (np.abs(b) > 1e-290)
    assert np.array_equal((a == 0)[big], (b == 0)[big])
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=1e-12 * float(np.max(np.abs(b))))


def test_the_families_and_their_keys_are_physics_reflectances():
    assert resynthesis.FAMILIES == {m: (lobe.colour_key, lobe.roughness_key) for m, lobe in LOBES.items()}


@pytest.mark.parametrize("model", MODELS)
def test_every_family_agrees_with_physics_reflectance_on_random_geometry(model, rng):
    for _ in range(20):
        P, N, camera, lamp = _random_scene(rng)
        bsdf = _family_bsdf(model, rng)
        ours = resynthesis.specular_near(P, N, camera, lamp, bsdf)
        theirs = specular_radiance(P, N, camera, lamp, 1.0, bsdf)
        assert 0.3 < np.mean(ours[:, 0] > 0) < 1.0
        _close_to_the_tail(ours, theirs)


@pytest.mark.parametrize("model", MODELS)
def test_every_family_under_a_distant_light_agrees_with_physics_reflectance(model, rng):
    """Distant: ``colour · f · cos θi`` with one light and one view direction; the reference is the
    estimator's BRDF (``brdf_shape``, α by ``arccos``) times ``cos θi``."""
    for _ in range(20):
        _, N, _, _ = _random_scene(rng)
        light, view = _unit(rng.normal(size=3) + [0, 0, 1.5]), _unit(rng.normal(size=3) + [0, 0, 1.5])
        bsdf = _family_bsdf(model, rng)
        spec = LOBES[model]
        cos_i, cos_r = N @ light, N @ view
        alpha = np.arccos(np.clip(N @ _unit(light + view), -1.0, 1.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            f = brdf_shape(model, cos_i, cos_r, alpha, bsdf[spec.roughness_key]) * cos_i
        theirs = np.where((cos_i > 0) & (cos_r > 0), f, 0.0)[:, None] * bsdf[spec.colour_key]
        _close_to_the_tail(resynthesis.specular_distant(N, light, view, bsdf), theirs)


def _family_capture(model, shape="board"):
    """A small analytic capture of ``model`` with the default lobe's width and peak, and a lamp of
    intensity 3 (1.5 reaches the surface: the colour an estimate reports is 1.5 × the BSDF's)."""
    bsdf = convert_bsdf(DEFAULT_BSDF, model)
    return analytic_capture(shape=shape, width=64, height=48, lamp_intensity=3.0, bsdf=bsdf), bsdf


def _reported(cap, bsdf):
    """``bsdf`` as an estimator reports it: the lamp intensity reaching the surface folded into its colour."""
    key = LOBES[bsdf["model"]].colour_key
    reaching = through_polarizer(np.asarray(cap.truth["lamp_intensity"], dtype=float))
    return {"model": bsdf["model"], key: np.asarray(bsdf[key], dtype=float) * reaching,
            LOBES[bsdf["model"]].roughness_key: bsdf[LOBES[bsdf["model"]].roughness_key]}


@pytest.mark.parametrize("shape", ["board", "sphere"])
@pytest.mark.parametrize("model", MODELS)
def test_the_true_bsdf_of_every_family_reproduces_the_analytic_truth_image(model, shape):
    """The analytic capture computes its truth in float64 and stores P, N and ``truth_specular`` in float32:
    the re-synthesis from the float32 geometry differs by that rounding only.

    * Storage of the truth image: 2^-24 = 6e-8 relative per pixel, so ≤ 6e-8 of the peak in the RMSE.
    * Geometry: as for Torrance–Sparrow above, a P or N rounded by 2^-24 moves α by ~1e-7 rad and each lobe
      by (∂ ln lobe / ∂α) · 1e-7 ≈ α/σ² · 1e-7 relative, ≤ 1e-5 where the lobe is above 1e-9 of its peak;
      near the sphere's terminator the factors cos θi, cos θr (and Smith's G1) move by 1e-7 / cos θ relative
      (measured ≤ 8e-5 there, GGX, on pixels ~2e-9 of the peak): hence rtol 1e-4 with the absolute 1e-9.
    * Values below float32's smallest denormal (1.4e-45: the far tail of Ward's and Beckmann's lobes at the
      sphere's rim, ~1e-60) are stored as 0, so the zero pattern is compared after the same float32 cast.

    So ``specular_rmse_rel`` < 1e-6 holds with a wide margin: measured ≤ 9e-9 for every family and shape,
    against ~1e-2 for a Ward lobe graded through its Torrance–Sparrow equivalent (the next test)."""
    cap, bsdf = _family_capture(model, shape)
    est = _full_estimate(np.asarray(cap.truth["lamp_position"]), _reported(cap, bsdf))
    ours = resynthesize(cap, est)
    observed = cap.extra["truth_specular"].astype(float)
    assert observed.max() > 0
    np.testing.assert_allclose(ours, observed, rtol=1e-4, atol=1e-9 * observed.max())
    assert np.array_equal(ours.astype(np.float32) == 0, observed == 0)
    assert score(cap, est)["specular_rmse_rel"] < 1e-6


@pytest.mark.parametrize("model", NORMALISED)
def test_a_family_graded_through_its_torrance_sparrow_equivalent_reads_far_worse(model):
    """The bug this module's families fix: ``estimate.ks/sigma`` are only the Torrance–Sparrow lobe of the
    same head-on peak and small-angle width. Graded through it, even the true lobe misses the truth image
    (measured ``specular_rmse_rel`` on this 64×48 board: Ward 0.030, GGX 0.062, Beckmann 0.0029); graded as
    itself, by float32 rounding (≤ 9e-9). Before the families, both estimates read the first numbers."""
    cap, bsdf = _family_capture(model)
    right = _full_estimate(np.asarray(cap.truth["lamp_position"]), _reported(cap, bsdf))
    ts_only = Estimate(method="full", lamp_position=right.lamp_position, ks=right.ks, sigma=right.sigma)
    rmse_right = score(cap, right)["specular_rmse_rel"]
    rmse_ts = score(cap, ts_only)["specular_rmse_rel"]
    assert rmse_right < 1e-6
    assert rmse_ts > 1e3 * rmse_right
    if model == "ward":
        assert rmse_ts > 1e-3


def test_an_estimate_without_a_fitted_bsdf_is_graded_exactly_as_before():
    """Every method but ``full`` (and a result row) has no ``stages["full"]["bsdf"]``: the Torrance–Sparrow
    path of ``ks``/``sigma``, bit for bit; a Torrance–Sparrow ``full`` fit's dict gives the same numbers."""
    cap = analytic_capture(width=64, height=48, lamp_intensity=3.0)
    truth = truth_estimate(cap)
    plain = resynthesize(cap, truth)
    P, N = cap.P.astype(float), resynthesis._unit(cap.N.astype(float))
    s = cap.surface_mask
    assert np.array_equal(plain[s], ts_specular_near(P[s], N[s], cap.camera.position, truth.lamp_position,
                                                     truth.ks, truth.sigma))
    for stages in ({}, {"init": {"t": 1.0}}, {"full": {"lobe": "torrance_sparrow"}}):
        est = Estimate(method="x", lamp_position=truth.lamp_position, ks=truth.ks, sigma=truth.sigma, stages=stages)
        assert np.array_equal(resynthesize(cap, est), plain)
    ts_fit = _full_estimate(truth.lamp_position, {"model": "torrance_sparrow", "ks": truth.ks, "sigma": truth.sigma})
    assert np.array_equal(resynthesize(cap, ts_fit), plain)


@pytest.mark.parametrize("bsdf", [
    {"model": "phong", "ks": [1.0, 1.0, 1.0], "alpha": 0.1},
    {"ks": [1.0, 1.0, 1.0], "sigma": 0.1},  # no model: not guessed
    {"model": "ward", "ks": [1.0, 1.0, 1.0], "alpha": 0.1},  # Ward's colour is rho_s
    {"model": "ggx", "ks": [1.0, 1.0, 1.0], "sigma": 0.1},
])
def test_a_fitted_bsdf_of_an_unknown_model_or_without_its_keys_is_refused(bsdf):
    cap = analytic_capture(width=32, height=24)
    est = _full_estimate(truth_estimate(cap).lamp_position, {"model": "ward", "rho_s": [1, 1, 1], "alpha": 0.1})
    est.stages["full"]["bsdf"] = bsdf
    with pytest.raises(ValueError, match="estimate bsdf"):
        resynthesize(cap, est)


@pytest.mark.parametrize("field", ["lamp_position", "colour", "roughness", "light_direction", "view_direction"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("model", MODELS)
def test_a_non_finite_fitted_bsdf_renders_nan_on_every_surface_pixel(model, field, bad):
    cap, bsdf = _family_capture(model)
    bsdf = _reported(cap, bsdf)
    spec = LOBES[model]
    lamp = np.asarray(cap.truth["lamp_position"], dtype=float)
    light_model = None
    if field in ("light_direction", "view_direction"):
        light_model = {"type": "distant", "light_direction": [0.0, 0.3, 1.0], "view_direction": [0.0, -0.6, 1.0]}
        light_model[field] = [0.0, bad, 1.0]
    elif field == "lamp_position":
        lamp[1] = bad
    elif field == "colour":
        bsdf[spec.colour_key] = bsdf[spec.colour_key].copy()
        bsdf[spec.colour_key][1] = bad
    else:
        bsdf[spec.roughness_key] = bad
    est = _full_estimate(lamp, {"model": "torrance_sparrow", "ks": [1.0, 1.0, 1.0], "sigma": 0.1},
                         light_model=light_model)
    est.stages["full"]["bsdf"] = bsdf  # only the fitted dict is non-finite: ks/sigma are fine
    img = resynthesize(cap, est)
    assert np.all(np.isnan(img[cap.surface_mask])) and np.all(img[~cap.surface_mask] == 0)
    assert math.isnan(score(cap, est)["specular_rmse_rel"])


@pytest.mark.parametrize("model", NORMALISED)
def test_a_normalised_lobe_at_roughness_zero_is_nan_and_the_sign_of_roughness_does_not_matter(model, rng):
    """Ward, GGX and Beckmann tend to a delta as their roughness → 0: no image (NaN, as a non-finite estimate;
    Torrance–Sparrow's un-normalised lobe has the mirror limit, tested above). Each depends on a² (Beckmann's
    Smith term on |a|), so −a renders as a."""
    P, N, camera, lamp = _random_scene(rng, n=200)
    bsdf = _family_bsdf(model, rng)
    key = LOBES[model].roughness_key
    assert np.all(np.isnan(resynthesis.specular_near(P, N, camera, lamp, {**bsdf, key: 0.0})))
    assert np.all(np.isnan(resynthesis.specular_distant(N, [0, 0.3, 1], [0, -0.6, 1], {**bsdf, key: 0.0})))
    assert np.array_equal(resynthesis.specular_near(P, N, camera, lamp, {**bsdf, key: -bsdf[key]}),
                          resynthesis.specular_near(P, N, camera, lamp, bsdf))


@pytest.mark.parametrize("model", MODELS)
def test_a_lamp_on_a_surface_point_makes_that_pixel_nan_only_for_every_family(model, rng):
    P = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
    N = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, -0.6, 0.8]])
    img = resynthesis.specular_near(P, N, [0.0, -0.3, 0.5], P[0], _family_bsdf(model, rng))
    # the second point: lamp in its plane, unlit; the third: tilted towards the camera, lamp above its plane, lit
    assert np.all(np.isnan(img[0])) and np.all(img[1] == 0) and np.all(img[2] > 0)


@pytest.mark.parametrize("model", MODELS)
def test_a_result_row_gives_back_the_fitted_family_and_renders_it(model):
    """A row records σ and Ks as the Torrance–Sparrow equivalent and ``est_lobe`` the family: ``row_estimate``
    converts back (:func:`convert_bsdf` both ways: float64 rounding, ~1e-16 relative), so the re-synthesis of
    a row, by the grader and by the estimator's own ``render_specular`` (the reproduction's figures), is the
    fitted lobe's, within that rounding (rtol 1e-12); a row of another method (``torrance_sparrow``) or written
    before the column existed reads as Torrance–Sparrow, exactly as before."""
    import pandas as pd

    from nearlight.evaluation.engine.run import row_estimate
    from nearlight.evaluation.scoring.metrics import estimate_columns

    cap, bsdf = _family_capture(model)
    fit = _full_estimate(np.asarray(cap.truth["lamp_position"]), _reported(cap, bsdf))
    row = pd.Series({"method": "full", **estimate_columns(fit)})
    assert row["est_lobe"] == model
    back = row_estimate(row)
    observed = cap.extra["truth_specular"].astype(float)
    for render in (resynthesize, render_specular):
        np.testing.assert_allclose(render(cap, back), render(cap, fit), rtol=1e-12, atol=1e-14 * observed.max())
    assert score(cap, back)["specular_rmse_rel"] < 1e-6
    old = row_estimate(row.drop("est_lobe"))
    assert old.stages == {} and np.array_equal(resynthesize(cap, old), resynthesize(cap, Estimate(
        method="full", lamp_position=fit.lamp_position, ks=fit.ks, sigma=fit.sigma)))
