"""Regression verdicts (nearlight.evaluation.views.compare) on synthetic result rows: exact and pooled checks,
failures, missing units, the family-wise false-alarm rate and the power against a planted shift."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from nearlight.errors import UserError
from nearlight.evaluation.views.compare import EXACT_FLOOR, MIN_SEEDS, compare_frames

METRIC = "lamp_position_error_m"


def _rows(rng, *, seeds, methods=("a", "b"), distances=(0.3, 0.5), scale=1.0, shift=0.0, noisy=True):
    """Rows like a sweep's: per (distance, method) unit one row per seed, the error a folded normal
    (like a lamp error's magnitude) of mean ~1 mm, optionally scaled / shifted for method "a"."""
    rows = []
    for d in distances:
        for m in methods:
            for s in seeds:
                e = abs(rng.normal(1e-3, 5e-4)) if noisy else 1e-3 * d
                if m == "a":
                    e = e * scale + shift
                rows.append({"lamp_distance": d, "noise": "sensor" if noisy else "none", "method": m, "seed": s,
                             "noisy": noisy, "status": "ok", "error": "", METRIC: e, "sigma_rel_error": e * 10})
    return pd.DataFrame(rows)


AXES = ["lamp_distance", "noise"]


def _regressions(checks):
    return [c for c in checks if c.regression]


def test_identical_results_are_all_same(rng):
    df = _rows(rng, seeds=range(10))
    checks = compare_frames(df, df, axes=AXES)
    # 2 distances x 2 methods = 4 units, each: failures + 2 metrics
    assert len(checks) == 12 and {c.verdict for c in checks} == {"same"}
    assert {c.kind for c in checks} == {"pooled"}


def test_exact_units_compare_value_against_value(rng):
    base = _rows(rng, seeds=[0], noisy=False)
    assert {c.kind for c in compare_frames(base, base, axes=AXES)} == {"exact"}
    # a change below the cross-machine floor is not a change; one above tolerance + floor is
    tiny = base.assign(**{METRIC: base[METRIC] + 0.5 * EXACT_FLOOR[METRIC]})
    assert not _regressions(compare_frames(tiny, base, axes=AXES))
    worse = base.copy()
    worse.loc[worse["method"] == "a", METRIC] *= 1.5
    got = _regressions(compare_frames(worse, base, axes=AXES))
    assert {(c.method, c.metric, c.kind) for c in got} == {("a", METRIC, "exact")} and len(got) == 2
    # improvements are reported too
    better = base.copy()
    better.loc[better["method"] == "b", METRIC] *= 0.5
    assert sum(c.verdict == "better" for c in compare_frames(better, base, axes=AXES)) == 2
    # within a generous tolerance it is not a regression
    assert not _regressions(compare_frames(worse, base, axes=AXES, tolerance=0.6))


def test_failures_and_missing_units_are_regressions(rng):
    base = _rows(rng, seeds=[0], noisy=False)
    new = base.copy()
    new.loc[0, ["status", "error", METRIC, "sigma_rel_error"]] = ["error", "boom", np.nan, np.nan]
    got = _regressions(compare_frames(new, base, axes=AXES))
    assert [(c.metric, c.base, c.new) for c in got] == [("failures", 0, 1)]
    gone = base[base["method"] != "b"]
    got = _regressions(compare_frames(gone, base, axes=AXES))
    assert {c.verdict for c in got} == {"missing"} and len(got) == 2  # method b at 2 distances


def test_pooled_units_need_enough_seeds(rng):
    base = _rows(rng, seeds=range(MIN_SEEDS - 1))
    new = _rows(rng, seeds=range(100, 100 + MIN_SEEDS - 1), scale=3.0)
    checks = [c for c in compare_frames(new, base, axes=AXES) if c.metric == METRIC]
    assert {c.verdict for c in checks} == {"inconclusive"}


def test_pooled_shift_is_caught_with_its_interval(rng):
    base = _rows(rng, seeds=range(10))
    new = _rows(rng, seeds=range(100, 110), shift=2e-3)  # method "a": +2 mm on a ~1 mm error, 4 sd
    got = [c for c in compare_frames(new, base, axes=AXES) if c.regression]
    assert {(c.method, c.metric) for c in got} == {("a", METRIC), ("a", "sigma_rel_error")}
    for c in got:
        assert c.kind == "pooled" and c.low > 0 and c.p_value < 0.01
        true = 2e-3 * (10 if c.metric == "sigma_rel_error" else 1)
        assert c.low < true < c.high


def test_family_wise_false_alarm_rate_of_seed_shifted_reruns():
    # 200 re-runs with other seeds of a sweep with 4 pooled units x 3 checks; the Sidak correction at
    # alpha = 0.05 bounds the chance that any check of a run is flagged by 5 %. The two metrics of a unit
    # are perfectly correlated here (sigma = 10 x lamp), so the family behaves like 8 checks and the rate
    # sits below alpha. Binomial standard error at 5 % over 200 runs: 1.5 %; we allow alpha + 3 SE.
    rng = np.random.default_rng(20261125)
    base = _rows(rng, seeds=range(10))
    flagged = 0
    for k in range(200):
        new = _rows(rng, seeds=range(100 + 10 * k, 110 + 10 * k))
        flagged += bool(_regressions(compare_frames(new, base, axes=AXES, intervals=False)))
    assert flagged / 200 <= 0.05 + 3 * 0.0154


@pytest.mark.parametrize("bad", [{"tolerance": float("nan")}, {"tolerance": -0.1}, {"alpha": 0.0}, {"alpha": 1.5}])
def test_bad_options_are_one_line_errors(rng, bad):
    df = _rows(rng, seeds=range(2))
    with pytest.raises(UserError, match="--tolerance|--alpha"):
        compare_frames(df, df, axes=AXES, **bad)
