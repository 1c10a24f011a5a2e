"""The Cramér–Rao bound with range noise (nearlight.evaluation.scoring.range_bound) against its limits."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.evaluation.scoring.crlb import camera_noise_variance, specular_crlb
from nearlight.evaluation.scoring.range_bound import range_crlb, surface_family
from nearlight.generator.analytic import analytic_capture

LOW = {"full_well": 50000, "read_noise": 3.0, "bits": 14}  # sweeps/sensitivity.yaml's "low" camera noise


@pytest.fixture(scope="module", params=["board", "sphere"])
def clean(request):
    return analytic_capture(shape=request.param, width=120, height=90)


def test_the_family_is_read_off_the_exact_points(clean):
    family, s = surface_family(np.asarray(clean.P, float)[clean.surface_mask], clean.camera.position)
    if family == "sphere":
        assert s == pytest.approx([0.0, 0.0, 0.15, 0.15], abs=1e-6)  # analytic_capture's sphere, float32 P
    else:
        assert family == "plane"
        P = np.asarray(clean.P, float)[clean.surface_mask]
        assert np.max(np.abs((P - clean.camera.position) @ s - 1.0)) < 1e-6


def test_a_vanishing_range_noise_gives_the_exact_surface_bound(clean):
    """σ → 0: the range pins the surface, and the bound is specular_crlb's (surface taken as exact)."""
    nv = camera_noise_variance(clean.stack, noise=LOW)
    exact = specular_crlb(clean, noise_var=nv)
    tiny = range_crlb(clean, noise_var=nv, range_sigma_m=1e-9)
    # 1 nm of range noise moves the bound by ~(1e-9 / 2e-4)² of the 0.2 mm row's change: nothing at 1e-5
    assert tiny["crlb_lamp_m"] == pytest.approx(exact["crlb_lamp_m"], rel=1e-5)
    assert tiny["crlb_sigma_rel"] == pytest.approx(exact["crlb_sigma_rel"], rel=1e-5)


def test_the_bound_grows_with_the_range_noise(clean):
    nv = camera_noise_variance(clean.stack, noise=LOW)
    bounds = [range_crlb(clean, noise_var=nv, range_sigma_m=s)["crlb_lamp_m"] for s in (5e-5, 2e-4, 1e-3, 5e-3)]
    assert np.all(np.diff(bounds) > 0), bounds
    z = range_crlb(clean, noise_var=nv, range_sigma_m=1e-3, axis="z")["crlb_lamp_m"]
    assert np.isfinite(z) and z > bounds[0]


def test_a_surface_of_no_family_has_no_bound_and_says_why():
    clean = analytic_capture(shape="sphere", width=80, height=60)
    P = np.array(clean.P, dtype=float)
    P[..., 2] += 0.01 * np.maximum(P[..., 0], 0.0)  # a crease along x = 0
    out = range_crlb(clean.replace(P=P), noise_var=1e-6, range_sigma_m=2e-4)
    assert np.isnan(out["crlb_lamp_m"]) and "neither a plane nor a sphere" in out["reason"]


def test_bad_arguments_are_refused():
    clean = analytic_capture(shape="board", width=40, height=30)
    with pytest.raises(ValueError, match="range_sigma_m"):
        range_crlb(clean, noise_var=1e-6, range_sigma_m=0.0)
    with pytest.raises(ValueError, match="axis"):
        range_crlb(clean, noise_var=1e-6, range_sigma_m=1e-4, axis="x")


def test_a_sweep_rows_bound_is_the_range_aware_one_where_its_range_is_noisy(clean):
    """The CRLB columns of a sweep's row (engine.tasks): the exact-surface bound without range error, this one with
    the task's Gaussian range noise and the scene's quantum combined as √(σ² + q²/12) along the ray."""
    from nearlight.evaluation.engine.tasks import _crlb

    nv = camera_noise_variance(clean.stack, noise=LOW)
    task = {"crlb": True, "noise": LOW, "range_noise": 0.0, "scene": {}}
    assert _crlb(clean, task) == specular_crlb(clean, noise_var=nv)
    noisy = _crlb(clean, {**task, "range_noise": 2e-4})
    assert noisy["crlb_lamp_m"] == range_crlb(clean, noise_var=nv, range_sigma_m=2e-4)["crlb_lamp_m"]
    both = _crlb(clean, {**task, "range_noise": 2e-4, "scene": {"nuisances": {"range": {"quantum_m": 1e-3}}}})
    sigma = np.hypot(2e-4, 1e-3 / np.sqrt(12))
    assert both["crlb_lamp_m"] == range_crlb(clean, noise_var=nv, range_sigma_m=sigma)["crlb_lamp_m"]
    assert both["crlb_lamp_m"] > noisy["crlb_lamp_m"] > specular_crlb(clean, noise_var=nv)["crlb_lamp_m"]
