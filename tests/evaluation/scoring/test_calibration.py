"""The stated covariance scored (nearlight.evaluation.scoring.calibration): the truth's squared Mahalanobis
distance, the ellipsoid's coverage and the mean d²/3, on draws whose answer is known; the report's and the
scorecard's covariance tables on synthetic rows; the column on a real estimate of ``full``."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from nearlight.estimator import Estimate
from nearlight.evaluation.scoring.calibration import (MAHALANOBIS_COLUMN, coverage, coverage_cells, coverage_table,
                                                      lamp_mahalanobis_sq)

COV = np.diag([4.0, 1.0, 0.25, 1.0])  # (x, y, z, sigma): s.d. 2, 1, 0.5


def _estimate(lamp, cov=COV):
    return Estimate(method="m", lamp_position=np.asarray(lamp, float), ks=np.ones(3), sigma=0.1, covariance=cov)


def test_the_distance_is_the_lamp_blocks_whitened_square():
    # (2, 1, 0.5) off is one s.d. on each axis: 3; the sigma row and column (here 1) do not enter
    assert lamp_mahalanobis_sq(_estimate([2.0, 1.0, 0.5]), np.zeros(3)) == pytest.approx(3.0, rel=1e-12)
    rotated = np.eye(4)
    rotated[:2, :2] = [[2.0, 1.0], [1.0, 2.0]]  # x and y correlated: d = (1, 1) gives dᵀC⁻¹d = 2/3
    assert lamp_mahalanobis_sq(_estimate([1.0, 1.0, 0.0], rotated), np.zeros(3)) == pytest.approx(2 / 3)


@pytest.mark.parametrize("cov", [None, np.full((4, 4), np.nan), -np.eye(4), np.zeros((4, 4))],
                         ids=["none", "nan", "negative", "singular"])
def test_no_usable_covariance_no_distance(cov):
    assert math.isnan(lamp_mahalanobis_sq(_estimate([1.0, 0.0, 0.0], cov), np.zeros(3)))


def test_a_non_finite_lamp_has_no_distance():
    assert math.isnan(lamp_mahalanobis_sq(_estimate([np.nan, 0.0, 0.0]), np.zeros(3)))


def test_a_gaussian_error_of_the_stated_size_covers_95_percent_and_reads_1():
    """4000 chi-square(3) draws (seed 0): coverage and mean d²/3 within their own intervals of 0.95 and 1
    (binomial s.e. 0.0034, mean's s.e. √(2/3)/√4000 = 0.013; measured 0.952 and 0.998)."""
    d2 = np.sum(np.random.default_rng(0).normal(size=(4000, 3)) ** 2, axis=1)
    f = coverage(d2)
    assert f["n"] == 4000 and f["coverage_lo"] < 0.95 < f["coverage_hi"]
    assert f["mean_d2_3_lo"] < 1.0 < f["mean_d2_3_hi"]
    assert f["coverage_hi"] - f["coverage_lo"] < 0.02


def test_a_bounded_error_of_the_right_variance_over_covers_but_reads_1():
    """Uniform errors of unit variance per axis (±√3): the right covariance, yet nearly every draw is inside the
    95 % ellipsoid (|d|² ≤ 9, beyond χ²₃'s 7.81 only near the cube's corners: measured 3996 of 4000, 0.999) while
    the mean d²/3 stays 1 (measured 1.002): the two figures tell a wrong covariance from a non-Gaussian error."""
    u = np.random.default_rng(1).uniform(-math.sqrt(3), math.sqrt(3), size=(4000, 3))
    f = coverage(np.sum(u**2, axis=1))
    assert f["coverage_lo"] > 0.95
    assert f["mean_d2_3_lo"] < 1.0 < f["mean_d2_3_hi"]


def test_a_covariance_ten_times_too_small_in_sd_reads_100():
    d2 = 100 * np.sum(np.random.default_rng(2).normal(size=(400, 3)) ** 2, axis=1)
    f = coverage(d2)
    assert f["coverage_hi"] < 0.1 and 85 < f["mean_d2_3"] < 115  # measured 0.0125 and 101.7 (s.e. 4)


def test_nan_rows_are_left_out_and_no_rows_read_not_given():
    f = coverage(np.array([1.0, np.nan, 2.0]))
    assert f["n"] == 2 and f["inside"] == 2
    empty = coverage(np.array([np.nan]))
    assert empty["n"] == 0 and math.isnan(empty["coverage"])
    assert coverage_cells(empty) == ("not given", "not given")
    assert coverage_cells(coverage(np.array([1.0, 2.0, 3.0, 30.0])))[0].startswith("0.750 [")


def test_the_table_groups_successful_rows_and_says_not_given():
    rows = pd.DataFrame({"method": ["a", "a", "a", "b", "b"], "status": ["ok", "ok", "error", "ok", "ok"],
                         MAHALANOBIS_COLUMN: [1.0, 20.0, 0.5, np.nan, np.nan]})
    t = coverage_table(rows, ["method"]).set_index("method")
    assert t.loc["a", "tasks"] == 2 and t.loc["a", "with_covariance"] == 2  # the failed row is not scored
    assert t.loc["a", "inside_95"].startswith("0.500 [")
    assert t.loc["b", "inside_95"] == "not given" and t.loc["b", "with_covariance"] == 0
    assert coverage_table(rows.drop(columns=MAHALANOBIS_COLUMN), ["method"]).empty  # results from before


def test_fulls_row_has_its_distance():
    """``full`` on the noise-free analytic board: its lamp within float rounding and a tiny covariance; the row's
    distance is finite and non-negative (its size is float noise's, not asserted)."""
    from nearlight.estimator import estimate
    from nearlight.evaluation.scoring.metrics import score
    from nearlight.generator.analytic import analytic_capture
    from nearlight.generator.noise import add_camera_noise

    clean = analytic_capture(width=64, height=48)
    row = score(clean, estimate(add_camera_noise(clean, noise={"full_well": 50000, "read_noise": 3.0, "bits": 14},
                                                 seed=0), method="full"))
    assert np.isfinite(row[MAHALANOBIS_COLUMN]) and row[MAHALANOBIS_COLUMN] >= 0
    # the paper's method states no covariance
    paper = score(clean, estimate(clean, method="paper-init"))
    assert math.isnan(paper[MAHALANOBIS_COLUMN])
