"""``nearlight score``: run one method on every case of a built suite and write its scorecard.

The score folder is a results folder of the sweep engine's store (``sweep.json``,
``parts/<case id>.parquet``, ``results.parquet``, ``environment.json``): one row per
case with the suite's category columns, ``seed``, ``noisy``, ``method``, ``status``
and the metric columns of :func:`nearlight.evaluation.scoring.metrics.score`, so a re-run
skips scored cases and ``nearlight compare`` reads it as it reads a sweep. When every
case has its row the scorecard is written beside: ``scorecard.json``,
``scorecard.md`` and ``scorecard.png``.

The method gets the case's ``input`` capture without its truth
(:func:`nearlight.evaluation.suites.suite.strip_truth`); the row is scored against the
case's ``truth`` capture, read separately in the same worker after the method has
returned.

A scorecard is BOP-style recall: for each metric of :data:`LADDERS`, the fraction
of the cases of a category whose error is below each threshold. A failed case (the
method raised) and a case whose error is NaN (e.g. a σ the method declares
undetermined) are misses at every threshold. Medians count them as +inf and carry
a percentile-bootstrap 95 % interval (:data:`BOOTSTRAP` resamples, fixed seed).
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...capture import read_capture
from ...estimator.api import answer_and_verdict, rules_options
from ...estimator.sanity import UnsupportedEstimate, review
from ...errors import UserError
from ...files.atomic import write_json, write_text
from ...files.digests import file_sha256, stable_hash
from ...files.figures import pyplot, save_png
from ...files.jsonable import jsonable
from ...files.markdown import markdown_table
from ...files.outputs import check_file_out, check_folder
from ..engine.environment import code_version, machine
from ..engine.provenance import record
from ..engine.store import SWEEP_JSON, ResultStore, read_sweep_json, set_aside_damaged_parts
from ..engine.sweep import check_method
from ..engine.tasks import blank_row, failed_row
from ..engine.workers import completed, executing
from ..scoring.calibration import MAHALANOBIS_COLUMN, coverage, coverage_cells
from ..scoring.metrics import ESTIMATE_COLUMNS, INFO_COLUMNS, LOBE_COLUMN, METRICS, estimate_columns, score
from .ladders import LADDERS
from .results_file import RESULTS_JSONL, estimate_row, read_results, row_estimate, write_results
from .results_file import header as results_header
from .suite import INPUT, MANIFEST, TRUTH, checksum_problems, read_manifest, strip_truth, suite_cases

#: Bootstrap resamples of each median's interval, and its seed (a re-run gives the same interval).
BOOTSTRAP = 2000
BOOTSTRAP_SEED = 0
SCORECARD_JSON, SCORECARD_MD, SCORECARD_PNG = "scorecard.json", "scorecard.md", "scorecard.png"
#: First line of a scorecard's Markdown, and the JSON's ``format``: how nearlight recognises its own files.
MD_TITLE = "# Scorecard"
FORMAT = "nearlight-scorecard/1"
#: A score row's line of a results file (JSON text), from which ``results.jsonl`` is written.
ANSWER_COLUMN = "answer"


def score_case(case: Mapping[str, Any], *, method: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """Run ``method`` on one case's input (truth stripped) and score it against the case's truth.

    Parameters
    ----------
    case : mapping
        ``folder`` (the case's folder in the suite) and ``id``.
    method : str
        Built-in name or ``module:function``.
    options : mapping
        Method options.

    Returns
    -------
    dict
        ``status`` (``ok``; ``failed``: the estimate refused by :mod:`nearlight.estimator.sanity`; ``error``), ``error``, the :data:`METRICS` and ``INFO_COLUMNS``
        (NaN when not computed), ``runtime_s`` (s, the method alone), and :data:`ANSWER_COLUMN`: the case's
        line of a results file (:func:`~nearlight.evaluation.suites.results_file.estimate_row`, JSON). Never raises.
    """
    row = blank_row()
    stage, answer, verdict = "read", None, None
    try:
        seen = strip_truth(read_capture(Path(case["folder"]) / INPUT))
        stage = "estimate"
        t0 = time.perf_counter()
        answer, verdict = answer_and_verdict(seen, method=method, **options)
        row["runtime_s"] = time.perf_counter() - t0
        if not verdict.ok:
            raise UnsupportedEstimate(verdict)
        stage = "score"
        row = _graded(row, verdict, Path(case["folder"]))
    except Exception as exc:  # a failing case is a row (a miss), not a crashed run
        row = failed_row(row, stage, exc)
    error = row["error"] if stage != "score" and row["status"] != "ok" else None
    line = estimate_row(case["id"], answer, verdict, runtime_s=None, error=error)  # its time: the row's runtime_s
    return {**row, ANSWER_COLUMN: json.dumps(line, allow_nan=False)}


def score_reported(case: Mapping[str, Any], *, answer: Mapping[str, Any], method: str,
                   rules: Mapping[str, Any]) -> dict[str, Any]:  # fmt: skip
    """Score one case's row of a results file: a ``failed`` row is a failure with its reason, an ``ok`` row the
    :class:`~nearlight.estimator.Estimate` it states (:func:`~nearlight.evaluation.suites.results_file.row_estimate`),
    held to the rules of :mod:`nearlight.estimator.sanity` as a plug-in's answer is (``rules``: the header's
    ``rules``), then scored as :func:`score_case` scores. Its ``runtime_s`` is the reported one. Never raises."""
    row = blank_row()
    row["runtime_s"] = answer.get("runtime_s", math.nan)
    if answer["status"] != "ok":
        return {**row, "status": "failed", "error": answer["reason"]}
    stage = "review"
    try:
        seen = strip_truth(read_capture(Path(case["folder"]) / INPUT))
        verdict = review(seen, row_estimate(answer, method), rules)
        if not verdict.ok:
            raise UnsupportedEstimate(verdict)
        stage = "score"
        return _graded(row, verdict, Path(case["folder"]))
    except Exception as exc:
        return failed_row(row, stage, exc)


def _graded(row: dict[str, Any], verdict: Any, folder: Path) -> dict[str, Any]:
    """``row`` with the (accepted) estimate's columns and its scores against the case's truth."""
    row = {**row, **estimate_columns(verdict)}
    row.update(score(read_capture(folder / TRUTH), verdict))
    return row


def method_label(method: str, options: Mapping[str, Any]) -> str:
    """The method column: its name, with its options when any (``full[energy=radiance]``)."""
    return method + (f"[{','.join(f'{k}={v}' for k, v in sorted(options.items()))}]" if options else "")


def _run_hash(manifest: Mapping[str, Any], method: str, options: Mapping[str, Any]) -> str:
    return stable_hash([manifest["suite"], manifest["version"], manifest["cases_hash"], method, dict(options)])


def check_score_out(out: str | Path, manifest: Mapping[str, Any], method: str, options: Mapping[str, Any]) -> Path:
    """Raise :class:`UserError` unless ``out`` may hold this score run: a folder (or creatable) that holds
    no results or this run's, and whose scorecard and results files, when there, are nearlight's. Nothing is
    written. ``method`` and ``options`` name the run (for a results file: its sha256)."""
    out = check_folder(out, what="score folder")
    if (out / SWEEP_JSON).exists():
        old = read_sweep_json(out)
        if old.get("sweep_hash") != _run_hash(manifest, method, options):
            raise UserError(f"{out}: holds another run ({old.get('name')!r}); choose another --out or remove it")
    for name, kind in ((SCORECARD_PNG, "png"), (SCORECARD_JSON, "scorecard-json"), (SCORECARD_MD, "scorecard-md"),
                       (RESULTS_JSONL, "results")):  # fmt: skip
        check_file_out(out / name, kind)  # files.outputs.KINDS: how nearlight knows its own files
    return out


def score_suite(
    suite_dir: str | Path, out: str | Path, *, method: str | None = None, options: Mapping[str, Any] | None = None,
    results: str | Path | None = None, workers: int = 1, scheduler: Any = None, progress: bool = True,
    command: str | None = None,
) -> tuple[dict[str, Any] | None, dict[str, int]]:  # fmt: skip
    """Score ``method`` (or the answers of a ``results`` file) on every case of the built suite in ``suite_dir``
    (resumed in ``out``).

    Parameters
    ----------
    suite_dir : path-like
        A built suite (``manifest.json``); every file's sha256 is checked first.
    out : path-like
        Score folder (results rows, then the scorecard; with ``method``, also ``results.jsonl``: its
        answers as a results file).
    method : str, optional
        Built-in name or ``module:function``, run here.
    options : mapping, optional
        Method options.
    results : path-like, optional
        Instead of ``method``: a results file (:mod:`~nearlight.evaluation.suites.results_file`) of answers
        a method gave elsewhere; the scorecard is marked ``self_reported``, its run times as reported.
    workers, scheduler, progress
        As :func:`nearlight.evaluation.engine.run.run_sweep`.
    command : str, optional
        The command that regenerates ``out``, recorded in its ``provenance.json`` (with the hashes of
        the code that scored, so a committed scorecard goes stale when that code changes) by the run
        that completes it (default ``nearlight score SUITE_DIR --method METHOD --out OUT``).

    Returns
    -------
    scorecard : dict or None
        The scorecard (written as ``scorecard.json``/``.md``/``.png``), None when cases are missing.
    counts : dict
        ``ran``, ``skipped``, ``failed``.
    """
    if (method is None) == (results is None):
        raise ValueError("score_suite: give method or results, not both")
    options = dict(options or {})
    suite_dir = Path(suite_dir)
    manifest = read_manifest(suite_dir)
    reported = None
    if results is not None:
        head, answers = read_results(results, manifest, suite_cases(suite_dir, manifest))
        reported = {"file": Path(results).name, "sha256": file_sha256(results), "method_version": head["method_version"],
                    "machine": head["machine"]}  # fmt: skip
        label, run_method_name, run_options = head["method"], "results", {"sha256": reported["sha256"]}
        rules = {k: v for k, v in head["rules"].items() if v is not None}
    else:
        check_method(method, options, where="--method")
        label, run_method_name, run_options = method_label(method, options), method, options
    out = check_score_out(out, manifest, run_method_name, run_options)
    problems = checksum_problems(suite_dir, manifest)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise UserError(problems[0] + more + "; rebuild or re-download the suite")
    _check_category_names(suite_dir, manifest)
    t_start = time.perf_counter()
    cats = list(manifest["categories"])
    axes = list(manifest["cases"][0]["categories"]) if manifest["cases"] else []
    store = ResultStore(out, name=f"score {manifest['suite']} v{manifest['version']} {label}",
                        sweep_hash=_run_hash(manifest, run_method_name, run_options), n_tasks=len(manifest["cases"]),
                        axes=axes)  # fmt: skip
    for moved in set_aside_damaged_parts(out):  # as a sweep does: a re-run recomputes a damaged row
        print(f"nearlight: note: a damaged result part was moved to {moved}; its case is scored again", file=sys.stderr)
    done = store.done_ids()
    todo = [c for c in manifest["cases"] if c["id"] not in done]
    version = code_version()
    failed = 0
    with executing(workers, scheduler, running=f"method {label}") as executor:
        if reported is None:
            futs = {executor.submit(score_case, {"folder": str(suite_dir / c["path"]), "id": c["id"]}, method=method,
                                    options=options): c for c in todo}  # fmt: skip
        else:
            futs = {executor.submit(score_reported, {"folder": str(suite_dir / c["path"])}, answer=answers[c["id"]],
                                    method=label, rules=rules): c for c in todo}  # fmt: skip
        for fut in completed(executor, futs, desc=f"{manifest['suite']}: {label}", unit="case", progress=progress,
                             total=len(manifest["cases"]), initial=len(manifest["cases"]) - len(todo)):  # fmt: skip
            c = futs[fut]
            row = {"task_id": c["id"], "task_index": manifest["cases"].index(c), "sweep": manifest["suite"],
                   **c["categories"], "seed": c["seed"], "noisy": c["noisy"], "method": label,
                   "render_key": c["id"], "renderer": "suite", "code_version": version, **fut.result()}  # fmt: skip
            store.write_row(row)
            failed += row["status"] != "ok"
    df = store.consolidate()
    counts = {"ran": len(todo), "skipped": len(manifest["cases"]) - len(todo), "failed": failed}
    if df is None:
        return None, counts
    card = scorecard(df, manifest, label=label, categories=cats)
    card["machine"] = machine() if reported is None else reported["machine"]
    if reported is not None:
        card["self_reported"] = reported
    if todo:
        card["wall_s"] = time.perf_counter() - t_start
    elif (out / SCORECARD_JSON).is_file():  # a re-run that scored nothing keeps the wall time of the run that did
        card["wall_s"] = json.loads((out / SCORECARD_JSON).read_text()).get("wall_s")
    if todo:  # a re-run that scored nothing leaves the record of the run that made the rows
        default = f"--method {method}" if reported is None else f"--results {results}"
        record(out, command=command or f"nearlight score {suite_dir} {default} --out {out}", entry_modules=[__name__])
    if reported is None and ANSWER_COLUMN in df.columns and df[ANSWER_COLUMN].map(lambda a: isinstance(a, str)).all():
        # (rows resumed from a run made before results files have no answer: no results.jsonl then)
        _write_answers(out / RESULTS_JSONL, df, manifest, label=label, rules=rules_options(method, options))
    write_scorecard(card, out)
    return card, counts


def _write_answers(path: Path, df: pd.DataFrame, manifest: Mapping[str, Any], *, label: str,
                   rules: Mapping[str, Any]) -> Path:  # fmt: skip
    """The run's answers as a results file, in the suite's order (``nearlight score --results`` on it gives the
    same scorecard, run times aside)."""
    lines = {str(i): {**json.loads(str(a)), **({"runtime_s": float(t)} if np.isfinite(t) else {})}
             for i, a, t in zip(df["task_id"], df[ANSWER_COLUMN], df["runtime_s"].astype(float))}
    head = results_header(manifest, method=label, method_version=code_version(), machine=machine(), rules=rules)
    return write_results(path, head, [lines[c["id"]] for c in manifest["cases"]])


#: Columns of a score row that are not the case's categories (a category of the same name would replace them).
ROW_COLUMNS = ("task_id", "task_index", "sweep", "seed", "noisy", "method", "render_key", "renderer", "code_version",
               "status", "error", "runtime_s", LOBE_COLUMN, *METRICS, *INFO_COLUMNS, *ESTIMATE_COLUMNS, ANSWER_COLUMN)  # fmt: skip


def _check_category_names(suite_dir: Path, manifest: Mapping[str, Any]) -> None:
    """A (hand-edited) manifest's category named like a row column (``task_id``: the row's file name) is refused."""
    for i, c in enumerate(manifest["cases"]):
        clash = sorted(set(c["categories"]) & set(ROW_COLUMNS))
        if clash:
            raise UserError(f"{suite_dir / MANIFEST}: cases.{i}.categories.{clash[0]}: a category cannot be named like "
                            f"a column of the score's rows ({', '.join(ROW_COLUMNS[:12])}, the metrics, ...)")  # fmt: skip


def median_ci(x: np.ndarray, *, level: float = 0.95) -> tuple[float, float, float]:
    """Median of ``x`` (NaN read as +inf: a miss) and its percentile-bootstrap interval.

    Parameters
    ----------
    x : ndarray, shape (n,)
    level : float
        Coverage of the interval.

    Returns
    -------
    median, low, high : float
        NaN when ``x`` is empty; +inf where more than half (of a resample) are misses.
    """
    x = np.where(np.isnan(x), np.inf, np.asarray(x, dtype=float))
    if x.size == 0:
        return math.nan, math.nan, math.nan
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    meds = np.median(x[rng.integers(0, x.size, (BOOTSTRAP, x.size))], axis=1)
    a = (1.0 - level) / 2.0
    # "lower"/"higher": no interpolation, so an interval edge at +inf stays +inf (never inf - inf = NaN)
    return float(np.median(x)), float(np.quantile(meds, a, method="lower")), float(np.quantile(meds, 1 - a, method="higher"))


def _recalls(values: np.ndarray, thresholds: tuple[float, ...]) -> list[float]:
    """Fraction of ``values`` below each threshold (NaN, a miss or failure, is below none)."""
    v = np.where(np.isnan(values), np.inf, values)
    return [float(np.mean(v < t)) for t in thresholds]


def _group_stats(g: pd.DataFrame) -> dict[str, Any]:
    ok = (g["status"] == "ok").to_numpy()
    stats: dict[str, Any] = {"n": len(g), "failed": int((~ok).sum())}
    for metric, ladder in LADDERS.items():
        vals = np.where(ok, g[metric].to_numpy(dtype=float), np.nan)
        med, lo, hi = median_ci(vals)
        stats[metric] = {"recall": _recalls(vals, ladder.thresholds), "median": med, "median_ci95": [lo, hi]}
    if MAHALANOBIS_COLUMN in g.columns:  # rows written before the column existed have none
        stats["covariance"] = coverage(np.where(ok, g[MAHALANOBIS_COLUMN].to_numpy(dtype=float), np.nan))
    return stats


def scorecard(df: pd.DataFrame, manifest: Mapping[str, Any], *, label: str, categories: list[str]) -> dict[str, Any]:
    """The scorecard of a complete run's rows.

    Returns
    -------
    dict
        ``format``, ``suite``, ``version``, ``cases_hash``, ``method``, ``thresholds``
        (metric -> list), ``groups``: ``[{"category", "value", "n", "failed", <metric>: {"recall":
        [per threshold], "median", "median_ci95": [low, high]}, "covariance": {...}}]`` (first ``all``, then
        each value of each category; ``covariance`` the stated ellipsoid's figures,
        :func:`~nearlight.evaluation.scoring.calibration.coverage`), ``runtime_s`` (method seconds per case: median and total) and
        ``code_version``.
    """
    groups = [{"category": "all", "value": "all", **_group_stats(df)}]
    for cat in categories:
        for value, g in df.groupby(cat, sort=False, dropna=False):
            groups.append({"category": cat, "value": value, **_group_stats(g)})
    rt = df["runtime_s"].to_numpy(dtype=float)
    return {
        "format": FORMAT,
        "suite": manifest["suite"],
        "version": manifest["version"],
        "cases_hash": manifest["cases_hash"],
        "method": label,
        "cases": len(df),
        "failed": int((df["status"] != "ok").sum()),
        "thresholds": {m: list(ladder.thresholds) for m, ladder in LADDERS.items()},
        "groups": groups,
        "runtime_s": {"median": float(np.nanmedian(rt)) if np.isfinite(rt).any() else math.nan,
                      "total": float(np.nansum(rt))},  # fmt: skip
        "code_version": sorted(set(df["code_version"].astype(str))),
        "errors": sorted(set(df.loc[df["status"] != "ok", "error"].astype(str)))[:10],
    }


def _fmt(x: float, scale: float = 1.0) -> str:
    """``x × scale`` to three figures (– for NaN, ∞ for a median of misses)."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if math.isinf(x):
        return "∞"
    return f"{scale * x:.3g}"


def scorecard_markdown(card: Mapping[str, Any]) -> str:
    """The Markdown of a scorecard: one table per metric, recall (%) per threshold and category."""
    lines = [
        f"{MD_TITLE}: {card['method']} on {card['suite']} v{card['version']}",
        "",
        f"{card['cases']} cases (suite cases {card['cases_hash']}), {card['failed']} failed (misses at every "
        f"threshold). Method time: median {_fmt(card['runtime_s']['median'])} s per case, "
        f"{_fmt(card['runtime_s']['total'])} s in all"
        + (f"; wall {card['wall_s']:.1f} s." if card.get("wall_s") else ".")
        + (f" Machine: {card['machine']}." if card.get("machine") else ""),
        *_self_reported_lines(card),
        "",
        "Recall: % of the cases whose error is below each threshold (a failure or an undefined error is a miss). "
        "Median with its 95 % bootstrap interval (misses count as ∞).",
    ]
    for metric, ladder in LADDERS.items():
        if metric not in card["groups"][0]:  # a scorecard written before this metric had a ladder
            continue
        heads = [f"< {ladder.scale * t:g} {ladder.unit}" for t in ladder.thresholds]
        rows = []
        for g in card["groups"]:
            s = g[metric]
            lo, hi = s["median_ci95"]
            med = f"{_fmt(s['median'], ladder.scale)} [{_fmt(lo, ladder.scale)}, {_fmt(hi, ladder.scale)}] {ladder.unit}"
            rows.append([str(g["category"]), str(g["value"]), str(g["n"]), str(g["failed"]),
                         *(f"{100 * r:.0f}" for r in s["recall"]), med])  # fmt: skip
        lines += ["", f"## {ladder.label} ({metric}, {ladder.meaning})", "",
                  markdown_table(["category", "value", "n", "failed", *heads, "median [95 % CI]"], rows)]
    if any("covariance" in g for g in card["groups"]):
        rows = [[str(g["category"]), str(g["value"]), str(g["covariance"]["n"]), *coverage_cells(g["covariance"])]
                for g in card["groups"] if "covariance" in g]
        lines += ["", "## Covariance: the stated lamp ellipsoid", "",
                  "Cases with a covariance (one lamp; a method without one reads \"not given\"); the share of true "
                  "lamps inside the stated 95 % ellipsoid with its exact binomial 95 % interval (0.95 for a Gaussian "
                  "error of the stated size); the mean squared Mahalanobis distance over 3 with its 95 % bootstrap "
                  "interval (1 when the covariance equals the error's).", "",
                  markdown_table(["category", "value", "with covariance", "inside 95 % [CI]", "mean d²/3 [CI]"], rows)]
    if card.get("errors"):
        lines += ["", "## Failures (first distinct messages)", ""] + [f"- `{e}`" for e in card["errors"]]
    return "\n".join(lines) + "\n"


def _self_reported_lines(card: Mapping[str, Any]) -> list[str]:
    """The scorecard's line on a self-reported run (none for a method nearlight ran)."""
    rep = card.get("self_reported")
    if not rep:
        return []
    return ["", f"**Self-reported**: the answers of `{rep['file']}` (sha256 {rep['sha256'][:16]}…), method version "
                f"{rep['method_version']}, run elsewhere; its run times as the file reports them, not measured. Every "
                "answer was held to nearlight's rules (an estimate the data do not support is a failure), as a "
                "plug-in's is."]


def scorecard_figure(card: Mapping[str, Any], path: Path) -> Path:
    """Recall against threshold: one row of panels per category (and ``all``), one column per metric."""
    plt = pyplot()

    cats = list(dict.fromkeys(g["category"] for g in card["groups"]))
    fig, axs = plt.subplots(len(cats), len(LADDERS), figsize=(3.4 * len(LADDERS), 2.3 * len(cats)),
                            squeeze=False, sharex="col", sharey=True)  # fmt: skip
    for i, cat in enumerate(cats):
        for j, (metric, ladder) in enumerate(LADDERS.items()):
            ax = axs[i, j]
            x = np.array(ladder.thresholds) * ladder.scale
            for g in card["groups"]:
                if g["category"] == cat:
                    ax.plot(x, 100 * np.array(g[metric]["recall"]), marker="o", ms=3, label=f"{g['value']} (n={g['n']})")
            ax.set_xscale("log")
            ax.set_xticks(x, [f"{v:g}" for v in x])
            ax.minorticks_off()
            ax.set_ylim(-3, 103)
            ax.grid(alpha=0.3)
            if i == 0:
                ax.set_title(f"{ladder.label} error", fontsize=10)
            if i == len(cats) - 1:
                ax.set_xlabel(f"threshold ({ladder.unit})")
            if j == 0:
                ax.set_ylabel(f"{cat}\nrecall (%)", fontsize=9)
            if j == len(LADDERS) - 1:
                ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    fig.suptitle(f"{card['method']} on {card['suite']} v{card['version']} ({card['cases']} cases)", fontsize=11)
    fig.tight_layout()
    return save_png(fig, path)


def write_scorecard(card: Mapping[str, Any], out: Path) -> list[Path]:
    """Write ``scorecard.json``, ``scorecard.md`` and ``scorecard.png`` into ``out`` (checked beforehand
    by :func:`check_score_out`); returns their paths."""
    paths = [write_json(out / SCORECARD_JSON, jsonable(card))]
    text = scorecard_markdown(card)
    write_text(out / SCORECARD_MD, text)
    paths.append(out / SCORECARD_MD)
    paths.append(scorecard_figure(card, out / SCORECARD_PNG))
    return paths
