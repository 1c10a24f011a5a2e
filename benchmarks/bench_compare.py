"""Benchmark: how often ``nearlight compare`` cries wolf, and the smallest regression it catches, per method.

On the smoke sweep (``sweeps/smoke.yaml``), every task is run once for the
baseline's seeds (0–9, what ``reports/smoke-baseline`` holds) and for a pool of
other seeds. Then, without running anything again:

- **false alarms**: ``--reruns`` seed-shifted re-runs, each the noise-free
  tasks plus 10 seeds drawn from the pool, are compared with the baseline
  (all checks of a run together: a run counts once if any check is flagged).
  Goal: at most 5 % (the family-wise ``alpha``). Also against the committed
  baseline folder, which was made on another machine or day.
- **power**, per method: the same re-runs with that method's lamp moved a
  fraction further along its ray from the highlight
  (:func:`nearlight.evaluation.planted.moved_along_ray`, the planted
  regression; the other methods' rows as they are), for several fractions;
  the rate at which a pooled check of that method on the noisy configurations
  flags it, and the smallest fraction caught in ≥ 95 % of re-runs, the
  minimum detectable bias (goal: ≤ 0.5 % of the lamp's distance for a method
  whose noisy error is small enough to see it; a method whose own error is
  tens of percent cannot show a bias of a fraction of a percent on 10 seeds,
  and the table says so). The noise-free configurations catch far smaller
  biases (their floor is 0.005 % of the distance); they are reported apart.

Re-runs drawn from one pool share seeds, so they are not independent: the
interval printed beside a rate is the binomial (Clopper–Pearson) one, a lower
bound on the true uncertainty. Printed, not asserted.

    .venv/bin/python benchmarks/bench_compare.py [--pool 150] [--reruns 200] [--workers 2]
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "sweeps" / "smoke.yaml"
BASELINE = ROOT / "reports" / "smoke-baseline"
BASE_SEEDS = list(range(10))
FRACTIONS = (0.001, 0.0025, 0.005, 0.01, 0.02, 0.05)


def _run(payload: dict, renderer: Any, cache_dir: str, fractions: tuple[float, ...]) -> tuple[dict, dict]:
    """One task's row, and the rows of its estimate moved along the ray by each fraction."""
    from nearlight.evaluation.planted import moved_along_ray
    from nearlight.evaluation.scoring.metrics import score
    from nearlight.evaluation.engine.tasks import noisy_capture, run_method

    clean = renderer.render(payload["scene"], cache_dir=Path(cache_dir))
    capture = noisy_capture(clean, payload)
    row: dict[str, Any] = {"status": "ok", "error": ""}
    try:
        est = run_method(capture, payload["method_spec"], payload["options"])
    except Exception as exc:  # a failing task is a row, as in the engine
        return {"status": "error", "error": str(exc)}, {}
    row.update(score(clean, est))
    moved = {f: {"status": "ok", "error": "", **score(clean, moved_along_ray(capture, est, f))} for f in fractions}
    return row, moved


def _rate(k: int, n: int) -> str:
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(0.95)
    return f"{k}/{n} = {100 * k / n:.1f} % (95 % CI {100 * ci.low:.1f}–{100 * ci.high:.1f} %)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pool", type=int, default=150, help="seeds beside the baseline's (default 150)")
    parser.add_argument("--reruns", type=int, default=200, help="seed-shifted re-runs to compare (default 200)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()

    from nearlight.evaluation.views.compare import compare_frames
    from nearlight.evaluation.engine.run import task_payload, task_row
    from nearlight.evaluation.engine.environment import code_version
    from nearlight.evaluation.engine.store import read_results
    from nearlight.evaluation.engine.sweep import load_sweep

    doc = yaml.safe_load(SMOKE.read_text())
    pool = list(range(len(BASE_SEEDS), len(BASE_SEEDS) + args.pool))
    sweep = load_sweep(doc | {"seeds": BASE_SEEDS + pool})
    axes = list(sweep.axes)
    print(f"smoke sweep, seeds 0-9 (baseline) + {args.pool} pool seeds: {len(sweep.tasks)} tasks", flush=True)

    t0 = time.perf_counter()
    rows, moved_rows = [], {f: [] for f in FRACTIONS}
    with tempfile.TemporaryDirectory() as cache:
        for key in sweep.render_keys:  # render once, in this process, before the workers share the cache
            sweep.renderer.prepare(next(t.scene for t in sweep.tasks if t.render_key == key), cache_dir=Path(cache))
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(args.workers, mp_context=ctx) as pool_ex:
            futs = {pool_ex.submit(_run, task_payload(t, sweep), sweep.renderer, cache, FRACTIONS): t for t in sweep.tasks}
            for i, fut in enumerate(cf.as_completed(futs), 1):
                t = futs[fut]
                row, moved = fut.result()
                rows.append(task_row(t, row, sweep=sweep, version=code_version()))
                for f, r in moved.items():
                    moved_rows[f].append(task_row(t, r, sweep=sweep, version=code_version()))
                if i % 50 == 0:
                    print(f"  {i}/{len(futs)} tasks, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    print(f"ran {len(rows)} tasks in {time.perf_counter() - t0:.0f} s on {args.workers} worker(s)")
    df = pd.DataFrame(rows)
    exact = df[~df["noisy"]]
    base = pd.concat([exact, df[df["noisy"] & df["seed"].isin(BASE_SEEDS)]])
    committed = read_results(BASELINE)[0] if (BASELINE / "results.parquet").is_file() else None

    rng = np.random.default_rng(0)
    reruns = [sorted(rng.choice(pool, size=len(BASE_SEEDS), replace=False)) for _ in range(args.reruns)]

    def rerun(frame: pd.DataFrame, seeds: list[int]) -> pd.DataFrame:
        return pd.concat([frame[~frame["noisy"]], frame[frame["noisy"] & frame["seed"].isin(seeds)]])

    alarms = {"own baseline (this machine, seeds 0-9)": 0, "committed baseline": 0}
    n_checks = None
    for seeds in reruns:
        new = rerun(df, seeds)
        checks = compare_frames(new, base, axes=axes, intervals=False)
        n_checks = len(checks)
        alarms["own baseline (this machine, seeds 0-9)"] += any(c.regression for c in checks)
        if committed is not None:
            alarms["committed baseline"] += any(c.regression for c in compare_frames(new, committed, axes=axes,
                                                                                     intervals=False))
    print(f"\nfalse alarms over {args.reruns} seed-shifted re-runs ({n_checks} checks each, alpha 0.05):")
    for name, k in alarms.items():
        if name == "committed baseline" and committed is None:
            continue
        print(f"  vs {name}: {_rate(k, args.reruns)}")

    moved = {f: pd.DataFrame(r) for f, r in moved_rows.items()}
    print("\nplanted regression: one method's lamp moved further along its ray, caught in how many re-runs")
    for method in dict.fromkeys(df["method"]):
        others = df[df["method"] != method]
        noisy_error = df.loc[(df["method"] == method) & df["noisy"] & (df["status"] == "ok"), "lamp_position_error_pct"]
        print(f"\n  {method} (its noisy tasks' median lamp error {noisy_error.median():.3g} %, "
              f"{int(noisy_error.count())} answered of {int(((df['method'] == method) & df['noisy']).sum())})")
        print("  fraction   noisy configurations (pooled)                 noise-free configurations (exact)")
        smallest = None
        for f in FRACTIONS:
            mine = moved[f][moved[f]["method"] == method] if not moved[f].empty else moved[f]
            planted = pd.concat([others, mine])
            pooled = exact_hit = 0
            for seeds in reruns:
                checks = compare_frames(rerun(planted, seeds), base, axes=axes, intervals=False)
                pooled += any(c.regression and c.method == method and c.kind == "pooled" for c in checks)
                exact_hit += any(c.regression and c.method == method and c.kind == "exact" for c in checks)
            print(f"  {100 * f:6.2f} %   {_rate(pooled, args.reruns):44s}  {_rate(exact_hit, args.reruns)}")
            if smallest is None and pooled >= 0.95 * args.reruns:
                smallest = f
        what = (f"{100 * smallest:.2f} % of the lamp's distance" if smallest is not None
                else f"none up to {100 * FRACTIONS[-1]:g} %")
        print(f"  minimum detectable bias of {method} on the noisy tasks (caught >= 95 %): {what}")


if __name__ == "__main__":
    main()
