"""Regression check: did any error get worse than in a baseline run of the same sweep?

Rows are matched by task id (configuration, seed, method). For each method and
each error metric the mean over the tasks that succeeded in both runs is
compared: worse means ``new > base · (1 + tolerance) + atol``. A task that
succeeded in the baseline and fails now, or is missing, is worse too.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pandas as pd

from nearlight.evaluation.store import read_results
from nearlight.evaluation.tasks import METRICS


def compare_frames(
    new: pd.DataFrame, base: pd.DataFrame, *, tolerance: float = 0.05, atol: float = 1e-6, include_runtime: bool = False
) -> tuple[list[str], int]:
    """The regressions of ``new`` against ``base`` as printable lines, and the number of checks.

    Parameters
    ----------
    new, base : DataFrame
        Result rows (``task_id``, ``method``, ``status`` and metric columns).
    tolerance : float
        Allowed relative increase of a mean error.
    atol : float
        Allowed absolute increase, in the metric's units.
    include_runtime : bool
        Also check ``runtime_s`` (off by default: machines differ).

    Returns
    -------
    worse : list of str
    checks : int
    """
    worse: list[str] = []
    merged = base.merge(new, on="task_id", how="left", suffixes=("_base", "_new"), indicator=True)
    missing = merged[merged["_merge"] == "left_only"]
    if len(missing):
        worse.append(f"{len(missing)} task(s) of the baseline have no row in the new results")
    both = merged[merged["_merge"] == "both"]
    broke = both[(both["status_base"] == "ok") & (both["status_new"] != "ok")]
    for _, r in broke.iterrows():
        worse.append(f"task {r['task_id']} ({r['method_base']}): ok in baseline, now {r['status_new']}: {r['error_new']}")
    ok = both[(both["status_base"] == "ok") & (both["status_new"] == "ok")]
    checks = 0
    metrics = [m for m in METRICS if include_runtime or m != "runtime_s"]
    for method, grp in ok.groupby("method_base", sort=True):
        for m in metrics:
            if f"{m}_base" not in grp or f"{m}_new" not in grp:
                continue
            b = float(np.nanmean(grp[f"{m}_base"])) if grp[f"{m}_base"].notna().any() else math.nan
            n = float(np.nanmean(grp[f"{m}_new"])) if grp[f"{m}_new"].notna().any() else math.nan
            if math.isnan(b):
                continue
            checks += 1
            if math.isnan(n) or n > b * (1.0 + tolerance) + atol:
                change = f"{100 * (n - b) / b:+.1f}%" if b > 0 and not math.isnan(n) else "n/a"
                worse.append(f"{method}: {m} mean {n:.6g} vs baseline {b:.6g} ({change}, unit {METRICS[m]})")
    return worse, checks


def compare_dirs(
    new_dir: str | os.PathLike, base_dir: str | os.PathLike, **options: float | bool
) -> tuple[list[str], list[str]]:
    """Compare two sweep folders; returns (worse lines, every line to print).

    ``options`` as :func:`compare_frames`.
    """
    new, new_complete = read_results(new_dir)
    base, _ = read_results(base_dir)
    worse, checks = compare_frames(new, base, **options)
    lines = []
    if not new_complete:
        lines.append(f"note: {new_dir} is an incomplete sweep ({len(new)} rows)")
    if worse:
        lines.append(f"WORSE than {base_dir} ({len(worse)}):")
        lines += [f"  {w}" for w in worse]
    else:
        lines.append(f"ok: no metric worse than {base_dir} ({checks} method x metric means checked, {len(base)} tasks)")
    return worse, lines
