"""The grading re-synthesis: a second implementation that agrees with the first, and its defined edges.

``nearlight.evaluation.resynthesis`` is written apart from ``nearlight.physics.reflectance`` on purpose
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
from nearlight.evaluation import resynthesis
from nearlight.evaluation.metrics import truth_estimate
from nearlight.evaluation.resynthesis import resynthesize, ts_specular_distant, ts_specular_near
from nearlight.generator.analytic import analytic_capture
from nearlight.physics.reflectance import specular_radiance

#: Two float64 implementations of one formula: they differ by rounding only. Measured: ≤ 4e-14 relative
#: (α by arccos against atan2 near α = 0, Ks / cos θr against Ks cos θi / (cos θi cos θr)).
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
    estimates += [estimate(cap, method="distant"), estimate(cap, method="paper-init")]  # as the methods write them
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
