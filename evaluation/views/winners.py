"""Which method wins where: per configuration of a sweep, every method's lamp error with its interval (issue 40).

For each configuration (a value of every varied axis) and method, over its seeds: the median lamp position error
in millimetres with its percentile-bootstrap 95 % interval (a failed task is a miss, read as +∞, as the
scorecards read it: :func:`nearlight.evaluation.suites.scorecard.median_ci`), the RMSE over the successful tasks,
and how often the true lamp lies inside the method's own 95 % ellipsoid (its covariance checked by Monte Carlo
over the seeds, with the exact binomial interval: :func:`nearlight.evaluation.scoring.calibration.coverage`). A
calibration target's error is a bias per capture (its centre drawn once per seed): a covariance that leaves it out
covers far less than 95 % here.

The configuration's **winner** is the method whose interval lies wholly below every other method's; where the
best median's interval meets another's, the cell says which methods it cannot tell apart. Written only when every
configuration ran at least :data:`MIN_SEEDS` seeds of at least two methods: fewer seeds give intervals too wide to
rank anything.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ...files.figures import pyplot, save_png
from ..scoring.calibration import MAHALANOBIS_COLUMN, coverage
from ..suites.scorecard import median_ci

#: Fewest seeds per configuration and method for the table to be written.
MIN_SEEDS = 10
#: The metric ranked, and its display scale (metres to millimetres).
METRIC, SCALE, UNIT = "lamp_position_error_m", 1000.0, "mm"


def _method_stats(part: pd.DataFrame) -> dict[str, float]:
    ok = (part["status"] == "ok").to_numpy()
    vals = np.where(ok, part[METRIC].to_numpy(dtype=float), np.nan)
    med, lo, hi = median_ci(vals)
    good = vals[np.isfinite(vals)]
    cov = coverage(np.where(ok, part[MAHALANOBIS_COLUMN].to_numpy(dtype=float), np.nan)) \
        if MAHALANOBIS_COLUMN in part.columns else coverage(np.array([]))  # fmt: skip
    return {"n": len(part), "failed": int((~ok).sum()), "median": med * SCALE, "lo": lo * SCALE, "hi": hi * SCALE,
            "rmse": float(np.sqrt(np.mean(good**2))) * SCALE if good.size else np.nan,
            "inside_95": cov["coverage"], "inside_lo": cov["coverage_lo"], "inside_hi": cov["coverage_hi"]}  # fmt: skip


def verdict(stats: pd.DataFrame) -> str:
    """The cell's winner: the method whose interval's top is below every other method's interval's bottom, else
    ``"none: A, B overlap"`` naming the methods whose intervals meet the best median's."""
    best = stats.loc[stats["median"].idxmin()] if np.isfinite(stats["median"]).any() else None
    if best is None:
        return "none: every method failed"
    others = stats[stats["method"] != best["method"]]
    if (best["hi"] < others["lo"]).all():
        return str(best["method"])
    tied = [best["method"], *others.loc[others["lo"] <= best["hi"], "method"]]
    return "none: " + ", ".join(map(str, tied)) + " overlap"


def winners_table(df: pd.DataFrame, varied: list[str]) -> pd.DataFrame:
    """One row per configuration and method (columns: the ``varied`` axes, ``method``, ``n``, ``failed``,
    ``median``, ``lo``, ``hi``, ``rmse`` in mm, ``inside_95`` with ``inside_lo``, ``inside_hi``, and the cell's
    ``winner``); empty unless every configuration ran :data:`MIN_SEEDS` seeds of two methods or more."""
    if df["method"].nunique() < 2 or METRIC not in df.columns:
        return pd.DataFrame()
    cells = list(varied)
    groups = df.groupby(cells, sort=False, dropna=False) if cells else [((), df)]
    rows = []
    for key, cell in groups:
        key = key if isinstance(key, tuple) else (key,)
        stats = pd.DataFrame([{"method": m, **_method_stats(part)} for m, part in cell.groupby("method", sort=False)])
        if stats["n"].min() < MIN_SEEDS:
            return pd.DataFrame()
        stats["winner"] = verdict(stats)
        rows += [{**dict(zip(cells, key)), **r} for r in stats.to_dict("records")]
    return pd.DataFrame(rows)


def winners_wide(table: pd.DataFrame, varied: list[str]) -> pd.DataFrame:
    """One row per configuration: each method's ``median [lo, hi]`` (mm) and the winner."""
    out = []
    for key, cell in table.groupby(list(varied), sort=False, dropna=False) if varied else [((), table)]:
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(varied, key))
        row.update({m: f"{r['median']:.3g} [{r['lo']:.3g}, {r['hi']:.3g}]" for m, r in
                    zip(cell["method"], cell.to_dict("records"))})  # fmt: skip
        row["winner"] = cell["winner"].iloc[0]
        out.append(row)
    return pd.DataFrame(out)


def plot_winners(table: pd.DataFrame, varied: list[str], path: Path) -> Path:
    """Configurations × methods, coloured by the median lamp error (log mm), each cell's winner outlined."""
    plt = pyplot()
    methods = list(dict.fromkeys(table["method"]))
    labels, grid, wins = [], [], []
    for key, cell in table.groupby(list(varied), sort=False, dropna=False) if varied else [((), table)]:
        key = key if isinstance(key, tuple) else (key,)
        labels.append(", ".join(f"{a}={v}" for a, v in zip(varied, key)) or "all")
        med = dict(zip(cell["method"], cell["median"]))
        grid.append([med.get(m, np.nan) for m in methods])
        wins.append(cell["winner"].iloc[0])
    grid = np.array(grid, dtype=float)
    shown = np.log10(np.clip(np.where(np.isfinite(grid), grid, np.nan), 1e-3, None))
    fig, ax = plt.subplots(figsize=(3.5 + 1.3 * len(methods), 1.8 + 0.32 * len(labels)))
    im = ax.imshow(shown, aspect="auto", cmap="viridis_r")
    for i, row in enumerate(grid):
        for j, v in enumerate(row):
            ax.text(j, i, "fail" if not np.isfinite(v) else f"{v:.3g}", ha="center", va="center", fontsize=7,
                    color="w" if np.isfinite(v) and shown[i, j] > np.nanmedian(shown) else "k")
            if wins[i] == methods[j]:
                ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="red", lw=2))
    ax.set_xticks(range(len(methods)), methods, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(labels)), labels, fontsize=7)
    fig.colorbar(im, ax=ax, label=f"log10 median ({UNIT})")
    ax.set_title(f"Median lamp error ({UNIT}) per configuration\nred: the winner (its interval below every other's)",
                 fontsize=9)
    fig.tight_layout()
    return save_png(fig, path)
