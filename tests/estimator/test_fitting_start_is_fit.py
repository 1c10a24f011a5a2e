"""``fitting.robust_fit(start_is_fit=True)``: one pass, its loss scale from the residuals at the start."""

import numpy as np
import pytest

from nearlight.estimator.fitting import robust_fit


@pytest.fixture(scope="module")
def line():
    """y = 2 + 0.5 t with N(0, 0.1²) noise on 4000 points, 5 % of them 10× the noise off (outliers)."""
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 10.0, 4000)
    y = 2.0 + 0.5 * t + rng.normal(0.0, 0.1, t.size)
    bad = rng.random(t.size) < 0.05
    y[bad] += rng.choice([-1.0, 1.0], bad.sum())
    A = np.stack([np.ones_like(t), t], axis=1)
    x0 = np.linalg.lstsq(A[::4], y[::4], rcond=None)[0]  # a least-squares fit on a subset, as full's final fit's start

    def residuals(x):
        return A @ x - y

    return residuals, A, x0


def _fit(residuals, A, x0, **kw):
    return robust_fit(residuals, x0, typical=np.ones(2), lower=np.full(2, -np.inf), upper=np.full(2, np.inf),
                      loss="huber", jac=lambda x: A, **kw)


def test_one_pass_takes_three_mads_of_the_start_residuals(line):
    residuals, A, x0 = line
    one = _fit(residuals, A, x0, start_is_fit=True)
    r0 = residuals(x0)
    mad = 1.4826 * np.median(np.abs(r0 - np.median(r0)))
    assert one["f_scale"] == pytest.approx(3.0 * mad, rel=1e-12)
    # 3 noise deviations (0.3): the MAD of 4000 normal draws is within ~2.5 % (1 s.d.), 5 % outliers widen it ~6 %
    assert one["f_scale"] == pytest.approx(0.3, rel=0.15)
    two = _fit(residuals, A, x0)  # the two-pass default: its second scale from the first pass's residuals
    assert one["f_scale"] == pytest.approx(two["f_scale"], rel=0.02)  # both are 3 MADs of near-optimal residuals
    se = np.sqrt(np.diag(one["cov"]))
    assert np.all(np.abs(one["x"] - two["x"]) < 0.05 * se)  # the same estimate, to a twentieth of its s.d.
    assert np.all(np.abs(one["x"] - [2.0, 0.5]) < 4 * se)
    assert one["nfev"] < two["nfev"]
