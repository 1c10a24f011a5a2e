"""``full``'s errors-in-variables fit (nearlight.estimator.joint_surface) on closed-form captures, no Mitsuba.

Every capture is ``analytic_capture``'s board or sphere at 160×120 (exact
``P`` and ``N``, float32 as the generator writes them), its range perturbed
by ``generator.range_sensor.perturb_range``. Golden values were measured at
main d9fa5c3 with this change (the numbers in each test's comment); each
tolerance is a stated multiple of the measured value or a limit float32
sets. The coverage of the joint covariance over many seeds is a benchmark's
(``benchmarks/bench_range_bound.py``), not a test's.
"""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.estimator.fitting import robust_fit
from nearlight.estimator.full import full_estimate
from nearlight.estimator.geometry import capture_rays, surface_geometry
from nearlight.estimator import full as full_module
from nearlight.estimator.whole_surface import on_rays, sphere_turn
from nearlight.generator.analytic import DEFAULT_LAMP_POSITION
from nearlight.generator.noise import add_camera_noise
from nearlight.generator.range_sensor import perturb_range

LOW_NOISE = {"full_well": 50000, "read_noise": 3.0, "bits": 14}  # sweeps/sensitivity.yaml's "low"


def _error_m(est) -> float:
    return float(np.linalg.norm(np.asarray(est.lamp_position, float) - DEFAULT_LAMP_POSITION))


def test_on_rays_meets_plane_and_sphere_with_normals_towards_the_origin():
    rng = np.random.default_rng(0)
    o = np.array([0.1, -0.2, 0.3])
    rays = rng.normal(size=(50, 3)) * [0.2, 0.2, 1.0] + [0, 0, 3.0]
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    m = np.array([0.05, -0.1, 1.25])  # the plane m·(X − o) = 1, 0.8 m ahead
    t, n = on_rays("plane", m, o, rays)
    X = o + t[:, None] * rays
    np.testing.assert_allclose((X - o) @ m, 1.0, rtol=1e-12)
    np.testing.assert_allclose(n, np.broadcast_to(-m / np.linalg.norm(m), n.shape), atol=1e-15)
    c, R = np.array([0.1, -0.2, 1.3]), 0.3  # straight ahead of o: every ray within ~0.4 rad of +z meets it
    g = np.concatenate([c, [R]])
    t, n = on_rays("sphere", g, o, rays)
    hit = np.isfinite(t)
    assert hit.sum() > 10 and np.all(t[hit] > 0)
    X = o + t[hit, None] * rays[hit]
    np.testing.assert_allclose(np.linalg.norm(X - c, axis=1), R, rtol=1e-12)
    assert np.all(np.sum(n[hit] * rays[hit], axis=1) < 0)  # the near side faces the origin
    t_far, n_far = on_rays("sphere", g, o, rays, near=np.full(len(rays), 2.0))
    assert np.all(t_far[hit] > t[hit]) and np.all(np.sum(n_far[hit] * rays[hit], axis=1) < 0)


def test_sphere_turn_is_the_normals_turn_for_a_small_change():
    """The linearised s.d. of the sphere's normals (:func:`sphere_turn`) against the exact turn of ``on_rays``'s
    normals when ``g`` moves by 1e-3 of each principal axis of its covariance, summed in quadrature and scaled back
    (the angle is linear in so small a change: its second order is ~1e-3 of it). Rays within ~0.4 rad of the
    sphere's centre, off its silhouette (``N·r`` ≤ −0.2)."""
    rng = np.random.default_rng(3)
    o = np.zeros(3)
    rays = rng.normal(size=(200, 3)) * [0.1, 0.1, 1.0] + [0, 0, 5.0]
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    g = np.array([0.02, -0.01, 1.0, 0.3])
    A = rng.normal(size=(4, 4)) * 1e-3
    cov = A @ A.T
    t, n = on_rays("sphere", g, o, rays)
    keep = np.isfinite(t) & (np.sum(n * rays, axis=1) <= -0.2)
    rays, t, n = rays[keep], t[keep], n[keep]
    vals, vecs = np.linalg.eigh(cov)
    turn2 = np.zeros(len(t))
    for k in range(4):
        nk = on_rays("sphere", g + 1e-3 * vecs[:, k] * np.sqrt(vals[k]), o, rays)[1]
        turn2 += (np.arctan2(np.linalg.norm(np.cross(nk, n), axis=1), np.sum(nk * n, axis=1)) / 1e-3) ** 2
    np.testing.assert_allclose(sphere_turn(o + t[:, None] * rays, rays, g, cov), np.sqrt(turn2), rtol=5e-3)


def test_the_sandwich_counts_prior_terms_by_their_expected_square():
    """A linear problem: observations ``y = A x + e`` and a prior ``x ~ N(x_p, I)`` whose centre falls ~10 s.d.
    off. The covariance is the closed form ``(JᵀJ)⁻¹ Jᵀ W J (JᵀJ)⁻¹ · n/(n − p)``, ``W`` the residuals' squares;
    with ``prior_rows`` the prior's terms count with their expected square (1) instead of their one draw each."""
    rng = np.random.default_rng(1)
    A = rng.normal(size=(40, 3))
    y = A @ [1.0, 2.0, 3.0] + rng.normal(size=40)
    centre = np.array([8.0, -6.0, 15.0])

    def fun(x):
        return np.concatenate([A @ x - y, x - centre])

    J = np.vstack([A, np.eye(3)])
    Hinv = np.linalg.inv(J.T @ J)
    sd = {}
    for rows in (0, 3):
        fit = robust_fit(fun, np.zeros(3), typical=np.ones(3), lower=np.full(3, -np.inf), upper=np.full(3, np.inf),
                         loss="linear", prior_rows=rows, prior_var=1.0)
        r2 = fun(fit["x"]) ** 2
        w = np.concatenate([r2[:40], np.ones(3)]) if rows else r2
        np.testing.assert_allclose(fit["cov"], Hinv @ (J.T * w) @ J @ Hinv * 43 / 40, rtol=1e-8)
        sd[rows] = np.sqrt(np.diag(fit["cov"]))
    assert np.all(sd[0] > 1.3 * sd[3])  # the realized prior terms (measured 1.5-2.3x) would inflate it

def _covariance_warnings(est) -> list[str]:
    return [w for w in est.diagnostics.get("warnings", []) if w.startswith("covariance:")]


def test_auto_refines_the_surface_only_for_a_range_with_error(board):
    exact = full_estimate(board.replace(N=None))
    assert exact.stages["full"]["surface_fit"] == "fixed" and "below" in exact.stages["full"]["surface_fit_reason"]
    assert not _covariance_warnings(exact)  # the range's error (measured 1.5e-9 m) is float32's
    noisy = perturb_range(board, sigma_m=1e-3, seed=0)
    joint = full_estimate(noisy)
    stage = joint.stages["full"]
    assert stage["surface_fit"] == "joint" and stage["surface_parameters"]["kind"] == "plane"
    assert stage["surface_fit_reason"] == "one plane fitted to a range with error 0.001 m"
    assert not _covariance_warnings(joint)
    fixed = full_estimate(noisy, surface="fixed")
    assert fixed.stages["full"]["surface_fit"] == "fixed" and fixed.stages["full"]["surface_parameters"] is None
    # the surface taken as given from a noisy range: the ellipsoid is the image's alone, and the estimate says so
    assert _covariance_warnings(fixed) == ["covariance: the image's share only; the plane surface fitted to a range "
                                           "with error 0.001 m was taken as given (its error moves the lamp beyond "
                                           "the stated ellipsoid)"]
    given = full_estimate(noisy.replace(N=board.N), surface="joint").stages["full"]  # the capture's own normals
    assert given["surface_fit"] == "fixed" and given["surface_fit_reason"] == "the capture's own normals"


def test_with_one_lobe_the_joint_fit_is_the_final_fit(board, monkeypatch):
    """A named lobe and the surface refined: the joint fit starts from the short fit and the image-only final fit
    does not run (it did before, then the joint fit from it: the same optimum, at the cost of a second fit). With
    two lobe families the image-only fits choose the lobe when both are refitted (their short fits' evidence
    within ``REFIT_EVIDENCE``), else the joint fit is again the only final fit."""
    cap = perturb_range(add_camera_noise(board, noise=LOW_NOISE, seed=0), sigma_m=1e-3, seed=0)
    real = full_module.final_fit
    calls = []

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(full_module, "final_fit", counted)
    one = full_estimate(cap, lobe="torrance_sparrow")
    assert one.stages["full"]["surface_fit"] == "joint" and not calls
    fixed = full_estimate(cap, lobe="torrance_sparrow", surface="fixed")
    assert len(calls) == 1
    # the joint fit corrects the surface's share: within the joint ellipsoid's 3 s.d. of the truth
    d = np.asarray(one.lamp_position, float) - DEFAULT_LAMP_POSITION
    assert d @ np.linalg.solve(np.asarray(one.covariance, float)[:3, :3], d) < 14.2  # chi-square(3) 0.997
    assert _error_m(fixed) > 0
    calls.clear()
    two = full_estimate(cap, lobe="torrance_sparrow+ward")
    assert two.stages["full"]["surface_fit"] == "joint"
    refitted = [k for k, v in two.stages["full"]["lobe_evidence"].items() if v < full_module.REFIT_EVIDENCE]
    assert len(calls) == (len(refitted) if len(refitted) > 1 else 0)


@pytest.mark.parametrize(("shape", "limit_m"), [("board", 1e-7), ("sphere", 2e-6)])
def test_the_joint_fit_is_exact_on_exact_data(shape, limit_m, request):
    """Forced on with an exact range: the lamp and the surface stay where the exact data put them. Measured: the
    lamp 2.0e-8 m (board), 3.6e-7 m (sphere) from the truth; the surface within 1e-8 of the range fit's. Float32
    ``P`` (6e-8 relative, ~1e-7 m at the scene's 1-2 m) is the floor; the image-only fit's own error on the same
    captures is 4.7e-6 % and 2.6e-4 % of the lamp distance."""
    clean = request.getfixturevalue(shape)
    est = full_estimate(clean.replace(N=None), surface="joint")
    stage = est.stages["full"]
    assert stage["surface_fit"] == "joint"
    assert _error_m(est) < limit_m
    g, g0 = stage["surface_parameters"]["g"], stage["surface_parameters"]["range_fit_g"]
    np.testing.assert_allclose(g, g0, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize(("shape", "sigma_m"), [("board", 1e-3), ("sphere", 3e-3)])
def test_the_image_corrects_the_range_fits_surface(shape, sigma_m, request):
    """No camera noise, a noisy range: with the surface as given the lamp carries the surface's error, with the
    surface refined the image pulls both back. Measured over seeds 0-2 (mm, fixed → joint): board at 1 mm 0.036,
    0.015, 0.054 → 0.003 each; sphere at 3 mm 0.445, 0.198, 0.245 → 0.055, 0.015, 0.049 (ratios 5-19). (The
    sphere's 4 parameters from ~10⁴ pixels leave the lamp within 0.01-0.1 mm at 1 mm of noise already.)"""
    clean = request.getfixturevalue(shape)
    for seed in range(3):
        cap = perturb_range(clean, sigma_m=sigma_m, seed=seed)
        fixed, joint = (_error_m(full_estimate(cap, surface=s)) for s in ("fixed", "joint"))
        assert joint < fixed / 2.5, (seed, fixed, joint)


def test_the_joint_covariance_is_the_propagated_one(board):
    """Low camera noise, 1 mm of range noise, seed 0: the joint fit's lamp covariance against the image-only
    covariance plus the surface's propagated, ``C_img + G C_g Gᵀ`` with ``G = ∂lamp/∂g`` by central differences of
    the image-only fit on surfaces moved by one s.d. of ``g`` each way. Both are linearisations of the same
    estimator, so they agree to second order in the surface error: measured s.d. along the two thin axes
    0.050, 0.077 mm (joint) vs 0.052, 0.082 (propagated); joint/propagated s.d. on the eigenaxes 0.96, 0.94, 1.00."""
    cap = perturb_range(add_camera_noise(board, noise=LOW_NOISE, seed=0), sigma_m=1e-3, seed=0)
    joint = full_estimate(cap)
    g0 = joint.stages["full"]["surface_parameters"]["range_fit_g"]
    cov_g = surface_geometry(cap).parameters.cov
    cam = np.asarray(board.camera.position, float)
    rays = capture_rays(board).reshape(-1, 3)
    off = ~np.all(np.isfinite(board.P), axis=-1)  # off the board: no point, as in the capture

    def image_only(g):
        t, n = on_rays("plane", g, cam, rays)
        P, N = ((cam + t[:, None] * rays).reshape(board.P.shape), n.reshape(board.P.shape))
        P[off], N[off] = np.nan, np.nan
        est = full_estimate(cap.replace(P=P.astype(np.float32), N=N.astype(np.float32)))
        return np.asarray(est.lamp_position, float), np.asarray(est.covariance, float)[:3, :3]

    _, c_img = image_only(g0)
    sd = np.sqrt(np.diag(cov_g))
    G = np.column_stack([(image_only(g0 + h)[0] - image_only(g0 - h)[0]) / (2 * h[i])
                         for i, h in enumerate(np.diag(sd))])
    propagated = c_img + G @ cov_g @ G.T
    c_joint = np.asarray(joint.covariance, float)[:3, :3]
    vals, vecs = np.linalg.eigh(propagated)
    ratio = np.sqrt(np.einsum("ij,jk,ki->i", vecs.T, c_joint, vecs) / vals)
    assert np.all((ratio > 0.85) & (ratio < 1.1)), ratio


@pytest.mark.parametrize(
    ("shape", "error", "k"),
    [("board", {"quantum_m": 1e-3, "axis": "z"}, 3), ("sphere", {"quantum_m": 1e-3, "axis": "z"}, 4),
     ("sphere", {"sigma_m": 1e-3}, 4)],
    ids=["board-z-1mm", "sphere-z-1mm", "sphere-gauss-1mm"],
)
def test_the_range_fits_covariance_covers_its_scatter(shape, error, k, request):
    """What the joint fit's prior needs: the range fit's ``ĝ`` scattered over seeds as its own ``C_g`` says. Mean
    squared Mahalanobis distance from the exact range's fit over 20 seeds, against the dimension ``k`` (a
    chi-square's mean; its s.e. over 20 seeds about √(2k/20) ≈ 0.6). Measured: board 1-mm steps 1.65 (one of its
    3 parameters held by the scene's symmetry), sphere 1-mm steps 1.81, sphere 1 mm of noise 4.12; before the
    staircase simulation and the sphere fit's normals from the sphere (40 seeds, their mean covariance): 26, 19
    and 22."""
    clean = request.getfixturevalue(shape)
    g0 = surface_geometry(clean.replace(N=None)).parameters.g
    m2 = []
    for seed in range(20):
        p = surface_geometry(perturb_range(clean, seed=seed, **error)).parameters
        d = p.g - g0
        m2.append(d @ np.linalg.solve(p.cov, d))
    assert np.mean(m2) < 1.5 * k


def test_lamps_auto_choosing_one_lamp_keeps_its_warnings(board):
    """``lamps=auto`` choosing one lamp is the one-lamp fit, warnings included (the surface as given: the image's
    share only; refined: none). Several lamps refining their surface: tests/estimator/test_several_lamps.py."""
    noisy = perturb_range(board, sigma_m=1e-3, seed=0)
    auto = full_estimate(noisy, lamps="auto", surface="fixed")
    assert auto.stages["full"]["n_lamps"] == 1 and len(_covariance_warnings(auto)) == 1
    assert not _covariance_warnings(full_estimate(noisy, lamps="auto"))
