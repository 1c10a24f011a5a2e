"""Regression verdicts: did a method get worse than in a baseline run of the same sweep or suite?

Rows of a sweep are grouped by *check unit*: the configuration (the sweep's axis
columns) and the method label. Seeds are not matched, so a re-run with other
seeds, or on another machine, compares like with like. Each unit is one of two
kinds:

``exact`` (no camera or range noise: the numbers do not depend on the seed)
    compared value against value. Worse when ``new > base + tolerance·|base|
    + floor``, better when ``new < base − (tolerance·|base| + floor)``. The
    per-metric floors (:data:`EXACT_FLOOR`) absorb what differs between two
    machines for the same code: Dr.Jit renders differ in their last bits
    between CPUs, and the estimators move by far less than the floors then
    (measured on the smoke sweep, a 2-core Xeon against the baseline's
    machine: at most 2.7e-6 m, 8.4e-4 % of the distance, 8e-6°, 5.7e-6 relative
    in σ; the floors are 4–20 times that).

``pooled`` (noisy: one row per seed)
    the seeds' values of the baseline against the new run's, unpaired. Worse
    only when the change is larger than the tolerance (``mean_new >
    mean_base·(1 + tolerance)``, the asv rule) *and* unlikely under noise: a
    one-sided Mann–Whitney U test at the Šidák-corrected level
    ``1 − (1 − alpha)^(1/m)`` over the ``m`` pooled checks of the run, so the
    chance that a re-run with other seeds is flagged anywhere is at most
    ``alpha`` (default 5 %). Better is the mirror image. The change is printed
    with a bootstrap confidence interval of the difference of means (at the
    same corrected level). A unit with fewer than :data:`MIN_SEEDS` seeds on
    either side cannot reach significance and is reported ``inconclusive``.

A failure count that rises is checked the same way (exact units: any task that
failed; pooled units: Fisher's exact test on the failure counts, in the same
Šidák family). A unit of the baseline with no rows in the new results is a
regression (``missing``).

Two scorecards (``nearlight score`` runs on one frozen suite) are compared
*paired* (:func:`compare_scores`): each case of the baseline is paired with the
new run's row of the same case id (whose categories and seed must agree too: a
bad pairing is an error), and a case without a new row is ``missing``. Comparing
each case value against value, each case its own verdict, would cry wolf: the
same suite built on two machines has renders that differ in their last bits,
and a discontinuous method (``paper-init``'s brightest pixel) flips on a few
cases. So per method and metric there is one check over all the cases, and one
per value of each category column that holds at least :data:`MIN_SEEDS` paired
cases:

``paired``
    the differences ``d_i = new_i − base_i`` of the cases (those ``ok`` on both
    sides with the metric defined on both). A difference within the exact
    class, ``|d_i| ≤ EXACT_FLOOR + PAIRED_RTOL·|base_i|``, is no change (a
    last-bit move is not a regression) and is dropped from the test. Worse only
    when the mean moved by more than the tolerance (the asv rule above) *and* a
    one-sided Wilcoxon signed-rank test of the cases that moved is significant
    at the Šidák level over the run's paired checks (so one case that flips
    cannot be: its p is 1/2; nor can fewer than ``log2(1/level)`` cases moved
    one way, the price of not crying wolf). Better is the mirror image. The
    change is printed with a paired bootstrap interval of the mean difference,
    at the same level. Fewer than :data:`MIN_SEEDS` paired cases:
    ``inconclusive``. Failures: the cases ok in the baseline and failed in the
    new run against the reverse, McNemar's exact (binomial) test in the same
    family.

:func:`compare_frames` and :func:`compare_scores` return every check as a
:class:`Check`; :func:`compare_dirs` adds the two folders' environments and the
printed table.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...errors import UserError
from ...files.atomic import write_json
from ...files.jsonable import jsonable
from ...files.outputs import check_file_out
from ..engine import provenance
from ..engine.environment import differences
from ..engine.store import read_environments, read_sweep_json, read_results
from ..scoring.metrics import INFO_COLUMNS, LOBE_COLUMN, METRICS, PER_LAMP_COLUMN

#: Metrics compared (``runtime_s`` only on request; ``specular_rmse`` is in radiance units whose scale
#: differs per scene, ``specular_rmse_rel`` carries the same information scale-free).
COMPARED = tuple(m for m in METRICS if m not in ("runtime_s", "specular_rmse"))
#: Absolute allowance of an exact check, in the metric's units (see the module docstring for the
#: cross-machine spread these cover).
EXACT_FLOOR: dict[str, float] = {
    "lamp_position_error_m": 2e-5,
    "lamp_position_error_pct": 5e-3,
    "direction_error_deg": 2e-3,
    "distance_error_m": 2e-5,
    "sigma_rel_error": 1e-4,
    "ks_rel_error": 1e-4,
    "specular_rmse_rel": 1e-5,
    "runtime_s": 0.0,
}
#: Fewest seeds per side for a pooled check to reach a verdict: with 5 against 5 the smallest one-sided
#: Mann–Whitney p is 1/252 = 0.004, below the Šidák level of a few dozen checks at alpha = 0.05.
MIN_SEEDS = 5
#: Relative part of the class of a paired check's per-case difference that counts as none, beside the
#: metric's :data:`EXACT_FLOOR`: a case's error moved by 1/1000 of itself, the suites' build tolerance
#: on images (``suite.DIGEST_RTOL``; docs/benchmark-suites.md, "Comparing scorecards").
PAIRED_RTOL = 1e-3
VERDICTS = ("worse", "missing", "better", "same", "inconclusive")


@dataclasses.dataclass
class Check:
    """One verdict: a method's metric in one configuration, new against baseline.

    Attributes
    ----------
    method : str
    config : dict
        Axis column -> value.
    metric : str
        A :data:`~nearlight.evaluation.scoring.metrics.METRICS` column, or ``"failures"``.
    kind : str
        ``"exact"``, ``"pooled"`` or ``"paired"`` (scorecards).
    n_base, n_new : int
        Rows (seeds) on each side; paired: the paired cases, on both.
    base, new : float
        Baseline and new value (mean over seeds for pooled checks, over the paired cases for paired ones;
        failure count for ``failures``).
    low, high : float
        Confidence interval of ``new − base`` (pooled, paired; NaN otherwise).
    p_value : float
        One-sided p of the test in the direction of the change (pooled and paired checks whose change
        exceeds the tolerance, failures checks whose counts differ; NaN otherwise).
    verdict : str
        One of :data:`VERDICTS`.
    """

    method: str
    config: dict[str, Any]
    metric: str
    kind: str
    n_base: int
    n_new: int
    base: float
    new: float
    low: float = math.nan
    high: float = math.nan
    p_value: float = math.nan
    verdict: str = "same"

    @property
    def regression(self) -> bool:
        """Whether this check fails the comparison."""
        return self.verdict in ("worse", "missing")

    def line(self) -> str:
        """One printable line."""
        where = ", ".join(f"{k}={v}" for k, v in self.config.items()) or ("all" if self.kind == "paired" else "")
        unit = METRICS.get(self.metric, "tasks")
        if self.verdict == "missing":
            return f"{self.verdict:>12}  {self.method} [{where}]: no rows in the new results"
        change = self.new - self.base
        rel = f" ({100 * change / self.base:+.1f}%)" if self.base and math.isfinite(change) else ""
        ci = f" [{self.low:+.3g}, {self.high:+.3g}]" if math.isfinite(self.low) else ""
        p = f" p={self.p_value:.2g}" if math.isfinite(self.p_value) else ""
        n = self.n_base if self.kind == "paired" else f"{self.n_base}/{self.n_new}"
        return (
            f"{self.verdict:>12}  {self.method} [{where}] {self.metric}: {self.base:.6g} -> {self.new:.6g} "
            f"{unit}, change {change:+.3g}{rel}{ci}{p} ({self.kind}, n={n})"
        )


def _axes(df: pd.DataFrame, axes: Sequence[str] | None) -> list[str]:
    """Config columns: the sweep's axes present in the rows, else every non-result column."""
    if axes is not None:
        return [a for a in axes if a in df.columns]
    skip = {"task_id", "task_index", "sweep", "seed", "noisy", "method", "render_key", "renderer", "code_version",
            "status", "error", LOBE_COLUMN, *METRICS, *INFO_COLUMNS}
    return [c for c in df.columns if c not in skip and not c.startswith("crlb_") and not PER_LAMP_COLUMN.match(c)]


def _is_noisy(*sides: pd.DataFrame | None) -> bool:
    """Whether a unit's numbers depend on the seed: the ``noisy`` column of either side, else
    (results made before the column existed) whether its seeds disagree."""
    sides = [s for s in sides if s is not None]
    if any("noisy" in s for s in sides):
        return any(bool(s["noisy"].any()) for s in sides if "noisy" in s)
    for s in sides:
        values = s[[m for m in COMPARED if m in s]].to_numpy(float)
        if len(s) > 1 and not np.allclose(values, values[0], equal_nan=True, rtol=0, atol=0):
            return True
    return False


def _finite(s: pd.Series) -> np.ndarray:
    a = s.to_numpy(float)
    return a[np.isfinite(a)]


def _exact(metric: str, b: float, n: float, tolerance: float) -> str:
    allow = tolerance * abs(b) + EXACT_FLOOR.get(metric, 0.0)
    if math.isnan(n):
        return "worse"
    return "worse" if n > b + allow else "better" if n < b - allow else "same"


def _bootstrap_ci(xb: np.ndarray, xn: np.ndarray, level: float, seed: int, *,
                  paired: bool = False) -> tuple[float, float]:  # fmt: skip
    """Percentile-bootstrap interval of mean(xn) − mean(xb) (scipy.stats.bootstrap): the two runs' values
    resampled apart, or, ``paired``, case by case (``xb[i]`` and ``xn[i]`` one case: the interval of the mean
    paired difference)."""
    from scipy.stats import bootstrap

    if np.ptp(xn - xb if paired else np.concatenate([xb, xn])) == 0:  # nothing to resample: the change is known
        change = float(xn.mean() - xb.mean())
        return change, change
    res = bootstrap((xn, xb), lambda a, b, axis=-1: a.mean(axis=axis) - b.mean(axis=axis), paired=paired,
                    confidence_level=level, n_resamples=2000, method="percentile", random_state=seed)  # fmt: skip
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def sidak_level(alpha: float, m: int) -> float:
    """Per-check level ``1 − (1 − alpha)^(1/m)`` that keeps the chance of any false alarm over ``m``
    independent checks at ``alpha`` (Šidák)."""
    return 1.0 - (1.0 - alpha) ** (1.0 / max(m, 1))


def verdict_counts(checks: Sequence[Check]) -> dict[str, int]:
    """How many checks have each verdict, in :data:`VERDICTS` order."""
    return {v: sum(c.verdict == v for c in checks) for v in VERDICTS}


def _with_columns(df: pd.DataFrame, cols: Sequence[str]) -> pd.DataFrame:
    """``df`` with every config column of the baseline, those it lacks empty: rows of another sweep's axes match
    no unit of the baseline, so each of its units is ``missing`` (a verdict) rather than a crash."""
    lacking = {c: None for c in cols if c not in df}
    return df.assign(**lacking) if lacking else df


def unchecked_units(new: pd.DataFrame, base: pd.DataFrame, *, axes: Sequence[str] | None = None) -> int:
    """How many units (configuration and method) of ``new`` have no unit in ``base``: new configurations or
    methods, which no check covers."""
    cols = _axes(base, axes)
    keys = [*cols, "method"]
    seen = set(_lean(base, cols, ()).groupby(keys, sort=False, dropna=False).groups)
    new = _lean(_with_columns(new, cols), cols, ())
    return sum(k not in seen for k in new.groupby(keys, sort=False, dropna=False).groups)


def _lean(df: pd.DataFrame, cols: Sequence[str], metrics: Sequence[str]) -> pd.DataFrame:
    """The columns a comparison reads, text columns as Python objects: grouping and masking a row table of
    ~100 Arrow-backed columns is what a comparison spends its time on (9x faster on the smoke sweep)."""
    keep = [c for c in dict.fromkeys([*cols, "method", "status", "noisy", "seed", *metrics]) if c in df]
    lean = df[keep]
    text = [c for c in keep if pd.api.types.is_string_dtype(lean[c])]
    return lean.astype(dict.fromkeys(text, object)) if text else lean


def check_thresholds(tolerance: float, alpha: float) -> None:
    """Raise :class:`UserError` unless ``tolerance`` ≥ 0 and ``alpha`` in (0, 1) (``--tolerance``, ``--alpha``)."""
    if not (math.isfinite(tolerance) and tolerance >= 0):
        raise UserError(f"--tolerance: expected a number >= 0, got {tolerance}")
    if not (0 < alpha < 1):
        raise UserError(f"--alpha: expected a number between 0 and 1, got {alpha}")


def compare_frames(
    new: pd.DataFrame,
    base: pd.DataFrame,
    *,
    axes: Sequence[str] | None = None,
    tolerance: float = 0.05,
    alpha: float = 0.05,
    include_runtime: bool = False,
    intervals: bool = True,
) -> list[Check]:
    """Every check of ``new`` against ``base`` (see the module docstring for the rules).

    Parameters
    ----------
    new, base : DataFrame
        Result rows: config columns, ``method``, ``status``, metric columns,
        optionally ``noisy`` and ``seed``.
    axes : sequence of str, optional
        The config columns (the sweep's axes); default: guessed from the rows.
    tolerance : float
        Relative change below which no change counts, ≥ 0.
    alpha : float
        Family-wise false-alarm rate of the pooled checks, in (0, 1).
    include_runtime : bool
        Also check ``runtime_s`` (off by default: machines differ).
    intervals : bool
        Bootstrap the confidence interval of each pooled change (the verdicts do not use it;
        off saves ~10 ms a check in loops over many re-runs).

    Returns
    -------
    list of Check
        In baseline order: per unit, failures first, then each metric.
    """
    from scipy.stats import fisher_exact, mannwhitneyu

    check_thresholds(tolerance, alpha)
    cols = _axes(base, axes)
    keys = [*cols, "method"]
    metrics = [*COMPARED, *(["runtime_s"] if include_runtime else [])]
    new, base = _lean(_with_columns(new, cols), cols, metrics), _lean(base, cols, metrics)
    new_groups = {k if isinstance(k, tuple) else (k,): g for k, g in new.groupby(keys, sort=False, dropna=False)}
    units = []
    for key, b in base.groupby(keys, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        units.append((dict(zip(cols, key[:-1])), key[-1], b, new_groups.get(key)))

    pooled = [u for u in units if u[3] is not None and _is_noisy(u[2], u[3])]
    m = sum(1 + sum(_finite(b[x]).size > 0 for x in metrics if x in b) for _, _, b, _ in pooled)
    level = sidak_level(alpha, m)
    checks: list[Check] = []
    for i, (config, method, b, n) in enumerate(units):
        if n is None:
            checks.append(Check(method, config, "-", "-", len(b), 0, math.nan, math.nan, verdict="missing"))
            continue
        kind = "pooled" if _is_noisy(b, n) else "exact"
        fb, fn = int((b["status"] != "ok").sum()), int((n["status"] != "ok").sum())
        c = Check(method, config, "failures", kind, len(b), len(n), fb, fn)
        if kind == "exact":
            c.verdict = "worse" if fn > fb else "better" if fn < fb else "same"
        elif fb != fn:
            up = fn / len(n) > fb / len(b)
            table = [[fn, len(n) - fn], [fb, len(b) - fb]]
            c.p_value = float(fisher_exact(table, alternative="greater" if up else "less")[1])
            c.verdict = ("worse" if up else "better") if c.p_value < level else "same"
        checks.append(c)
        bok, nok = b[b["status"] == "ok"], n[n["status"] == "ok"]
        if nok.empty:  # every new task failed: the failures check says so, no metric to compare
            continue
        for metric in metrics:
            if metric not in b or metric not in n:
                continue
            xb, xn = _finite(bok[metric]), _finite(nok[metric])
            if xb.size == 0:
                continue
            c = Check(method, config, metric, kind, xb.size, xn.size, float(xb.mean()),
                      float(xn.mean()) if xn.size else math.nan)  # fmt: skip
            if kind == "exact":
                c.verdict = _exact(metric, c.base, c.new, tolerance)
            elif xn.size == 0:
                c.verdict = "worse"
            elif min(xb.size, xn.size) < MIN_SEEDS:
                c.verdict = "inconclusive"
            else:
                if intervals:
                    c.low, c.high = _bootstrap_ci(xb, xn, 1.0 - level, seed=i)
                # tested only where the change exceeds the tolerance (the asv rule), so p is NaN otherwise
                if c.new > c.base * (1.0 + tolerance):
                    c.p_value = float(mannwhitneyu(xn, xb, alternative="greater").pvalue)
                    c.verdict = "worse" if c.p_value < level else "same"
                elif c.new < c.base * (1.0 - tolerance):
                    c.p_value = float(mannwhitneyu(xn, xb, alternative="less").pvalue)
                    c.verdict = "better" if c.p_value < level else "same"
            checks.append(c)
    return checks


def _is_score(df: pd.DataFrame) -> bool:
    """Whether ``df`` holds the rows of a ``nearlight score`` run (its ``renderer`` column is ``suite``)."""
    return "renderer" in df and not df.empty and bool((df["renderer"] == "suite").all())


def _as_scores(new: pd.DataFrame, base: pd.DataFrame) -> tuple[pd.DataFrame, str]:
    """The new score run as :func:`compare_scores` compares it with ``base``, and the note that says how.

    Two runs of one method each, different methods, are compared method against method on the same cases
    (the new run's method is renamed the baseline's).
    """
    mn, mb = sorted(set(new["method"])), sorted(set(base["method"]))
    note = ("note: scorecards: each case paired with its baseline case (by case id); per method and metric one "
            "paired check over all cases and one per category value")  # fmt: skip
    if len(mn) == 1 and len(mb) == 1 and mn != mb:
        new = new.assign(method=mb[0])
        note += f"; method {mn[0]!r} (new) against {mb[0]!r} (baseline)"
    return new, note


def unpaired_cases(new: pd.DataFrame, base: pd.DataFrame) -> int:
    """How many cases (case id and method) of a score run ``new`` have no case in ``base``: no check covers them."""
    seen = set(zip(base["task_id"], base["method"]))
    return sum(k not in seen for k in zip(new["task_id"], new["method"]))


def _same_cases(pairs: pd.DataFrame, cols: Sequence[str]) -> None:
    """Raise :class:`UserError` unless every paired case has the same categories and seed on both sides."""
    for col in [*cols, "seed"]:
        if col not in pairs:
            continue
        b, n = pairs[col], pairs[f"{col}_new"]
        differ = ~((b == n) | (b.isna() & n.isna()))
        if differ.any():
            i = differ.to_numpy().nonzero()[0][0]
            raise UserError(f"case {pairs['task_id'].iloc[i]}: {col} is {b.tolist()[i]!r} in the baseline and "
                            f"{n.tolist()[i]!r} in the new results: not the same case (two scorecards of one suite "
                            f"agree on every case's categories and seed)")  # fmt: skip


def _paired_groups(rows: pd.DataFrame, cols: Sequence[str]) -> list[tuple[dict[str, Any], pd.DataFrame]]:
    """The cases a method's paired checks cover: all of them, then each value of each category column that
    holds at least :data:`MIN_SEEDS` of them."""
    groups = [({}, rows)]
    for col in cols:
        groups += [({col: value}, g) for value, g in rows.groupby(col, sort=False, dropna=False) if len(g) >= MIN_SEEDS]
    return groups


def _paired_failures(c: Check, ok_base: np.ndarray, ok_new: np.ndarray, level: float) -> None:
    """The verdict of a paired failures check: McNemar's exact test, the one-sided binomial test of the
    discordant cases (failed in one run only), in the direction of the larger count."""
    from scipy.stats import binomtest

    if c.n_base < MIN_SEEDS:
        c.verdict = "inconclusive"
        return
    failed, recovered = int((ok_base & ~ok_new).sum()), int((~ok_base & ok_new).sum())
    if failed == recovered:
        return
    c.p_value = float(binomtest(max(failed, recovered), failed + recovered, 0.5, alternative="greater").pvalue)
    if c.p_value < level:
        c.verdict = "worse" if failed > recovered else "better"


def _paired_metric(c: Check, xb: np.ndarray, xn: np.ndarray, level: float, tolerance: float,
                   seed: int | None) -> None:  # fmt: skip
    """The verdict of a paired metric check on the cases' values ``xb``, ``xn`` (one case per index).

    A case's difference within the exact class (``|d| ≤ EXACT_FLOOR + PAIRED_RTOL·|base|``) counts as
    none and is dropped from the one-sided Wilcoxon signed-rank test (exact for up to 50 moved cases
    without ties), which runs only where the mean moved by more than the tolerance; ``seed`` seeds the
    bootstrap interval of the mean difference (None: no interval).
    """
    from scipy.stats import wilcoxon

    if c.n_base < MIN_SEEDS:
        c.verdict = "inconclusive"
        return
    if seed is not None:
        c.low, c.high = _bootstrap_ci(xb, xn, 1.0 - level, seed, paired=True)
    d = xn - xb
    moved = d[np.abs(d) > EXACT_FLOOR.get(c.metric, 0.0) + PAIRED_RTOL * np.abs(xb)]
    if c.new > c.base * (1.0 + tolerance):
        alternative, verdict = "greater", "worse"
    elif c.new < c.base * (1.0 - tolerance):
        alternative, verdict = "less", "better"
    else:
        return
    # no case moved beyond the class: no evidence of a change in either direction
    c.p_value = float(wilcoxon(moved, alternative=alternative).pvalue) if moved.size else 1.0
    if c.p_value < level:
        c.verdict = verdict


def _continuous_cases(new: pd.DataFrame, base: pd.DataFrame, categories: Sequence[str],
                      options: dict[str, Any]) -> tuple[list[Check], int]:
    """Two score runs' continuous methods (not a brightest-pixel choice: ``full``, ``distant``), case by case.

    A continuous method's number moves with a render's last bits by far less than :data:`EXACT_FLOOR`
    (measured across CPUs, module docstring), so each of its cases is also its own ``exact`` check,
    as sweeps' noise-free units are: one case gone wrong is a regression there, where the paired rule
    needs ``log2(1/level)`` cases. Brightest-pixel methods (``paper-init``, ``paper``) flip on a few
    cases between two builds and get the paired checks only.

    Returns
    -------
    checks : list of Check
        The case checks that are not ``same`` (the others are counted, not listed).
    n : int
        How many case checks were made.
    """
    from ..paper.check import CONTINUOUS, continuity

    methods = [m for m in base["method"].unique() if continuity(str(m)) == CONTINUOUS]
    if not methods:
        return [], 0
    sides = [df[df["method"].isin(methods)].assign(noisy=False) for df in (new, base)]
    checks = compare_frames(*sides, axes=[*categories, "seed"], **options)
    return [c for c in checks if c.verdict not in ("same", "missing")], len(checks)


def compare_scores(
    new: pd.DataFrame,
    base: pd.DataFrame,
    *,
    categories: Sequence[str] = (),
    tolerance: float = 0.05,
    alpha: float = 0.05,
    include_runtime: bool = False,
    intervals: bool = True,
) -> list[Check]:
    """Every paired check of a score run ``new`` against ``base`` (the ``paired`` rules of the module docstring).

    Parameters
    ----------
    new, base : DataFrame
        Score rows (``nearlight score``): ``task_id`` (the case id), ``method``, ``status``, ``seed``, the
        category columns and the metric columns.
    categories : sequence of str
        The suite's category columns: a check per value holding at least :data:`MIN_SEEDS` paired cases.
    tolerance, alpha, include_runtime, intervals
        As :func:`compare_frames` (``alpha``: over the run's paired checks).

    Returns
    -------
    list of Check
        First a ``missing`` check per baseline case without a new row; then per method, for all cases and
        then each category value, failures first, then each metric.

    Raises
    ------
    UserError
        When a case id of both runs has other categories or another seed in each.
    """
    check_thresholds(tolerance, alpha)
    cols = [c for c in categories if c in base]
    metrics = [m for m in [*COMPARED, *(["runtime_s"] if include_runtime else [])] if m in base and m in new]
    new, base = _lean(_with_columns(new, cols), ["task_id", *cols], metrics), _lean(base, ["task_id", *cols], metrics)
    merged = base.merge(new, on=["task_id", "method"], how="left", suffixes=("", "_new"), indicator=True)
    found = (merged.pop("_merge") == "both").to_numpy()
    checks = [Check(r["method"], {**{c: r[c] for c in cols}, "seed": r["seed"]}, "-", "-", 1, 0, math.nan, math.nan,
                    verdict="missing") for _, r in merged[~found].iterrows()]  # fmt: skip
    pairs = merged[found]
    _same_cases(pairs, cols)
    todo: list[tuple[Check, np.ndarray, np.ndarray]] = []  # each check with its paired values (failures: ok flags)
    for method, rows in pairs.groupby("method", sort=False):
        for config, g in _paired_groups(rows, cols):
            ok_base, ok_new = (g["status"] == "ok").to_numpy(), (g["status_new"] == "ok").to_numpy()
            todo.append((Check(method, config, "failures", "paired", len(g), len(g), int((~ok_base).sum()),
                               int((~ok_new).sum())), ok_base, ok_new))  # fmt: skip
            both = g[ok_base & ok_new]
            for metric in metrics:
                xb, xn = both[metric].to_numpy(float), both[f"{metric}_new"].to_numpy(float)
                if not np.isfinite(xb).any():
                    continue
                keep = np.isfinite(xb) & np.isfinite(xn)  # a case whose metric is undefined on a side is not paired
                xb, xn = xb[keep], xn[keep]
                means = (float(x.mean()) if x.size else math.nan for x in (xb, xn))
                todo.append((Check(method, config, metric, "paired", xb.size, xn.size, *means), xb, xn))
    level = sidak_level(alpha, len(todo))
    for i, (c, xb, xn) in enumerate(todo):
        if c.metric == "failures":
            _paired_failures(c, xb, xn, level)
        else:
            _paired_metric(c, xb, xn, level, tolerance, seed=i if intervals else None)
        checks.append(c)
    return checks


def _stale_baseline(base_dir: Path) -> list[str]:
    """Warning lines when ``base_dir`` was made by other code than this checkout's (its provenance record).

    A baseline older than the code it pins cannot tell a regression of today's
    code from one that was already there when it was made; the warning names
    what changed and the command that regenerates it. Nothing for a folder
    without a record (results made elsewhere, or before records existed).
    """
    if not (base_dir / provenance.FILE).is_file():
        return []
    stale = provenance.stale(base_dir)
    if not stale:
        return []
    return [f"warning: {base_dir} is older than the code it pins ({len(stale)} part(s) changed since it was made): "
            "its verdicts hold the new code to old code's numbers; once this comparison is read, regenerate it "
            "(`nearlight baseline`, which records the verdict)",
            *(f"  {line if len(line) <= 300 else line[:200] + ' ... ' + line[-90:]}" for line in stale)]


def compare_dirs(
    new_dir: str | os.PathLike, base_dir: str | os.PathLike, *, json_out: str | os.PathLike | None = None,
    **options: Any,
) -> tuple[list[Check], list[str]]:  # fmt: skip
    """Compare two sweep folders.

    Parameters
    ----------
    new_dir, base_dir : path-like
        Results folders of ``nearlight sweep`` (:func:`compare_frames`), or of ``nearlight score``
        (:func:`compare_scores`).
    json_out : path-like, optional
        Also write every check, the summary and the environment differences as JSON.
    **options
        As :func:`compare_frames` (``tolerance``, ``alpha``, ``include_runtime``).

    Returns
    -------
    checks : list of Check
    lines : list of str
        What to print: notes, environment differences, every check, a summary.
    """
    if json_out is not None:  # before any work: a file nearlight did not write is never replaced
        check_file_out(json_out, "comparison", flag="--json")
    new_dir, base_dir = Path(new_dir), Path(base_dir)
    new, new_complete = read_results(new_dir)
    base, _ = read_results(base_dir)
    mn, mb = read_sweep_json(new_dir), read_sweep_json(base_dir)
    axes = mb.get("axes")
    lines = []
    if _is_score(new) != _is_score(base):
        score_dir, sweep_dir = (new_dir, base_dir) if _is_score(new) else (base_dir, new_dir)
        raise UserError(f"{sweep_dir}: a sweep's results, and {score_dir} a scorecard's (`nearlight score`); "
                        f"compare like with like: two sweeps, or two score folders")  # fmt: skip
    scores = _is_score(new) and _is_score(base)
    if scores:
        new, note = _as_scores(new, base)
        lines.append(note)
        checks = compare_scores(new, base, categories=axes or (), **options)
        per_case, n_case = _continuous_cases(new, base, axes or (), options)
        if n_case:
            lines.append(f"note: continuous methods also case by case, value against value: {n_case} checks, "
                         f"{len(per_case)} beyond the exact class (listed)")
        checks += per_case
        unchecked = unpaired_cases(new, base)
        if unchecked:
            lines.append(f"note: {unchecked} case(s) of {new_dir} are not in the baseline: not checked")
    else:
        checks = compare_frames(new, base, axes=axes, **options)
        unchecked = unchecked_units(new, base, axes=axes)
        if unchecked:
            lines.append(f"note: {unchecked} unit(s) of {new_dir} (configuration and method) are not in the "
                         "baseline: not checked")  # fmt: skip

    if not new_complete:
        lines.append(f"note: {new_dir} is an incomplete sweep ({len(new)} rows)")
    if mn.get("sweep_hash") != mb.get("sweep_hash"):
        matched = ("cases are paired by case id" if scores
                   else f"units are matched by {', '.join(axes or ['config columns'])} and method")  # fmt: skip
        lines.append(
            f"note: different task lists ({mn.get('name')!r} {mn.get('sweep_hash')} vs {mb.get('name')!r} "
            f"{mb.get('sweep_hash')}): other seeds, methods or settings; {matched}"
        )
    lines += _stale_baseline(base_dir)
    env_new, env_base = read_environments(new_dir), read_environments(base_dir)

    diffs = differences(env_new[-1] if env_new else None, env_base[-1] if env_base else None)
    lines.append("environment: " + ("same as the baseline's" if not diffs else f"{len(diffs)} difference(s)"))
    lines += [f"  {d}" for d in diffs]
    lines += [c.line() for c in checks]
    counts = verdict_counts(checks)
    tested = (f"{sum(c.kind == 'paired' for c in checks)} paired case by case" if scores
              else f"{sum(c.kind == 'pooled' for c in checks)} pooled over seeds")  # fmt: skip
    summary = (
        f"{len(checks)} checks ({tested} at family-wise alpha "
        f"{options.get('alpha', 0.05):g}, tolerance {options.get('tolerance', 0.05):g}): "
        + ", ".join(f"{counts[v]} {v}" for v in VERDICTS)
    )
    regressions = [c for c in checks if c.regression]
    lines.append(f"WORSE than {base_dir}: {summary}" if regressions else f"ok: nothing worse than {base_dir}: {summary}")
    if json_out is not None:
        doc = {
            "new": str(new_dir), "baseline": str(base_dir), "regression": bool(regressions), "counts": counts,
            "options": {"tolerance": 0.05, "alpha": 0.05, "include_runtime": False, **options},
            "environment_differences": diffs,
            "checks": [{**dataclasses.asdict(c), "regression": c.regression} for c in checks],
        }  # fmt: skip
        write_json(json_out, jsonable(doc))
    return checks, lines
