"""Which imperfection breaks which method: the report's view of a one-at-a-time sweep.

A sweep with a ``set`` axis (each label its own scene keys, docs/sweep-files.md)
or a ``realism`` axis (the rig profiles) compares named configurations one
at a time. ``nearlight report`` (:mod:`nearlight.evaluation.views.report`) adds, per
such axis, a table with one row per label (in the sweep file's order) and one
column per method: the median lamp position error over the label's rows, with
the 90th percentile where the label ran several seeds; one table per object
when the sweep has an ``object`` axis (a nuisance may break a method on a board
and not on a sphere, and a pooled median would hide it); other axes are pooled.
A failed task (``status`` error, or a NaN error: no usable estimate) is not
dropped: it counts as an error worse than any other, so a label on which most
runs fail shows a failed median, and every cell says how many failed. A run
that found too few lamps (a several-lamp capture with a true lamp left
unmatched, :mod:`~nearlight.evaluation.scoring.matching`: its worst-lamp error is NaN)
counts the same way but is named for what it is, ``missed`` (a lamp), not
``failed`` (the method ran and answered).
Beside the table, a heatmap (labels × methods, log colour scale).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from ...files.figures import pyplot, save_png
from ..scoring.metrics import METRICS

#: Axes whose values are named configurations compared one at a time.
LABEL_AXES = ("set", "realism")
#: The error the table and heatmap show.
METRIC = "lamp_position_error_pct"
#: The axis a table is split by (one table, one heatmap panel per value).
SPLIT = "object"


def quantile_failures_worst(values: np.ndarray, q: float) -> float:
    """The ``q``-th percentile (linear interpolation, as ``numpy.percentile``) with NaN counted as +inf.

    Parameters
    ----------
    values : ndarray, shape (n,)
        Errors; NaN marks a failed run, worse than any error.
    q : float
        Percentile in [0, 100] (50: the median).

    Returns
    -------
    float
        ``numpy.percentile(values, q)`` when every value is finite; +inf when the
        percentile falls on or next to a failure; NaN when ``values`` is empty.
    """
    x = np.sort(np.where(np.isnan(values), np.inf, np.asarray(values, dtype=float)))
    if not len(x):
        return float("nan")
    pos = q / 100.0 * (len(x) - 1)
    lo, hi = math.floor(pos), math.ceil(pos)
    if np.isinf(x[hi]):
        return float("inf")
    return float(x[lo] + (x[hi] - x[lo]) * (pos - lo))


def label_table(df: pd.DataFrame, axis: str) -> pd.DataFrame:
    """The median and 90th percentile of :data:`METRIC` per label of ``axis`` and method (and object).

    Parameters
    ----------
    df : DataFrame
        Result rows of a sweep (``status``, ``seed``, ``method``, ``axis``, :data:`METRIC`).
    axis : str
        An axis of named configurations (:data:`LABEL_AXES`).

    Returns
    -------
    DataFrame
        Long table, one row per (object,) label and method, labels and methods in
        the order of the sweep's tasks: ``axis``, ``object`` (empty without an
        object axis), ``label``, ``method``, ``n`` (rows), ``seeds`` (distinct
        seeds), ``failed`` (rows without an error: failed task or NaN, but
        not ``missed``), ``missed`` (successful rows of a several-lamp capture
        that left a true lamp unmatched: ``n_lamps_true`` > 1, ``lamps_missed``
        > 0; on a one-lamp capture a NaN error is no usable estimate: failed), ``median`` and ``p90`` (% of the
        lamp distance; failed and missed rows count as +inf, see
        :func:`quantile_failures_worst`).
    """
    df = df.sort_values("task_index")
    objects = list(dict.fromkeys(df[SPLIT])) if SPLIT in df and SPLIT != axis else [""]
    rows = []
    for obj in objects:
        part = df[df[SPLIT] == obj] if obj != "" else df
        for label in dict.fromkeys(df[axis]):
            for method in dict.fromkeys(df["method"]):
                g = part[(part[axis] == label) & (part["method"] == method)]
                if g.empty:
                    continue
                ok = (g["status"] == "ok").to_numpy()
                err = np.where(ok, g[METRIC].astype(float), np.nan)
                several = (g["n_lamps_true"].fillna(1).to_numpy() > 1) if "n_lamps_true" in g else False
                missed = ok & np.isnan(err) & several & (g["lamps_missed"].fillna(0).to_numpy() > 0 if
                                                         "lamps_missed" in g else False)
                rows.append({"axis": axis, "object": obj, "label": label, "method": method, "n": len(g),
                             "seeds": g["seed"].nunique(), "failed": int(np.isnan(err).sum() - missed.sum()),
                             "missed": int(missed.sum()), "median": quantile_failures_worst(err, 50),
                             "p90": quantile_failures_worst(err, 90)})
    return pd.DataFrame(rows, columns=["axis", "object", "label", "method", "n", "seeds", "failed", "missed",
                                       "median", "p90"])


def _number(x: float, word: str) -> str:
    return word if math.isinf(x) else f"{x:.3g}"


def cell_text(row: pd.Series, *, compact: bool = False) -> str:
    """One cell: ``median``, ``median (p90)`` over several rows, and how many of them failed or missed a lamp.

    ``k/n failed`` (and/or ``k/n missed a lamp``) alone when the median is
    one of them; after a median, ``, k/n failed`` and ``, k/n missed a lamp``;
    ``compact`` (the heatmap) writes ``×k`` and ``−k`` for those. A percentile
    that falls on such a row reads ``failed``, or ``missed`` when no row failed.
    """
    missed = int(row.get("missed", 0))
    counts = [(row["failed"], "failed", "×"), (missed, "missed a lamp", "−")]
    if math.isinf(row["median"]):
        return ", ".join(f"{k}/{row['n']} {word}" for k, word, _ in counts if k)
    word = "missed" if missed and not row["failed"] else "failed"
    text = _number(row["median"], word) + (f" ({_number(row['p90'], word)})" if row["n"] > 1 else "")
    for k, long, short in counts:
        if k:
            text += f" {short}{k}" if compact else f", {k}/{row['n']} {long}"
    return text


def _two_five(v: float, _pos: int) -> str:
    """A colour-bar minor tick's label: ``v`` when it is 2 or 5 times a power of ten, else none."""
    return f"{v:g}" if v > 0 and round(v / 10 ** math.floor(math.log10(v))) in (2, 5) else ""


def markdown_tables(table: pd.DataFrame, axis: str) -> list[tuple[str, pd.DataFrame]]:
    """``[(object, wide table)]``: rows the labels, columns the methods, cells :func:`cell_text`."""
    out = []
    for obj, part in table.groupby("object", sort=False):
        wide = part.assign(cell=part.apply(cell_text, axis=1)).pivot_table(
            index="label", columns="method", values="cell", aggfunc="first", sort=False)
        out.append((str(obj), wide.rename_axis(index=axis, columns=None).reset_index()))
    return out


#: The heatmap's colour scale spans at least this ratio of medians (one decade), centred on theirs in log.
MIN_DECADES = 10.0
#: ... and the figure at least this wide, inches (the title's two lines fit).
MIN_WIDTH_IN = 6.0


def plot_heatmap(table: pd.DataFrame, axis: str, path: Path) -> None:
    """PNG: labels × methods, colour the median :data:`METRIC` (log scale), one panel per object.

    Cells are annotated with :func:`cell_text` (compact); a failed (or missed) median is a grey cell.
    """
    plt = pyplot()
    from matplotlib.colors import LogNorm
    from matplotlib.ticker import FuncFormatter, NullFormatter

    objects = list(dict.fromkeys(table["object"]))
    labels = list(dict.fromkeys(table["label"]))
    methods = list(dict.fromkeys(table["method"]))
    finite = table["median"][np.isfinite(table["median"]) & (table["median"] > 0)]
    lo, hi = (float(finite.min()), float(finite.max())) if len(finite) else (0.1, 10.0)
    if hi < lo * MIN_DECADES:  # medians within a few % of each other must not look a world apart
        mid = np.sqrt(lo * hi)
        lo, hi = mid / np.sqrt(MIN_DECADES), mid * np.sqrt(MIN_DECADES)
    norm = LogNorm(vmin=lo, vmax=hi)
    cmap = plt.get_cmap("YlOrRd").with_extremes(bad="0.6")
    fig, axs = plt.subplots(
        1, len(objects), squeeze=False, constrained_layout=True,
        figsize=(max(2.6 + 1.25 * len(methods) * len(objects), MIN_WIDTH_IN), 2.8 + 0.24 * len(labels)))
    for ax, obj in zip(axs[0], objects):
        part = table[table["object"] == obj].set_index(["label", "method"])
        grid = np.full((len(labels), len(methods)), np.nan)
        for (i, label), (j, method) in ((a, b) for a in enumerate(labels) for b in enumerate(methods)):
            if (label, method) not in part.index:
                continue
            row = part.loc[(label, method)]
            med = float(row["median"])
            grid[i, j] = max(med, lo) if np.isfinite(med) else np.nan
            dark = np.isfinite(med) and norm(max(med, lo)) > 0.6
            ax.text(j, i, cell_text(row, compact=True), ha="center", va="center", fontsize=6.5,
                    color="white" if dark else "black")
        image = ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, norm=norm, aspect="auto")
        ax.xaxis.tick_top()
        ax.set_xticks(range(len(methods)), methods, rotation=30, ha="left", fontsize=8)
        ax.set_yticks(range(len(labels)), [str(x) for x in labels], fontsize=7)
        ax.set_xlabel(str(obj) if obj != "" else axis, fontsize=10)
        ax.tick_params(length=0)
    bar = fig.colorbar(image, ax=axs[0].tolist(), location="bottom", shrink=0.5, aspect=40, pad=0.01,
                       label=f"median {METRIC} [{METRICS[METRIC]}]")
    bar.ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    # minor ticks labelled at 2 and 5 × a power of ten only (every one of them crowds within a decade)
    bar.ax.xaxis.set_minor_formatter(FuncFormatter(_two_five) if hi / lo < 30 else NullFormatter())
    fig.suptitle(f"Which imperfection breaks which method ({axis}): median (90th percentile) over runs\n"
                 "×k: k runs failed; −k: k missed a lamp; grey: half or more did either", fontsize=9)
    save_png(fig, path, dpi=110)
