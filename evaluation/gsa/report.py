"""The report of one design of a global sensitivity study: ``DIR/<design>/gsa/``.

Written by ``nearlight gsa`` once the design's sweep is complete (or, with
whatever rows exist, when it is not: the report then says how many blocks
were analysed). Files:

- ``indices.csv``: per method × metric × input, SALib's indices with the
  half-widths of their bootstrap intervals (``sobol``: ``S1``, ``S1_conf``,
  ``ST``, ``ST_conf``; ``morris``: ``mu``, ``mu_star``, ``mu_star_conf``,
  ``sigma``), and ``blocks`` (analysed) of ``n_blocks``;
- ``outputs.csv``: per sample and method, the inputs' values and every
  analysed metric (the mean over the sample's seeds), in sample order;
- ``gsa.md``: the headline (which input matters most, per method and
  metric), one table per metric, the plots linked;
- ``indices_<metric>.png``: a bar chart per metric, inputs × methods
  (``ST`` with ``S1`` inside it, or ``mu_star``, with their intervals);
- ``scatter_<method>.png``: the first metric against each input, one panel
  per input (a trend or a spread that the indices summarise).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ...files.atomic import write_text
from ...files.figures import pyplot, save_png
from ...files.outputs import check_files_in, make_folder
from .study import DesignRun, Input, Study, analyse, outputs
from ..engine.provenance import record
from ..views.report import frame_table, renderers_line
from ..engine.store import read_results

#: The report's sub-folder of a design's results folder.
FOLDER = "gsa"


def index_table(study: Study, run: DesignRun, results: pd.DataFrame) -> pd.DataFrame:
    """SALib's indices of every method × metric of ``run`` (long form, see the module docstring)."""
    rows = []
    n_blocks = run.design.n
    for method in run.sweep.methods:
        for metric in study.metrics:
            Y = outputs(run, results, metric, method.label)
            indices, blocks = analyse(study.inputs, run.design, run.samples, Y)
            rows += [{"method": method.label, "metric": metric, **r, "blocks": blocks, "n_blocks": n_blocks}
                     for r in indices]  # fmt: skip
    return pd.DataFrame(rows)


def output_table(study: Study, run: DesignRun, results: pd.DataFrame) -> pd.DataFrame:
    """Per sample and method: the inputs' values (labels for categorical inputs) and every metric."""
    values = {i.name: [i.label(x) for x in run.samples[:, j]] for j, i in enumerate(study.inputs)}
    frames = []
    for method in run.sweep.methods:
        df = pd.DataFrame({"sample": np.arange(len(run.samples)), "method": method.label, **values})
        for metric in study.metrics:
            df[metric] = outputs(run, results, metric, method.label)
        frames.append(df)
    return pd.concat(frames, ignore_index=True)


def _key(design: str) -> str:
    return "ST" if design == "sobol" else "mu_star"


def headline(indices: pd.DataFrame, design: str) -> pd.DataFrame:
    """Per method and metric, the inputs ranked by ``ST`` (Sobol') or ``mu_star`` (Morris), largest first."""
    key = _key(design)
    rows = []
    for (method, metric), g in indices.groupby(["method", "metric"], sort=False):
        g = g.dropna(subset=[key]).sort_values(key, ascending=False)
        ranked = ", ".join(f"{r.input} {getattr(r, key):.2g}" for r in g.itertuples())
        rows.append({"method": method, "metric": metric, f"inputs by {key}": ranked or "n/a (no block analysed)"})
    return pd.DataFrame(rows)


def _cells(indices: pd.DataFrame, metric: str, design: str) -> pd.DataFrame:
    """One metric's table: a row per method, a column per input, ``ST ± conf (S1 ± conf)`` or ``μ* ± conf (σ)``."""
    g = indices[indices["metric"] == metric]

    def cell(r: pd.Series) -> str:
        if pd.isna(r.ST if design == "sobol" else r.mu_star):
            return "n/a"
        if design == "sobol":
            return f"{r.ST:.2f} ± {r.ST_conf:.2f} ({r.S1:.2f} ± {r.S1_conf:.2f})"
        return f"{r.mu_star:.3g} ± {r.mu_star_conf:.2g} ({r.sigma:.3g})"

    wide = g.assign(cell=g.apply(cell, axis=1)).pivot_table(index="method", columns="input", values="cell",
                                                             aggfunc="first", sort=False)  # fmt: skip
    blocks = g.groupby("method", sort=False)["blocks"].first()
    wide["blocks"] = [f"{blocks[m]}/{g['n_blocks'].iloc[0]}" for m in wide.index]
    return wide.reset_index()


def plot_indices(indices: pd.DataFrame, metric: str, design: str, path: Path) -> Path:
    """Grouped bars for one metric: an input per group, a method per bar, with the bootstrap intervals."""
    plt = pyplot()

    g = indices[indices["metric"] == metric]
    inputs = list(dict.fromkeys(g["input"]))
    methods = list(dict.fromkeys(g["method"]))
    width = 0.8 / len(methods)
    x = np.arange(len(inputs))
    fig, ax = plt.subplots(figsize=(max(5.0, 1.3 * len(inputs) + 2), 3.6), constrained_layout=True)
    for j, method in enumerate(methods):
        m = g[g["method"] == method].set_index("input").reindex(inputs)
        pos = x - 0.4 + width * (j + 0.5)
        if design == "sobol":
            bars = ax.bar(pos, m["ST"], width, yerr=m["ST_conf"], capsize=2, label=f"{method} ST", alpha=0.55)
            ax.bar(pos, m["S1"], width * 0.5, yerr=m["S1_conf"], capsize=1, color=bars.patches[0].get_facecolor(),
                   alpha=1.0, label=f"{method} S1")  # fmt: skip
        else:
            ax.bar(pos, m["mu_star"], width, yerr=m["mu_star_conf"], capsize=2, label=method)
    ax.set_xticks(x, inputs, rotation=20, ha="right")
    ax.set_ylabel("Sobol' index (wide ST, narrow S1)" if design == "sobol" else "Morris mu* (per input range)")
    ax.set_title(f"{metric}: what the error depends on")
    ax.legend(fontsize=7, ncol=2)
    return save_png(fig, path, dpi=110)


def plot_scatter(table: pd.DataFrame, inputs: list[Input], metric: str, method: str, path: Path) -> Path:
    """``metric`` against each input for one method (one panel per input; categorical inputs by label,
    log-uniform ones on a log axis)."""
    plt = pyplot()
    import matplotlib.ticker

    t = table[table["method"] == method]
    fig, axs = plt.subplots(1, len(inputs), figsize=(2.8 * len(inputs), 2.8), constrained_layout=True, sharey=True)
    for ax, inp in zip(np.atleast_1d(axs), inputs):
        name = inp.name
        xs = t[name]
        if not pd.api.types.is_numeric_dtype(xs):
            codes = {v: k for k, v in enumerate(dict.fromkeys(xs))}
            ax.set_xticks(list(codes.values()), list(codes), rotation=20)
            xs = xs.map(codes)
        ax.scatter(xs, t[metric], s=6, alpha=0.6)
        if inp.dist == "loguniform":
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel(name)
    np.atleast_1d(axs)[0].set_ylabel(metric)
    fig.suptitle(f"{method}: {metric} against each input")
    return save_png(fig, path, dpi=100)


def check_report_out(study: Study, run: DesignRun, results_dir: str | Path) -> Path:
    """Raise :class:`UserError` unless the report of ``run`` may be written into ``results_dir/gsa/``
    (every file there that it would replace is one nearlight wrote); nothing is written. ``nearlight gsa``
    calls it for every design before any runs."""
    folder = Path(results_dir) / FOLDER
    pngs = {f"indices_{m}.png": "png" for m in study.metrics}
    pngs |= {f"scatter_{_safe(m.label)}.png": "png" for m in run.sweep.methods}
    check_files_in(folder, {"indices.csv": "report-csv", "outputs.csv": "report-csv", "gsa.md": "report-md", **pngs})
    return folder


def write_gsa_report(study: Study, run: DesignRun, results_dir: str | Path, *, command: str) -> Path:
    """Write the report of one design into ``results_dir/gsa/`` and record its provenance.

    Parameters
    ----------
    study : Study
    run : DesignRun
        The design whose sweep ran into ``results_dir``.
    results_dir : path-like
        The design's results folder.
    command : str
        The command that regenerates the report (recorded in ``provenance.json``).

    Returns
    -------
    Path
        The report folder.
    """
    results_dir = Path(results_dir)
    folder = check_report_out(study, run, results_dir)
    results, complete = read_results(results_dir)
    metrics = study.metrics
    methods = [m.label for m in run.sweep.methods]
    make_folder(folder, what="report folder")
    design = run.design.method
    indices = index_table(study, run, results)
    table = output_table(study, run, results)
    write_text(folder / "indices.csv", indices.to_csv(index=False), what="the report")
    write_text(folder / "outputs.csv", table.to_csv(index=False), what="the report")
    what = ("Sobol' indices (Saltelli sample, SALib): total ST ± half-width of the bootstrap interval, first-order "
            "S1 ± its half-width in brackets" if design == "sobol" else
            "Morris screening (SALib): mu* (mean |elementary effect|: the metric's change over a step of the input "
            "divided by the step, per input range) ± half-width of the bootstrap interval, sigma in brackets "
            "(interactions and curvature)")
    md = [f"# Sweep report: global sensitivity of {study.name}, design {run.design.name}", "",
          f"{what}, at {int(100 * run.design.conf_level)} % confidence; `blocks`: "
          + ("Saltelli base samples" if design == "sobol" else "trajectories")
          + " analysed (a block with a failed or non-finite output is dropped whole).", "",
          f"Design: `{design}`, n = {run.design.n}, seed {run.design.seed}, {len(run.samples)} samples, "
          f"{len(run.sweep.tasks)} tasks" + ("" if complete else " (INCOMPLETE: rows missing)") + f"; "
          f"{renderers_line(results)}.", "",
          "Inputs: " + "; ".join(f"`{i.name}` {_dist(i)}" for i in study.inputs) + ".", "",
          "## Which input matters most", "", frame_table(headline(indices, design)), ""]  # fmt: skip
    for metric in metrics:
        png = f"indices_{metric}.png"
        plot_indices(indices, metric, design, folder / png)
        md += [f"## {metric}", "", frame_table(_cells(indices, metric, design)), "", f"![indices of {metric}]({png})", ""]
    md += ["## Scatter plots", "", f"{metrics[0]} against each input (one point per sample).", ""]
    for method in methods:
        png = f"scatter_{_safe(method)}.png"
        plot_scatter(table, study.inputs, metrics[0], method, folder / png)
        md += [f"![{method}]({png})", ""]
    write_text(folder / "gsa.md", "\n".join(md), what="the report")
    record(results_dir, command=command, entry_modules=[__name__], inputs=[study.source], part="gsa")
    return folder


def _dist(i: Input) -> str:
    if i.labels is not None:
        return "one of " + ", ".join(str(lab) for lab, _ in i.labels)
    a, b = i.bounds
    return f"normal(mean {a:g}, sd {b:g})" if i.dist == "normal" else f"{i.dist}({a:g}, {b:g})"


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)

