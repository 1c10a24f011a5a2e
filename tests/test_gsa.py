"""Global sensitivity analysis (``nearlight.evaluation.gsa``): SALib's design and analysis recover known indices.

Goldens: the Ishigami function ``sin x1 + a sin² x2 + b x3⁴ sin x1`` (a = 7, b = 0.1,
x ~ U(-π, π)³) has closed-form Sobol' indices (Ishigami & Homma 1990; Saltelli et al.,
*Global Sensitivity Analysis: The Primer*, 2008, §4.4): S1 = (0.3139, 0.4424, 0),
ST = (0.5576, 0.4424, 0.2437). A linear model ``Σ c_i u_i`` of independent uniform
inputs (u_i the input scaled to [0, 1]) has S1_i = ST_i = c_i² / Σ c_j², and every
Morris elementary effect on the unit hypercube is exactly c_i (μ* = |c_i|, σ = 0).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from nearlight.evaluation.gsa import Design, Input, analyse, sample

PI = math.pi
ISHIGAMI_S1 = np.array([0.3139, 0.4424, 0.0])
ISHIGAMI_ST = np.array([0.5576, 0.4424, 0.2437])


def ishigami(X: np.ndarray, a: float = 7.0, b: float = 0.1) -> np.ndarray:
    return np.sin(X[:, 0]) + a * np.sin(X[:, 1]) ** 2 + b * X[:, 2] ** 4 * np.sin(X[:, 0])


ISHIGAMI_INPUTS = [Input(f"x{i}", "uniform", (-PI, PI)) for i in (1, 2, 3)]


def test_saltelli_sample_and_sobol_analysis_recover_the_ishigami_indices_within_their_intervals():
    design = Design("sobol", "sobol", n=1024, seed=7)
    X = sample(ISHIGAMI_INPUTS, design)
    assert X.shape == (1024 * 5, 3)  # N (k + 2) without second order
    rows, blocks = analyse(ISHIGAMI_INPUTS, design, X, ishigami(X))
    assert blocks == 1024
    s1 = np.array([r["S1"] for r in rows])
    st = np.array([r["ST"] for r in rows])
    s1c = np.array([r["S1_conf"] for r in rows])
    stc = np.array([r["ST_conf"] for r in rows])
    # the golden inside the 95 % bootstrap interval, and the intervals narrow enough to separate the inputs
    # (at N = 1024 SALib's half-widths are ~0.03-0.06; 0.1 keeps the check from passing on vague intervals)
    assert np.all(np.abs(s1 - ISHIGAMI_S1) <= s1c), (s1, s1c)
    assert np.all(np.abs(st - ISHIGAMI_ST) <= stc), (st, stc)
    assert np.all(s1c < 0.1) and np.all(stc < 0.1)


def test_a_failed_output_drops_its_saltelli_block_and_the_rest_still_recover_the_indices():
    design = Design("sobol", "sobol", n=1024, seed=7)
    X = sample(ISHIGAMI_INPUTS, design)
    Y = ishigami(X)
    Y[[3, 17, 400]] = np.nan  # rows of blocks 0, 3 and 80 (5 rows a block)
    rows, blocks = analyse(ISHIGAMI_INPUTS, design, X, Y)
    assert blocks == 1021
    st = np.array([r["ST"] for r in rows])
    assert np.all(np.abs(st - ISHIGAMI_ST) <= np.array([r["ST_conf"] for r in rows]))


@pytest.mark.parametrize("dist, bounds", [("uniform", (2.0, 4.0)), ("loguniform", (0.01, 1.0))])
def test_linear_model_sobol_indices_are_the_squared_coefficients_shares(dist, bounds):
    c = np.array([4.0, 2.0, 1.0])
    inputs = [Input(f"u{i}", dist, bounds) for i in range(3)]
    design = Design("sobol", "sobol", n=512, seed=3)
    X = sample(inputs, design)
    lo, hi = bounds
    U = (np.log(X / lo) / np.log(hi / lo)) if dist == "loguniform" else (X - lo) / (hi - lo)  # uniform on [0, 1]
    rows, _ = analyse(inputs, design, X, U @ c)
    want = c**2 / np.sum(c**2)  # 16/21, 4/21, 1/21
    for r, w in zip(rows, want):
        assert abs(r["S1"] - w) <= r["S1_conf"] and abs(r["ST"] - w) <= r["ST_conf"], (r, w)


def test_morris_elementary_effects_of_a_linear_model_are_its_coefficients():
    c = np.array([4.0, -2.0, 1.0, 0.0])
    inputs = [Input(f"u{i}", "uniform", (10.0, 20.0)) for i in range(4)]
    design = Design("morris", "morris", n=20, seed=5, levels=4)
    X = sample(inputs, design)
    assert X.shape == (20 * 5, 4)  # r (k + 1)
    rows, blocks = analyse(inputs, design, X, ((X - 10.0) / 10.0) @ c)
    assert blocks == 20
    # exact up to rounding: each effect is (Y(x + Δ e_i) - Y(x)) / Δ on the unit cube = c_i
    np.testing.assert_allclose([r["mu"] for r in rows], c, atol=1e-9)
    np.testing.assert_allclose([r["mu_star"] for r in rows], np.abs(c), atol=1e-9)
    np.testing.assert_allclose([r["sigma"] for r in rows], 0.0, atol=1e-9)


def test_a_categorical_input_picks_each_label_with_equal_probability():
    inp = Input("bsdf", "labels", (0.0, 2.0), [("torrance_sparrow", "torrance_sparrow"), ("ward", "ward")])
    X = sample([inp, Input("x", "uniform", (0.0, 1.0))], Design("s", "sobol", n=256, seed=1))
    picked = [inp.value(x) for x in X[:, 0]]
    assert 0.45 < picked.count("ward") / len(picked) < 0.55  # a scrambled Sobol' sequence: ~half exactly
    assert inp.value(2.0) == "ward"  # the closed upper end maps to the last label
