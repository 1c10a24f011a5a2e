"""Camera and range noise (numpy only: synthetic captures, no rendering)."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.capture import Camera, Capture
from nearlight.generator import add_camera_noise, add_range_noise
from nearlight.generator.noise import AUTO_EXPOSURE


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
