"""How much of a method's error is luck: its spread over seeds without camera noise, beside what the axes do.

A configuration without camera or range noise whose rows still run several
seeds (``noisy``) draws something per shot: where the pixel grid falls on the
highlight (``camera.jitter_px``), the analyzer's angle jitter, the lamp's
flicker. The spread of one configuration's errors over those seeds is luck; the
change of a method's median error from one value of an axis to another
(lamp distance, roughness, ...) is what the axis does. A method whose luck is
as large as its axes' effects is set by sampling luck, not by the physics the
sweep varies (the paper's first stage, which starts at the brightest pixel, is one).

Used by :func:`nearlight.evaluation.views.report.write_report`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ...files.figures import pyplot, save_png

#: The report's figure of this section.
LUCK_PNG = "luck_vs_axes.png"
METRIC = "lamp_position_error_pct"
#: Axes applied after rendering that make a row noisy by themselves (camera, range noise): rows with them are not luck.
_NOISE_AXES = ("noise", "range_noise")


def luck_rows(df: pd.DataFrame, axes: list[str]) -> pd.DataFrame:
    """The rows whose seeds differ only by per-shot draws: no camera or range noise, ``noisy``, status ok."""
    keep = (df["status"] == "ok") & df["noisy"].astype(bool)
    if "noise" in axes:
        keep &= df["noise"].astype(str) == "none"
    if "range_noise" in axes:
        keep &= pd.to_numeric(df["range_noise"], errors="coerce") == 0
    return df[keep]


def luck_table(df: pd.DataFrame, axes: list[str]) -> pd.DataFrame:
    """Per method: the spread over seeds within a configuration against the spread of medians along each axis.

    Parameters
    ----------
    df : DataFrame
        Result rows (``nearlight.evaluation.engine.store.read_results``).
    axes : list of str
        The sweep's axes (columns of ``df``).

    Returns
    -------
    DataFrame
        Columns ``method``, ``configurations``, ``seeds``, ``luck median``, ``luck p90`` (the max − min of
        :data:`METRIC` over one configuration's seeds, its median and 90th percentile over configurations,
        percentage points), and per varied axis other than the noise axes ``<axis> effect``: the median over
        the other axes' configurations of the max − min over the axis's values of the median over seeds
        (percentage points). Empty when no configuration has several noise-free seeds.
    """
    rows = luck_rows(df, axes)
    config = [a for a in axes if a not in _NOISE_AXES]
    if rows.empty or not config:
        return pd.DataFrame()
    out = []
    for method, g in rows.groupby("method", sort=False):
        per = g.groupby(config, sort=False, dropna=False)[METRIC]
        spread = (per.max() - per.min())[per.size() >= 2]
        if spread.empty:
            continue
        rec = {"method": method, "configurations": int(len(spread)), "seeds": int(per.size().max()),
               "luck median": float(spread.median()), "luck p90": float(np.percentile(spread, 90))}  # fmt: skip
        med = per.median()
        for a in config:
            if g[a].nunique() < 2:
                continue
            others = [b for b in config if b != a]
            rng = med.groupby(others, dropna=False).agg(lambda s: s.max() - s.min()) if others else \
                pd.Series([med.max() - med.min()])  # fmt: skip
            rec[f"{a} effect"] = float(rng.median())
        out.append(rec)
    return pd.DataFrame(out)


def plot_luck(df: pd.DataFrame, axes: list[str], path: Path, *, x_axis: str | None = None) -> None:
    """PNG: per method, every noise-free seed's error (dots) against ``x_axis`` (default the first numeric
    varied axis), one configuration's seeds joined by a vertical bar (min to max), configurations of the
    other axes side by side; log scale."""
    plt = pyplot()

    rows = luck_rows(df, axes)
    config = [a for a in axes if a not in _NOISE_AXES and rows[a].nunique() > 1]
    if x_axis is None:
        numeric = [a for a in config if pd.api.types.is_numeric_dtype(rows[a])]
        x_axis = numeric[0] if numeric else config[0]
    others = [a for a in config if a != x_axis]
    xs = list(dict.fromkeys(sorted(rows[x_axis].unique(), key=lambda v: (isinstance(v, str), v))))
    groups = [tuple(k) for k in rows[others].drop_duplicates().itertuples(index=False)] if others else [()]
    methods = list(dict.fromkeys(rows["method"]))
    ncol = min(3, len(methods))
    nrow = -(-len(methods) // ncol)
    fig, axs = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.4 * nrow), squeeze=False, sharey=True,
                            constrained_layout=True)  # fmt: skip
    cmap = plt.get_cmap("tab10" if len(groups) <= 10 else "tab20")
    width = 0.8 / max(len(groups), 1)
    for ax, method in zip(axs.flat, methods):
        g = rows[rows["method"] == method]
        for j, key in enumerate(groups):
            sel = g
            for a, v in zip(others, key):
                sel = sel[sel[a] == v]
            for i, xv in enumerate(xs):
                y = np.clip(sel.loc[sel[x_axis] == xv, METRIC].to_numpy(float), 1e-3, None)
                if not len(y):
                    continue
                x = i - 0.4 + width * (j + 0.5)
                ax.plot([x, x], [y.min(), y.max()], color=cmap(j % cmap.N), lw=1.2, alpha=0.7)
                ax.plot(np.full(len(y), x), y, "o", ms=2.5, color=cmap(j % cmap.N),
                        label=", ".join(map(str, key)) if i == 0 else None)
        ax.set_yscale("log")
        ax.set_xticks(range(len(xs)), [str(v) for v in xs])
        ax.set_xlabel(x_axis)
        ax.set_title(str(method), fontsize=10)
        ax.grid(alpha=0.3, which="both")
    for ax in axs[:, 0]:
        ax.set_ylabel(f"{METRIC} (floor 1e-3)")
    for ax in list(axs.flat)[len(methods):]:
        ax.set_visible(False)
    if others:
        axs.flat[0].legend(fontsize=6, title=", ".join(others), title_fontsize=6, ncol=2)
    fig.suptitle("luck: each dot one seed (per-shot draws, no camera noise); bar = one configuration's spread")
    save_png(fig, path, dpi=110)
