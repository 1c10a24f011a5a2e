"""The paper's method: t search, regression (eq. 11–17) and the AM of eq. 18."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.estimator.observation import observation_of
from nearlight.estimator.first_stage import RaySearch, fast_search, initial_estimate, scan_search, stage_one
from nearlight.estimator.paper import Energy, alternating_minimisation
from nearlight.estimator.fitting import log_regression
from nearlight.generator.analytic import analytic_capture

TS = {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.06}


def _exact_ray(capture):
    """The true mirror point on the board (z = 0 plane) and the unit direction to the lamp."""
    lamp = np.array(capture.truth["lamp_position"])
    cam = np.asarray(capture.camera.position)
    mirrored = cam * [1, 1, -1]
    point = lamp + lamp[2] / (lamp[2] + cam[2]) * (mirrored - lamp)
    d = lamp - point
    return point, d / np.linalg.norm(d), float(np.linalg.norm(d))


def _on_exact_ray(capture):
    obs = observation_of(capture)
    origin, direction, t_true = _exact_ray(capture)
    ray = RaySearch(obs)
    ray.origin, ray.direction = origin, direction
    return obs, ray, t_true


def test_stage_one_is_exact_on_the_exact_mirror_ray():
    # On the true mirror ray the noise-free (X, Y_m) points are exactly collinear at the true t
    # (eq. 11), so E_p = −3 there and the regression returns Ks, σ (Ks absorbs I_lamp/2 = 1).
    cap = analytic_capture(bsdf=TS, analyzer_angles_deg=None)
    obs, ray, t_true = _on_exact_ray(cap)
    found = fast_search(ray.ep, t_max=2.0, dt=1e-3)
    assert abs(found["t"] - t_true) <= 1e-3
    X, Y = ray.xy(np.array([t_true]))
    ks, sigma, _ = log_regression(X[0], Y[0])
    # float32 P/N/specular: ln I to ~1e-7, so slopes and intercepts to ~1e-5 relative.
    np.testing.assert_allclose(ks, TS["ks"], rtol=1e-4)
    assert sigma == pytest.approx(TS["sigma"], rel=1e-4)
    assert ray.ep(np.array([t_true]))[0] == pytest.approx(-3.0, abs=1e-6)


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"bsdf": TS},
        {"shape": "sphere"},
        {"shape": "sphere", "bsdf": TS, "lamp_position": (0.15, -0.1, 0.45)},
        {"lamp_position": (-0.1, 0.3, 0.8)},
    ],
    ids=["board", "board-sharp", "sphere", "sphere-sharp", "board-far-lamp"],
)
def test_fast_search_matches_plain_scan(kwargs):
    cap = analytic_capture(width=96, height=72, **kwargs)
    obs = observation_of(cap)
    ray = RaySearch(obs)
    t_max, dt = 3.0, 1e-3
    scan = scan_search(ray.ep, t_max=t_max, dt=dt)
    n_scan = ray.evaluations
    fast = fast_search(ray.ep, t_max=t_max, dt=dt)
    assert abs(fast["t"] - scan["t"]) <= dt
    assert ray.evaluations - n_scan < n_scan / 20  # at least 20x fewer E_p evaluations


PAPER_INIT_CASES = [
    ("board", {"sigma": 0.06}, {}),
    ("board", {"sigma": 0.1}, {}),
    ("sphere", {"sigma": 0.1}, {}),
    ("sphere", {"sigma": 0.06}, {"lamp_position": (0.1, 0.1, 0.6)}),
    ("sphere", {"sigma": 0.1}, {"lamp_position": (0.1, 0.1, 0.6)}),
    ("sphere", {"sigma": 0.1}, {"lamp_position": (0.2, -0.2, 0.4)}),
]


def test_paper_init_reaches_the_papers_class_of_error():
    # End to end the ray starts at the peak pixel, which is not the mirror point: the 1/cos θr
    # and 1/r² factors move the intensity peak (0.5–2° of ray direction here), and E_p(t) is
    # so flat near its minimum that t moves a lot. Measured with this code (noise-free,
    # 160x120): board 52 %, 45 %; spheres 8 %, 11 %, 17 %, 15 % of the lamp distance; the paper
    # reports 9 % on its RADIANCE board. Bounds: the best case is in the paper's class (< 12 %),
    # the median is < 30 %, none is off by more than 60 %.
    errs = []
    for shape, lobe, kwargs in PAPER_INIT_CASES:
        cap = analytic_capture(shape=shape, bsdf={**TS, **lobe}, **kwargs)
        est = initial_estimate(cap)
        lamp = np.array(cap.truth["lamp_position"])
        origin = np.asarray(est.diagnostics["ray_origin"])
        errs.append(np.linalg.norm(est.lamp_position - lamp) / np.linalg.norm(lamp - origin))
        # the estimate lies on the peak ray by construction (eq. 9)
        d = est.lamp_position - origin
        np.testing.assert_allclose(d / np.linalg.norm(d), est.diagnostics["ray_direction"], atol=1e-12)
    print("paper-init relative lamp errors:", np.round(errs, 3))
    assert min(errs) < 0.12
    assert np.median(errs) < 0.3
    assert max(errs) < 0.6


@pytest.mark.parametrize("space", ["ratio", "ratio-t", "radiance"])
@pytest.mark.parametrize("exact", [True, False], ids=["exact-ray", "peak-ray"])
def test_am_never_increases_energy(space, exact):
    cap = analytic_capture(width=96, height=72, bsdf=TS)
    init, obs = stage_one(cap)
    if exact:
        origin, direction, t_true = _exact_ray(cap)
        ks0, sigma0, t0 = np.array(TS["ks"]) * 1.1, TS["sigma"] * 1.1, t_true + 0.005
    else:
        origin, direction = init.diagnostics["ray_origin"], init.diagnostics["ray_direction"]
        ks0, sigma0, t0 = init.ks, init.sigma, init.stages["init"]["t"]
    energy = Energy(obs, np.asarray(origin), np.asarray(direction), space=space, t_ref=t0)
    am = alternating_minimisation(energy, ks=ks0, sigma=sigma0, t=t0, dt=1e-3, max_outer=400)
    e = am["energy"]
    assert len(e) > 2
    assert np.all(np.diff(e) <= 1e-12 * e[0])
    assert e[-1] < e[0]
    if exact and space != "ratio":  # "ratio" measures E at t0, not at the truth
        # From 10 % / 10 % / 5 mm off on the true ray, the AM walks back to the truth: t to within
        # Δt, σ and Ks to 1e-4 (t_true is 0.4 mm from the grid; measured 3e-7 and 6e-7).
        # From 20 mm off it stalls 13–17 mm short (measured): with Ks, σ fitted to the current
        # t, both t ± Δt cost energy — a coordinate-wise minimum of the paper's AM.
        assert am["converged"]
        assert abs(am["t"] - t_true) <= 1e-3
        assert am["sigma"] == pytest.approx(TS["sigma"], rel=1e-4)
        np.testing.assert_allclose(am["ks"], TS["ks"], rtol=1e-4)


def test_paper_ratio_t_energy_drifts_towards_the_surface():
    # With E = I_s r(t)² re-measured at every t, E shrinks as t does: when the peak ray misses
    # the lamp (always, end to end), the AM walks t towards 0. The default reading of eq. 18
    # (E measured once at t*) and energy="radiance" (image-space residuals) do not drift.
    cap = analytic_capture(width=96, height=72, bsdf=TS)
    from nearlight.estimator import estimate

    drift = estimate(cap, method="paper", energy="ratio-t")
    t0 = drift.stages["init"]["t"]
    assert drift.stages["am"]["t"] < 0.2 * t0
    for energy in ("ratio", "radiance"):
        est = estimate(cap, method="paper", energy=energy)
        assert abs(est.stages["am"]["t"] - t0) < 0.5 * t0
