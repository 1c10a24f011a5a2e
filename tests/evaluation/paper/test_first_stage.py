"""The first-stage study's analytic pieces (``nearlight.evaluation.paper.fidelity``), no renderer."""

from __future__ import annotations

from nearlight.evaluation.paper.fidelity import TS_BOARD, ep_curves
from nearlight.generator.analytic import analytic_capture


def test_ep_curves_the_mirror_ray_finds_the_lamp_the_peak_ray_does_not():
    # Noise-free TS board (the analytic default scene, σ = 0.05): along the exact mirror ray
    # E_p is smallest at the true t, to the curve's grid (160 log-spaced points over 0.05–4 t_true:
    # steps of 2.8 %); along the brightest pixel's ray at about 1/(1 + s) with s = 1 (t_star_curve
    # measured 0.39 there), well short of it.
    cap = analytic_capture(bsdf=TS_BOARD, analyzer_angles_deg=None)
    c = ep_curves(cap)
    assert set(c) == {"peak", "mirror", "delta_px"}
    assert 0.5 < c["delta_px"] < 2.0  # the brightest pixel is not the mirror point (t_star_curve: 1.1 px)
    for name in ("peak", "mirror"):
        assert len(c[name]["t"]) == len(c[name]["three_plus_ep"]) == 160
        assert min(c[name]["three_plus_ep"]) >= -1e-9  # E_p >= -3: three correlation coefficients
    assert abs(c["mirror"]["t_star"] / c["mirror"]["t_true"] - 1.0) < 0.03
    assert c["peak"]["t_star"] / c["peak"]["t_true"] < 0.6
    # at the true t on the exact ray the (X, Y) points are collinear: 3 + E_p = 0 up to rounding
    # (ep_flatness measured 1.6e-13)
    exact = ep_curves(cap, factors=[1.0])["mirror"]
    assert exact["three_plus_ep"][0] < 1e-9 and exact["t"] == [exact["t_true"]]
