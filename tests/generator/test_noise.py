"""Camera and range noise (numpy only: synthetic captures, no rendering)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import special, stats

from nearlight.capture import Camera, Capture, read_capture
from nearlight.generator import add_camera_noise, add_range_noise
from nearlight.generator.noise import EXACT_POISSON_BELOW, noise_rngs, shot_electrons
from nearlight.physics.camera import AUTO_EXPOSURE
from nearlight.generator.analytic import analytic_capture

ROOT = Path(__file__).resolve().parents[2]


def flat_capture(value: float, *, h: int = 200, w: int = 250, k: int = 2) -> Capture:
    ys, xs = np.mgrid[0:h, 0:w]
    P = np.stack([xs * 1e-3 - 0.1, ys * 1e-3 - 0.1, np.full((h, w), 0.5)], -1)
    P[0, 0] = np.nan  # one background pixel
    return Capture(
        width=w, height=h, camera=Camera(position=np.zeros(3)), P=P, N=np.broadcast_to([0.0, 0.0, -1.0], P.shape).copy(),
        stack=np.full((k, h, w, 3), value, np.float32), analyzer_angles_deg=np.arange(k) * 90.0,
        extra={"truth_specular": np.full((h, w, 3), value, np.float32)},
    )  # fmt: skip


def test_shot_and_read_noise_variance():
    # 1000 expected electrons per pixel, read noise 30 e-: variance 1000 + 900 e-² (Poisson + Gaussian).
    # 300k samples: the relative standard error of a sample variance is sqrt(2/n) = 0.26 %; tolerance 2 %.
    cap = flat_capture(0.5)
    noise = {"full_well": 1000 / 0.5, "read_noise": 30.0, "bits": 24, "saturation": 1.0}
    out = add_camera_noise(cap, noise=noise, seed=1)
    electrons = out.stack.astype(float) / 1.0 * 2000
    assert electrons.mean() == pytest.approx(1000, rel=0.002)
    assert electrons.var() == pytest.approx(1900, rel=0.02)
    assert np.array_equal(out.extra["truth_specular"], cap.extra["truth_specular"])  # truth is never noisy
    assert out.meta["noise"]["camera"]["seed"] == 1


def test_quantisation_and_saturation():
    cap = flat_capture(0.3)
    cap.stack[1] = 5.0  # above saturation
    out = add_camera_noise(cap, noise={"full_well": 1e5, "read_noise": 0, "bits": 4, "saturation": 1.0}, seed=0)
    levels = out.stack * 15  # a 4-bit ADC: 16 levels over [0, saturation]
    assert np.allclose(levels, np.round(levels), atol=1e-5)
    assert np.all(out.stack[1] == 1.0)  # clipped at the full well
    assert np.unique(out.stack[0]).size <= 2  # 0.3·15 = 4.5 ± shot noise of 3e4 e-: levels 4 and 5 only


def test_auto_saturation_exposes_the_brightest_pixel_at_90_percent():
    cap = flat_capture(0.2)
    cap.stack[0, 10, 10] = 2.0
    out = add_camera_noise(cap, noise={"full_well": 1e6, "read_noise": 0, "bits": 16}, seed=0)
    assert out.meta["noise"]["camera"]["saturation"] == pytest.approx(2.0 / AUTO_EXPOSURE)
    assert out.stack[0, 10, 10] == pytest.approx(2.0, rel=0.01)


def test_noise_is_seeded():
    cap = flat_capture(0.4)
    noise = {"read_noise": 5.0}
    a, b = (add_camera_noise(cap, noise=noise, seed=7) for _ in range(2))
    c = add_camera_noise(cap, noise=noise, seed=8)
    assert np.array_equal(a.stack, b.stack) and not np.array_equal(a.stack, c.stack)
    assert add_camera_noise(cap, noise=None, seed=7) is cap


def test_range_noise_moves_points_along_camera_rays_and_drops_normals():
    cap = flat_capture(0.1)
    out = add_range_noise(cap, sigma_m=0.002, seed=3)
    m = cap.surface_mask
    d = out.P[m] - cap.P[m]
    ray = cap.P[m] / np.linalg.norm(cap.P[m], axis=-1, keepdims=True)  # camera at the origin
    along = np.sum(d * ray, axis=-1)
    assert np.abs(np.cross(d, ray)).max() < 1e-6  # float32 P: only the along-ray component
    assert along.std() == pytest.approx(0.002, rel=0.02)  # 50k draws: std error 0.3 %
    assert out.N is None and np.array_equal(out.extra["truth_N"], cap.N)
    assert np.isnan(out.P[0, 0]).all()
    assert add_range_noise(cap, sigma_m=0.0, seed=3) is cap


# --- continuity in the render, the shot-noise quantile, the seed rule (nearlight.generator.noise's docstring) ---


def _adc_codes(out: Capture, noise: dict) -> np.ndarray:
    """The ADC codes behind a noisy stack: ``stack / saturation · (2^bits − 1)``, as integers."""
    sat = out.meta["noise"]["camera"]["saturation"]
    return np.rint(out.stack.astype(np.float64) / sat * (2 ** noise["bits"] - 1)).astype(np.int64)


@pytest.mark.parametrize(
    "noise",
    [
        # the default camera: the highlight near the full well, nearly every pixel on the expansion branch
        {"full_well": 20000.0, "read_noise": 5.0, "bits": 12, "saturation": "auto"},
        # photon-starved: the peak at 45 e-, most pixels on the exact Poisson branch, an ADC step of 0.012 e-,
        # so a one-electron jump of the exact quantile is ~80 steps
        {"full_well": 50.0, "read_noise": 0.5, "bits": 12, "saturation": "auto"},
    ],
)
def test_a_last_bit_change_of_the_render_moves_the_noise_by_at_most_one_adc_step(noise, rng):
    # A different CPU renders the same scene with other last bits (docs/physics.md, "Facts measured"): move every
    # pixel by one float32 ulp, up or down at random (relative <= 1.2e-7; `auto` saturation moves with the
    # peak). With the same draws the expansion branch and the read noise are continuous in the clean value, so
    # the ADC code can only tick over a rounding threshold (<= 1 step). Only the exact Poisson quantile
    # (lam < 20 e-) can jump, by one electron: it does where u falls between P(k; lam) and P(k; lam + dlam)
    # for some k, probability sum_k pmf(k)·|dlam| = |dlam| <= 20 · 1.2e-7 = 2.4e-6 per pixel. So the expected
    # fraction beyond one step is < 3e-6, and we ask >= 99.99 % (a margin of ~40 over that bound).
    # Measured with this perturbation: this code 100 % and 99.99995 %; numpy's old Poisson sampler, which
    # re-draws every pixel after its first lost sync, 97.9 % on the default camera (and 99.997 % photon-starved,
    # where its first lost sync came late).
    clean = analytic_capture(width=320, height=240, analyzer_angles_deg=np.arange(8) * 22.5)
    up = rng.random(clean.stack.shape) < 0.5
    bumped = clean.replace(stack=np.where(up, np.nextafter(clean.stack, np.float32(np.inf)),
                                          np.nextafter(clean.stack, np.float32(-np.inf))).astype(np.float32))  # fmt: skip
    assert np.all(bumped.stack != clean.stack)
    a = _adc_codes(add_camera_noise(clean, noise=noise, seed=3), noise)
    b = _adc_codes(add_camera_noise(bumped, noise=noise, seed=3), noise)
    within_one_step = np.mean(np.abs(a - b) <= 1)
    assert within_one_step >= 0.9999, within_one_step
    # a different seed is a different draw: the same measure then fails (so the test can)
    c = _adc_codes(add_camera_noise(clean, noise=noise, seed=4), noise)
    assert np.mean(np.abs(a - c) <= 1) < 0.9


def test_shot_noise_is_the_exact_poisson_quantile_below_the_threshold(rng):
    # golden: scipy.stats.poisson.ppf of the same uniform u = Φ(z); below the threshold the sampler is exact
    lam = rng.uniform(0.0, EXACT_POISSON_BELOW, 200_000)
    lam[:10] = [0.0, 1e-300, 1e-9, 0.5, 1.0, 2.0, 5.0, 10.0, np.nextafter(EXACT_POISSON_BELOW, 0), 19.5]
    z = rng.standard_normal(lam.size)
    z[10:16] = [-8.0, -5.0, 0.0, 5.0, 7.0, 8.0]
    expected = stats.poisson.ppf(np.minimum(special.ndtr(z), 1 - 1e-12), lam)
    assert np.array_equal(shot_electrons(lam, z), expected)


def test_shot_noise_expansion_stays_within_its_documented_bound_of_the_exact_quantile():
    # The module docstring's bound: for lam >= EXACT_POISSON_BELOW and |z| <= 6 the Cornish–Fisher sample is
    # within 0.9 electron of the exact quantile of the same u (0.5 of it the quantile's integer step),
    # measured against scipy.stats.poisson.ppf on a fine grid. It also bounds the jump at the threshold.
    z = np.linspace(-6.0, 6.0, 6001)
    u = special.ndtr(z)
    for lam in (EXACT_POISSON_BELOW, 20.5, 25.0, 40.0, 100.0, 1e3, 1e5):
        err = np.abs(shot_electrons(np.full(z.shape, lam), z) - stats.poisson.ppf(u, lam))
        assert err.max() < 0.9, (lam, err.max())
    below = shot_electrons(np.full(z.shape, np.nextafter(EXACT_POISSON_BELOW, 0)), z)
    at = shot_electrons(np.full(z.shape, EXACT_POISSON_BELOW), z)
    assert np.abs(at - below).max() < 0.9


@pytest.mark.parametrize(
    ("lam", "read_noise"),
    [(3.0, 0.0), (np.nextafter(EXACT_POISSON_BELOW, 0), 0.0), (EXACT_POISSON_BELOW, 0.0), (1000.0, 30.0)],
)
def test_noisy_electrons_have_the_moments_of_poisson_plus_read_noise(lam, read_noise):
    # Golden: Poisson(lam) + N(0, r²) has cumulants k1 = k3 = k4 = k6 = lam, k2 = lam + r² (the Gaussian adds
    # to k2 only). The clean value 0.01 of saturation 1 keeps every draw far from the full well (100·lam) and,
    # with read noise only at lam = 1000 (23 sd above 0), from 0: no clipping. The 24-bit ADC adds a variance
    # (fw/2^24)²/12 <= 3e-6 e-², float32 storage a relative 6e-8: both negligible. 300k samples; each tolerance is 5 standard errors of the sample statistic
    # (a false alarm below 1e-6): mean sqrt(k2/n); variance sqrt((m4 − m2²)/n); third central moment
    # sqrt((m6 − m3² − 6·m4·m2 + 9·m2³)/n), central moments m from the cumulants. A plain Gaussian shot noise
    # (third moment 0) fails the last check at lam = 20 by ~45 standard errors.
    cap = flat_capture(0.01)  # 2 x 200 x 250 x 3 samples, all at 0.01 (noise ignores P)
    noise = {"full_well": 100.0 * lam, "read_noise": read_noise, "bits": 24, "saturation": 1.0}
    e = add_camera_noise(cap, noise=noise, seed=11).stack.astype(np.float64).ravel() * noise["full_well"]
    n = e.size
    k2 = lam + read_noise**2
    m2, m3, m4 = k2, lam, lam + 3 * k2**2
    m6 = lam + 15 * lam * k2 + 10 * lam**2 + 15 * k2**3
    d = e - e.mean()
    assert e.mean() == pytest.approx(lam, abs=5 * np.sqrt(k2 / n))
    assert np.mean(d**2) == pytest.approx(m2, abs=5 * np.sqrt((m4 - m2**2) / n))
    assert np.mean(d**3) == pytest.approx(m3, abs=5 * np.sqrt((m6 - m3**2 - 6 * m4 * m2 + 9 * m2**3) / n))


def test_low_counts_follow_the_poisson_pmf():
    # lam = 3, no read noise, a 24-bit ADC: the recorded electrons are integers with Poisson(3) frequencies.
    # Golden: scipy.stats.poisson.pmf; 300k samples, 5 binomial standard errors sqrt(p(1 − p)/n) per count.
    cap = flat_capture(0.01)
    noise = {"full_well": 300.0, "read_noise": 0.0, "bits": 24, "saturation": 1.0}
    e = add_camera_noise(cap, noise=noise, seed=5).stack.astype(np.float64).ravel() * 300.0
    k = np.rint(e)
    assert np.abs(e - k).max() < 1e-3  # ADC step 300/2^24 = 2e-5 e-
    freq = np.bincount(k.astype(int), minlength=12)[:12] / k.size
    p = stats.poisson.pmf(np.arange(12), 3.0)
    assert np.all(np.abs(freq - p) <= 5 * np.sqrt(p * (1 - p) / k.size) + 1e-12)


def test_noise_rngs_are_independent_streams_of_one_seed():
    cam, rng_ = noise_rngs(3)
    cam2, _ = noise_rngs(3)
    a, b, c = cam.standard_normal(1000), rng_.standard_normal(1000), cam2.standard_normal(1000)
    assert np.array_equal(a, c) and not np.array_equal(a, b)
    assert not np.array_equal(noise_rngs(4)[0].standard_normal(1000), a)


def test_render_and_a_sweep_task_with_the_same_seed_make_the_same_noisy_capture(tmp_path, monkeypatch):
    # The one seed rule (nearlight.generator.noise): `nearlight render --set capture.seed=3` and a sweep task
    # with seed 3 on the same clean render see the same camera and range noise. No Mitsuba: the render is an
    # analytic capture standing in for render_clean.
    from nearlight.evaluation.engine.tasks import noisy_capture
    from nearlight.generator import load_scene, pipeline

    clean = analytic_capture(width=64, height=48, analyzer_angles_deg=np.arange(8) * 22.5)
    noise = {"full_well": 5000.0, "read_noise": 3.0, "bits": 12, "saturation": "auto"}
    scene = load_scene(ROOT / "scenes" / "ts_board.yaml",
                       overrides={"capture.seed": 3, "capture.noise": noise, "capture.range_noise_m": 0.001})  # fmt: skip
    monkeypatch.setattr(pipeline, "render_clean", lambda *a, **k: clean)
    rendered = read_capture(pipeline.render_capture(scene, tmp_path / "cap", progress=False))
    swept = noisy_capture(clean, {"noise": noise, "range_noise": 0.001, "seed": 3})
    assert not np.array_equal(swept.stack, clean.stack.astype(np.float32))
    assert np.array_equal(rendered.stack, swept.stack)
    assert np.array_equal(rendered.P, swept.P, equal_nan=True)
    other = noisy_capture(clean, {"noise": noise, "range_noise": 0.001, "seed": 4})
    assert not np.array_equal(rendered.stack, other.stack) and not np.array_equal(rendered.P, other.P, equal_nan=True)
