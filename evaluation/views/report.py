"""Tables and plots of a sweep's results: ``nearlight report DIR``.

Writes into ``DIR/report/``:

- ``summary.md``: every table below in Markdown, with the plots linked;
- ``overall.csv``: per method, n, failures, mean / median / 90th percentile of every metric;
- ``by_axis.csv``: the same per axis value and method (long form: axis, value, method, metric, stats);
- ``crlb.csv``: per configuration and method, the RMSE over seeds of the lamp position and σ
  beside their Cramér–Rao bounds and the ratio RMSE / bound (≥ 1 for an unbiased estimator);
- ``error_vs_<axis>.png``: median error (line) and 90th percentile (band) against each
  axis with several values, one line per method (not for an axis of named configurations,
  ``set`` or ``realism``: a line through labels in no order says nothing);
- for each ``set`` or ``realism`` axis, "which imperfection breaks which method"
  (:mod:`nearlight.evaluation.views.one_at_a_time`): ``one_at_a_time.csv`` (every such axis, long
  form) and ``one_at_a_time_<axis>.png`` (labels × methods heatmap), the tables in ``summary.md``;
- when a capture has several lamps or a method reports several (:mod:`nearlight.evaluation.scoring.matching`):
  ``lamps.csv``, per method the true lamps, the lamps found, matched, missed and extra (summed over
  tasks), the tasks that found every lamp and nothing else, and each true lamp's median position
  error; ``lamps.png``, the missed and extra lamps per method;
- when a method returned a covariance (:mod:`nearlight.evaluation.scoring.calibration`): ``covariance.csv``,
  per method (and per value of each varied axis) the share of truths inside its stated 95 % ellipsoid with
  its binomial interval and the mean squared Mahalanobis distance over 3; "not given" for the others;
- when configurations without camera noise ran several seeds (per-shot draws: ``camera.jitter_px``,
  analyzer jitter, lamp flicker), "luck" (:mod:`nearlight.evaluation.views.luck`): ``luck.csv``, the
  spread over those seeds beside what each axis does, and ``luck_vs_axes.png``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..engine.environment import code_version
from ..scoring.calibration import MAHALANOBIS_COLUMN, coverage_table
from ..scoring.matching import GATE_FRACTION
from ..scoring.metrics import COUNTED_COLUMN, LAMP_COUNT_COLUMNS, METRICS, PER_LAMP_COLUMN
from .one_at_a_time import LABEL_AXES, SPLIT, label_table, markdown_tables, plot_heatmap
from .winners import plot_winners, winners_table, winners_wide
from .luck import LUCK_PNG, luck_table, plot_luck
from ..engine.provenance import record
from ..engine.store import SWEEP_JSON, read_sweep_json, read_results
from ...files.atomic import write_text
from ...files.figures import pyplot, save_png
from ...files.markdown import markdown_table
from ...files.outputs import check_files_in, make_folder

#: Metrics shown in the Markdown tables and plots (all are in the CSV files).
HEADLINE = ("lamp_position_error_pct", "direction_error_deg", "distance_error_m", "sigma_rel_error", "ks_rel_error",
            "specular_rmse_rel", "runtime_s")
PLOTTED = ("lamp_position_error_pct", "direction_error_deg", "sigma_rel_error")


def p90(x: pd.Series) -> float:
    """90th percentile ignoring NaN (NaN when empty)."""
    x = x.dropna()
    return float(np.percentile(x, 90)) if len(x) else float("nan")


def stats(df: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Mean, median and 90th percentile of every metric of the successful rows, grouped by ``by``.

    Returns a long table: ``by`` columns, ``metric``, ``n``, ``mean``, ``median``, ``p90``.
    """
    ok = df[df["status"] == "ok"]
    cols = [m for m in METRICS if m in ok]
    long = ok.melt(id_vars=by, value_vars=cols, var_name="metric").dropna(subset=["value"])
    out = long.groupby([*by, "metric"], sort=False)["value"].agg(n="count", mean="mean", median="median", p90=p90)
    return out.reset_index()


def crlb_table(df: pd.DataFrame, axes: list[str]) -> pd.DataFrame:
    """RMSE over seeds beside the Cramér–Rao bound, per configuration and method.

    Columns: the axes, ``method``, ``n``, ``rmse_lamp_m``, ``crlb_lamp_m``,
    ``ratio_lamp``, ``rmse_sigma_rel``, ``crlb_sigma_rel``, ``ratio_sigma``.
    """
    ok = df[(df["status"] == "ok") & np.isfinite(df.get("crlb_lamp_m", pd.Series(dtype=float)))]
    if ok.empty:
        return pd.DataFrame()
    g = ok.assign(l2=ok["lamp_position_error_m"] ** 2, s2=ok["sigma_rel_error"] ** 2).groupby(
        [*axes, "method"], sort=False, dropna=False
    )
    t = g.agg(n=("l2", "size"), ms_l=("l2", "mean"), crlb_lamp_m=("crlb_lamp_m", "mean"), ms_s=("s2", "mean"),
              crlb_sigma_rel=("crlb_sigma_rel", "mean")).reset_index()
    t["rmse_lamp_m"] = np.sqrt(t.pop("ms_l"))
    t["rmse_sigma_rel"] = np.sqrt(t.pop("ms_s"))
    t["ratio_lamp"] = t["rmse_lamp_m"] / t["crlb_lamp_m"]
    t["ratio_sigma"] = t["rmse_sigma_rel"] / t["crlb_sigma_rel"]
    return t[[*axes, "method", "n", "rmse_lamp_m", "crlb_lamp_m", "ratio_lamp", "rmse_sigma_rel", "crlb_sigma_rel",
              "ratio_sigma"]]


def frame_table(df: pd.DataFrame, *, floatfmt: str = ".4g") -> str:
    """``df`` as a Markdown table (:func:`~nearlight.files.markdown.markdown_table`): a header of its columns,
    one line per row, floats formatted by ``floatfmt``, everything else by ``str``."""
    rows = ([format(v, floatfmt) if isinstance(v, (float, np.floating)) else str(v) for v in row]
            for row in df.itertuples(index=False))  # fmt: skip
    return markdown_table([str(c) for c in df.columns], rows)


def _wide(st: pd.DataFrame, index: list[str]) -> pd.DataFrame:
    """Headline metrics as ``median (p90)`` cells, one column per metric."""
    st = st[st["metric"].isin(HEADLINE)]
    cell = st.assign(cell=[f"{m:.3g} ({p:.3g})" for m, p in zip(st["median"], st["p90"])])
    wide = cell.pivot_table(index=index, columns="metric", values="cell", aggfunc="first", sort=False)
    return wide[[m for m in HEADLINE if m in wide.columns]].reset_index()


def plot_axis(df: pd.DataFrame, axis: str, path: Path) -> None:
    """PNG: median (line) and 90th percentile (band) of :data:`PLOTTED` against ``axis``, one line per method."""
    plt = pyplot()

    ok = df[df["status"] == "ok"]
    values = list(dict.fromkeys(df[axis]))
    numeric = all(isinstance(v, (int, float, np.number)) for v in values)
    if numeric:
        values = sorted(values)
    x = np.asarray(values, dtype=float) if numeric else np.arange(len(values))
    fig, axs = plt.subplots(1, len(PLOTTED), figsize=(4.2 * len(PLOTTED), 3.4), constrained_layout=True)
    for ax, metric in zip(axs, PLOTTED):
        for method, grp in ok.groupby("method", sort=False):
            g = grp.groupby(axis)[metric]
            med = np.array([g.median().get(v, np.nan) for v in values], dtype=float)
            hi = np.array([p90(g.get_group(v)) if v in g.groups else np.nan for v in values], dtype=float)
            (line,) = ax.plot(x, med, "o-", label=str(method))
            ax.fill_between(x, med, hi, color=line.get_color(), alpha=0.15, linewidth=0)
        ax.set_xlabel(axis)
        ax.set_ylabel(f"{metric} [{METRICS[metric]}]")
        if not numeric:
            ax.set_xticks(x, [str(v) for v in values], rotation=20)
        finite = ok[metric].replace(0, np.nan).dropna()
        if len(finite) and finite.max() / max(finite.min(), 1e-300) > 100:
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
        if ok.empty:  # every task failed: the failures are in the tables, not a curve
            ax.text(0.5, 0.5, "no task succeeded", transform=ax.transAxes, ha="center", va="center")
    if not ok.empty:
        axs[0].legend(fontsize=8)
    fig.suptitle(f"error vs {axis}: median (line), 90th percentile (band)")
    save_png(fig, path, dpi=110)


def lamp_table(df: pd.DataFrame) -> pd.DataFrame:
    """Lamps found, matched, missed and extra per method (an empty frame when every row has one true lamp and
    one estimated lamp from a method that did not count them, as every sweep before several lamps: then
    nothing is written; a method that counts, ``lamps=auto``, shows its count even on one-lamp captures).

    Columns: ``method``, ``tasks`` (successful), ``lamps_true``, ``lamps_found``, ``matched``,
    ``missed``, ``extra`` (sums over the tasks), ``all_found`` (tasks with nothing missed and nothing
    extra), and ``lamp<i>_median_error_pct`` for every true lamp index of a several-lamp capture
    (median over the tasks where it was matched).
    """
    if not all(c in df for c in LAMP_COUNT_COLUMNS):
        return pd.DataFrame()
    ok = df[df["status"] == "ok"]
    counted = ok[COUNTED_COLUMN] == 1 if COUNTED_COLUMN in ok else False
    if not ((ok["n_lamps_true"] > 1) | (ok["n_lamps_found"] > 1) | counted).any():
        return pd.DataFrame()
    per_lamp = [c for c in ok.columns if PER_LAMP_COLUMN.match(c) and c.endswith("_pct")]
    g = ok.assign(matched=ok["n_lamps_true"] - ok["lamps_missed"],
                  clean=(ok["lamps_missed"] == 0) & (ok["lamps_extra"] == 0)).groupby("method", sort=False)
    t = g.agg(tasks=("status", "size"), lamps_true=("n_lamps_true", "sum"), lamps_found=("n_lamps_found", "sum"),
              matched=("matched", "sum"), missed=("lamps_missed", "sum"), extra=("lamps_extra", "sum"),
              all_found=("clean", "sum"))
    for c in sorted(per_lamp, key=lambda c: int(c[4:c.index("_")])):
        t[c.replace("_position_error_pct", "_median_error_pct")] = g[c].median()
    int_cols = ["lamps_true", "lamps_found", "matched", "missed", "extra", "all_found"]
    return t.astype({c: int for c in int_cols}).reset_index()


def lamps_by_label(df: pd.DataFrame, axis: str) -> pd.DataFrame:
    """Per label of a one-at-a-time ``axis`` and method: how often every lamp was found, and the highlights in the image.

    Where the two highlights of a separation sweep merge (``highlights``
    drops to 1) and which method still finds every lamp there: the "merge
    point" of each method is the label below which its count falls.

    Returns
    -------
    DataFrame
        Long table in the sweep's order, one row per label and method of the
        labels with several true lamps: ``axis``, ``label``, ``method``,
        ``tasks``, ``all_found`` (successful tasks with nothing missed and
        nothing extra; failed ones count as not found), ``highlights_min``
        and ``highlights_max`` (the range of ``highlights_true`` over the
        label's rows, the separate highlights of the noise-free specular
        image, which the other axes can change: at one separation equal
        lamps may show two and a faint one a single blob; NaN where not
        measured). Empty when ``df`` has no several-lamp rows.
    """
    if "n_lamps_true" not in df:
        return pd.DataFrame()
    several = df[df[axis].isin(set(df.loc[df["n_lamps_true"] > 1, axis]))]  # failed rows have no count: by label
    if several.empty:
        return pd.DataFrame()
    several = several.sort_values("task_index")
    clean = (several["status"] == "ok") & (several["lamps_missed"] == 0) & (several["lamps_extra"] == 0)
    rows = []
    for label, g in several.groupby(axis, sort=False):
        seen = g["highlights_true"] if "highlights_true" in g else pd.Series(dtype=float)
        for method, m in g.groupby("method", sort=False):
            rows.append({"axis": axis, "label": label, "method": method, "tasks": len(m),
                         "all_found": int(clean[m.index].sum()), "highlights_min": float(seen.min()),
                         "highlights_max": float(seen.max())})
    return pd.DataFrame(rows)


def _lamps_by_wide(table: pd.DataFrame) -> pd.DataFrame:
    """:func:`lamps_by_label`'s table for the summary: rows the labels, ``highlights`` (``1`` or a range ``1–2``),
    a ``k/n`` column per method."""
    wide = table.assign(cell=table["all_found"].astype(str) + "/" + table["tasks"].astype(str)).pivot_table(
        index="label", columns="method", values="cell", aggfunc="first", sort=False)
    first = table.groupby("label", sort=False)[["highlights_min", "highlights_max"]].first()
    seen = pd.Series([f"{lo:g}" if lo == hi else f"{lo:g}–{hi:g}" for lo, hi in first.itertuples(index=False)],
                     index=first.index, name="highlights")
    axis = table["axis"].iloc[0]
    return pd.concat([seen, wide], axis=1).rename_axis(index=axis, columns=None).reset_index()


def plot_lamps(table: pd.DataFrame, path: Path) -> None:
    """PNG: missed and extra lamps per method (bars), beside the true lamps they are out of."""
    plt = pyplot()
    import matplotlib.ticker

    x = np.arange(len(table))
    fig, ax = plt.subplots(figsize=(max(4.0, 1.2 * len(table) + 2), 3.4), constrained_layout=True)
    for k, (col, label) in enumerate((("lamps_true", "true lamps"), ("matched", "matched"), ("missed", "missed"),
                                      ("extra", "extra"))):
        ax.bar(x + (k - 1.5) * 0.2, table[col], width=0.2, label=label)
    ax.set_xticks(x, [str(m) for m in table["method"]], rotation=20)
    ax.set_ylabel("lamps (summed over tasks)")
    ax.yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.suptitle("lamps matched, missed and extra per method")
    save_png(fig, path, dpi=110)


def report_files(varied: list[str], labelled: list[str] = (), luck: bool = False,
                 lamps: bool = False, covariance: bool = False, winners: bool = False) -> dict[str, str]:
    """``{file name: kind}`` of every file a report writes (kinds: :data:`nearlight.files.outputs.KINDS`).

    ``varied``: the axes with several values; ``labelled``: the axes of named configurations
    (:data:`~nearlight.evaluation.views.one_at_a_time.LABEL_AXES`) the sweep has; ``luck``: whether the
    luck section is written (:func:`~nearlight.evaluation.views.luck.luck_table` not empty); ``lamps``:
    whether the lamps section is (:func:`lamp_table` not empty); ``covariance``: whether a method returned a
    covariance (:func:`covariance_tables` not empty); ``winners``: whether the winners section is
    (:func:`~nearlight.evaluation.views.winners.winners_table` not empty).
    """
    files = {"summary.md": "report-md", "overall.csv": "report-csv", "by_axis.csv": "report-csv",
             "crlb.csv": "report-csv"}  # fmt: skip
    files.update({_png_name(a): "png" for a in varied if a not in LABEL_AXES})
    if labelled:
        files["one_at_a_time.csv"] = "report-csv"
        files.update({_heatmap_name(a): "png" for a in labelled})
    if luck:
        files.update({"luck.csv": "report-csv", LUCK_PNG: "png"})
    if lamps:
        files.update({"lamps.csv": "report-csv", "lamps.png": "png"})
        files.update({_lamps_by_name(a): "report-csv" for a in labelled})
    if covariance:
        files["covariance.csv"] = "report-csv"
    if winners:
        files.update({"winners.csv": "report-csv", "winners.png": "png"})
    return files


def covariance_tables(df: pd.DataFrame, varied: list[str]) -> tuple[pd.DataFrame, list[tuple[str, pd.DataFrame]]]:
    """The covariance section's tables: per method (every method; "not given" without a covariance), and per
    value of each ``varied`` axis and method (the methods with a covariance only); both empty when no method
    returned one."""
    if MAHALANOBIS_COLUMN not in df.columns or not np.isfinite(df[MAHALANOBIS_COLUMN].to_numpy(dtype=float)).any():
        return pd.DataFrame(), []
    given = df.groupby("method", sort=False)[MAHALANOBIS_COLUMN].transform(
        lambda v: np.isfinite(v.to_numpy(dtype=float)).any())
    return coverage_table(df, ["method"]), [(a, coverage_table(df[given], [a, "method"])) for a in varied]


def _lamps_by_name(axis: str) -> str:
    return f"lamps_by_{axis.replace('.', '_')}.csv"


def _png_name(axis: str) -> str:
    return f"error_vs_{axis.replace('.', '_')}.png"


def _heatmap_name(axis: str) -> str:
    return f"one_at_a_time_{axis}.png"


def write_report(
    results_dir: str | os.PathLike, *, out: str | os.PathLike | None = None, command: str | None = None
) -> Path:
    """Write the tables and plots of a sweep folder; returns the report folder.

    The report's part of ``DIR/provenance.json`` records ``command`` (default
    ``nearlight report DIR``) and the code the report was made with
    (:mod:`nearlight.evaluation.engine.provenance`).

    The report folder (default ``DIR/report``) and every file the report
    writes there (:func:`report_files`) are checked before anything is
    written: an existing file is replaced only when it is of the kind the
    report writes; other files in the folder are left alone.

    Raises
    ------
    UserError
        No results, a damaged results file, or a report place that cannot be written.
    """
    results_dir = Path(results_dir)
    df, complete = read_results(results_dir)
    manifest = results_dir / SWEEP_JSON
    info = read_sweep_json(results_dir) if manifest.exists() else {}
    axes = [a for a in info.get("axes", []) if isinstance(a, str) and a in df.columns]
    varied = [a for a in axes if df[a].nunique() > 1]
    labelled = [a for a in axes if a in LABEL_AXES]
    folder = Path(out) if out is not None else results_dir / "report"
    luck = luck_table(df, axes)
    lamps = lamp_table(df)
    cov_overall, cov_by = covariance_tables(df, varied)
    wins = winners_table(df, varied)
    check_files_in(folder, report_files(varied, labelled, luck=not luck.empty, lamps=not lamps.empty,
                                        covariance=not cov_overall.empty, winners=not wins.empty))
    make_folder(folder, what="report folder")

    overall = stats(df, ["method"])
    write_text(folder / "overall.csv", overall.to_csv(index=False), what="the report")
    frames = [stats(df, [a, "method"]).rename(columns={a: "value"}).assign(axis=a) for a in varied]
    by_axis = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    if not by_axis.empty:
        by_axis["value"] = by_axis["value"].astype(str)
        by_axis = by_axis[["axis", "value", "method", "metric", "n", "mean", "median", "p90"]]
    write_text(folder / "by_axis.csv", by_axis.to_csv(index=False), what="the report")
    bound = crlb_table(df, axes)
    write_text(folder / "crlb.csv", bound.to_csv(index=False), what="the report")

    counts = df.groupby("method", sort=False)["status"].agg(tasks="size", failed=lambda s: int((s != "ok").sum()))
    md = [f"# Sweep report: {info.get('name', results_dir.name)}", ""]
    if not complete:
        md += [f"**Incomplete sweep: {len(df)} of {info.get('tasks', '?')} tasks have rows.**", ""]
    md += [f"{len(df)} tasks; code version(s): {', '.join(sorted(df['code_version'].astype(str).unique()))}; "
           f"report written by {code_version()}; {renderers_line(df)}.",
           "Cells: median (90th percentile) over successful tasks. Units: "
           + "; ".join(f"{m} [{METRICS[m]}]" for m in HEADLINE) + ".", "",
           "## Overall", "", frame_table(counts.reset_index()), "", frame_table(_wide(overall, ["method"])), ""]
    if not lamps.empty:
        write_text(folder / "lamps.csv", lamps.to_csv(index=False), what="the report")
        plot_lamps(lamps, folder / "lamps.png")
        md += ["## Lamps found", "",
               "Estimated lamps matched to true ones (Hungarian on the position error, within "
               f"{100 * GATE_FRACTION:g} % of each true lamp's distance from its highlight: "
               "`nearlight.evaluation.scoring.matching`), summed over each method's successful tasks. A task's lamp errors are the worst over its true lamps and NaN when one was "
               "missed, so the other tables leave such a task out of the lamp medians (their `n` is smaller): "
               "read them with `missed` here. `all_found`: tasks with nothing missed and nothing extra; "
               "`lamp<i>_median_error_pct`: true lamp i's median error where it was matched.", "",
               frame_table(lamps), "", "![lamps matched, missed and extra](lamps.png)", ""]
        for a in labelled:
            by = lamps_by_label(df, a)
            if by.empty:
                continue
            write_text(folder / _lamps_by_name(a), by.to_csv(index=False), what="the report")
            md += [f"### Every lamp found, by {a}", "",
                   "`highlights`: separate highlights in the noise-free specular image (the estimators' "
                   "segmentation, `nearlight.estimator.highlights.segment_highlights`; 1 where the lamps' highlights "
                   "have merged into one blob), a range where the other axes change it; per method, the tasks that found every lamp and nothing extra, "
                   "of its tasks (failed ones count as not found).", "", frame_table(_lamps_by_wide(by)), ""]
    if not wins.empty:
        write_text(folder / "winners.csv", wins.to_csv(index=False), what="the report")
        plot_winners(wins, varied, folder / "winners.png")
        md += ["## Which method wins where", "",
               f"Per configuration, each method's median lamp position error (mm) with its 95 % bootstrap interval "
               f"over the seeds (a failure is a miss, +∞); `winner`: the method whose interval lies wholly below "
               f"every other's, or the methods the best cannot be told from. `winners.csv` adds each method's RMSE "
               f"and how often the true lamp fell inside its own 95 % ellipsoid, with the exact binomial interval "
               f"(`nearlight.evaluation.views.winners`).", "", frame_table(winners_wide(wins, varied)), "",
               "![which method wins where](winners.png)", ""]
    if not cov_overall.empty:
        long = pd.concat([cov_overall.assign(axis="all", value="all")]
                         + [t.rename(columns={a: "value"}).assign(axis=a) for a, t in cov_by], ignore_index=True)
        long["value"] = long["value"].astype(str)
        write_text(folder / "covariance.csv", long[["axis", "value", *cov_overall.columns]].to_csv(index=False),
                   what="the report")
        md += ["## Covariance: is the stated lamp ellipsoid right?", "",
               "Per method that returns a covariance, over its successful tasks with one lamp: `inside_95`, the "
               "share of true lamps inside the stated 95 % ellipsoid with its exact binomial 95 % interval (0.95 "
               "for a Gaussian error of the stated size); `mean_d2_over_3`, the mean squared Mahalanobis distance "
               "over 3 with its 95 % bootstrap interval (1 when the covariance equals the error's, whatever the "
               "error's distribution; 100 means the stated standard deviations are 10 times too small). A "
               "covariance holds the noise's share of the error, not a bias's: on a noise-free capture it is "
               "float rounding's, and its distances read the model's own discretisation; under a rig "
               "imperfection the method does not model they read that imperfection's bias (`full` warns when "
               "its residuals show it). `nearlight.evaluation.scoring.calibration`.", "", frame_table(cov_overall), ""]
        for a, t in cov_by:
            md += [f"### Covariance by {a}", "", frame_table(t), ""]
    tables = [label_table(df, a) for a in labelled]
    if tables:
        write_text(folder / "one_at_a_time.csv", pd.concat(tables, ignore_index=True).to_csv(index=False), what="the report")
    for a, table in zip(labelled, tables):
        pooled = [x for x in varied if x not in (a, SPLIT)]
        md += [f"## Which imperfection breaks which method ({a})", "",
               f"Median (90th percentile where a label ran several seeds) of lamp_position_error_pct "
               f"[{METRICS['lamp_position_error_pct']}] per {a} label and method"
               + (f", pooled over {', '.join(pooled)}" if pooled else "") + ". A failed task (an error, or no "
               "usable estimate: a NaN error) counts as worse than any error: a cell reads `k/n failed` when "
               "k of its n runs failed and that is half or more (the median is a failure); fewer failures are "
               "counted after the median (`, k/n failed`). A run that left a true lamp unmatched (several lamps) "
               "counts the same way and reads `missed a lamp`.", ""]
        for obj, wide in markdown_tables(table, a):
            md += ([f"### {obj}", ""] if obj else []) + [frame_table(wide), ""]
        plot_heatmap(table, a, folder / _heatmap_name(a))
        md += [f"![which imperfection breaks which method ({a})]({_heatmap_name(a)})", ""]
    for a in varied:
        st = stats(df, [a, "method"])
        md += [f"## By {a}", "", frame_table(_wide(st, [a, "method"])), ""]
        if a not in LABEL_AXES:
            png = _png_name(a)
            plot_axis(df, a, folder / png)
            md += [f"![error vs {a}]({png})", ""]
    if not luck.empty:
        write_text(folder / "luck.csv", luck.to_csv(index=False), what="the report")
        plot_luck(df, axes, folder / LUCK_PNG)
        md += ["## Luck: the spread over seeds without camera noise", "",
               "Configurations without camera or range noise that still ran several seeds draw something per "
               "shot (where the pixel grid falls on the highlight: `camera.jitter_px`; analyzer jitter; lamp "
               "flicker). `luck`: the max − min of lamp_position_error_pct over one configuration's seeds, median "
               "and 90th percentile over configurations; `<axis> effect`: how far the method's median error "
               "moves between that axis's values (max − min, median over the other axes' configurations). "
               "Percentage points. A method whose luck is as large as the axes' effects is set by sampling luck, "
               "not by what the sweep varies.", "", frame_table(luck, floatfmt=".3g"), "", f"![luck]({LUCK_PNG})", ""]
    if not bound.empty:
        md += ["## Cramér–Rao bounds (Gaussian camera noise)", "",
               "RMSE over seeds of each method beside the bound for the same configuration; ratio = RMSE / bound "
               "(1 is the best an unbiased estimator can do). Lamp: metres; sigma: relative.", "",
               frame_table(bound), ""]
    failed = df[df["status"] != "ok"]
    if len(failed):
        md += ["## Failed tasks", "", frame_table(failed[["task_index", "method", "error"]].head(50)), ""]
    write_text(folder / "summary.md", "\n".join(md), what="the report")
    record(results_dir, command=command or f"nearlight report {results_dir}" + (f" --out {out}" if out else ""),
           entry_modules=[__name__], part="report")
    return folder


def renderers_line(df: pd.DataFrame) -> str:
    """Which renderer made the rows: ``rendered by mitsuba`` or, for ``renderer: auto``, each with its count of
    tasks (``rendered by closed-form (4800 tasks), mitsuba (240)``)."""
    if "renderer" not in df.columns:
        return "renderer not recorded"
    counts = df["renderer"].astype(str).value_counts()
    if len(counts) == 1:
        return f"rendered by {counts.index[0]}"
    first, *rest = counts.items()
    return "rendered by " + ", ".join([f"{first[0]} ({first[1]} tasks)", *(f"{k} ({v})" for k, v in rest)])
