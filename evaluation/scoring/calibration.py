"""Is a method's stated covariance right? The truth's squared Mahalanobis distance and the ellipsoid's coverage.

A method that returns a covariance (``full``: ``Estimate.covariance``, the
lamp block its first 3×3, m²) states how far its lamp may be from the truth.
Each result row records the true lamp's squared Mahalanobis distance from
the estimate under that covariance, :data:`MAHALANOBIS_COLUMN`
(:func:`lamp_mahalanobis_sq`); over rows, :func:`coverage_table` gives

- the share of truths inside the stated 95 % ellipsoid (``d² ≤ χ²₃(0.95)``)
  with its exact (Clopper–Pearson) binomial 95 % interval: 0.95 for a
  Gaussian error of the stated covariance;
- the mean ``d²/3`` with its 95 % bootstrap interval: 1 for a covariance
  equal to the error's whatever the error's distribution (a bounded error,
  such as a range staircase's, covers more than 95 % at the right
  covariance; the mean tells the two apart).

A method without a covariance reads "not given"; a row with several true or
found lamps has no distance (NaN: which lamp's block is not defined).
The same numbers as ``benchmarks/bench_range_bound.py`` prints (its own
captures; it uses these functions).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd
from scipy.stats import binomtest, chi2

#: The result column: squared Mahalanobis distance of the true lamp from the estimate (its own covariance).
MAHALANOBIS_COLUMN = "lamp_mahalanobis_sq"
#: The ellipsoid's nominal coverage.
LEVEL = 0.95
#: Bootstrap resamples of the mean d²/3's interval (fixed seed: the same rows give the same interval).
BOOTSTRAP = 2000


def lamp_mahalanobis_sq(estimate: Any, true_lamp: np.ndarray) -> float:
    """``dᵀ C⁻¹ d`` with ``d`` the estimate's lamp minus ``true_lamp`` (3,) and ``C`` the lamp block (3, 3) of
    ``estimate.covariance``; NaN without a covariance, with a non-finite one or one not positive definite, or a
    non-finite lamp. Dimensionless."""
    cov = getattr(estimate, "covariance", None)
    if cov is None:
        return math.nan
    C = np.asarray(cov, dtype=float)[:3, :3]
    d = np.asarray(estimate.lamp_position, dtype=float).reshape(3) - np.asarray(true_lamp, dtype=float).reshape(3)
    if not (np.all(np.isfinite(C)) and np.all(np.isfinite(d))):
        return math.nan
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        return math.nan
    z = np.linalg.solve(L, d)
    value = float(z @ z)
    return value if math.isfinite(value) else math.nan


def coverage(d2: np.ndarray, *, seed: int = 0) -> dict[str, float]:
    """Coverage figures of squared Mahalanobis distances ``d2`` (n,) in 3 dimensions, NaNs left out.

    Returns
    -------
    dict
        ``n`` (finite distances), ``inside`` (of them within the 95 % ellipsoid), ``coverage`` with its
        Clopper–Pearson ``coverage_lo``, ``coverage_hi``, and ``mean_d2_3`` (mean ``d²/3``) with its bootstrap
        ``mean_d2_3_lo``, ``mean_d2_3_hi``; the figures NaN when ``n`` is 0.
    """
    d2 = np.asarray(d2, dtype=float)
    d2 = d2[np.isfinite(d2)]
    n = len(d2)
    if n == 0:
        return {"n": 0, "inside": 0, **dict.fromkeys(("coverage", "coverage_lo", "coverage_hi", "mean_d2_3",
                                                      "mean_d2_3_lo", "mean_d2_3_hi"), math.nan)}
    inside = int(np.sum(d2 <= chi2.ppf(LEVEL, 3)))
    ci = binomtest(inside, n).proportion_ci(LEVEL)
    x = d2 / 3
    means = x[np.random.default_rng(seed).integers(0, n, (BOOTSTRAP, n))].mean(axis=1)
    return {"n": n, "inside": inside, "coverage": inside / n, "coverage_lo": float(ci.low),
            "coverage_hi": float(ci.high), "mean_d2_3": float(x.mean()),
            "mean_d2_3_lo": float(np.percentile(means, 2.5)), "mean_d2_3_hi": float(np.percentile(means, 97.5))}


def coverage_cells(figures: dict[str, float]) -> tuple[str, str]:
    """``(coverage, mean d²/3)`` as a table prints them: ``0.950 [0.924, 0.969]``, ``1.02 [0.94, 1.12]``; both
    "not given" without a distance."""
    if not figures["n"]:
        return "not given", "not given"
    return (f"{figures['coverage']:.3f} [{figures['coverage_lo']:.3f}, {figures['coverage_hi']:.3f}]",
            f"{figures['mean_d2_3']:.3g} [{figures['mean_d2_3_lo']:.3g}, {figures['mean_d2_3_hi']:.3g}]")


def coverage_table(df: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Per group of ``by`` (in order of appearance) over the successful rows of ``df``: the rows, those with a
    distance, and :func:`coverage_cells`; empty when ``df`` has no :data:`MAHALANOBIS_COLUMN` (results written
    before it existed)."""
    if MAHALANOBIS_COLUMN not in df.columns:
        return pd.DataFrame()
    ok = df[df["status"] == "ok"]
    rows = []
    for key, part in ok.groupby(by, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        figures = coverage(part[MAHALANOBIS_COLUMN].to_numpy(dtype=float))
        cells = coverage_cells(figures)
        rows.append({**dict(zip(by, key)), "tasks": len(part), "with_covariance": figures["n"],
                     "inside_95": cells[0], "mean_d2_over_3": cells[1]})
    return pd.DataFrame(rows)
