"""The report of one design of a global sensitivity study: ``DIR/<design>/gsa/``.

Written by ``nearlight gsa`` once the design's sweep is complete (or, with
whatever rows exist, when it is not: the report then says how many blocks
were analysed). Files:

- ``indices.csv``: per method × metric × input, the indices with their
  bootstrap intervals (``sobol``: :data:`~nearlight.evaluation.gsa.study.SOBOL_COLUMNS`,
  percentile intervals and the chance floor, :mod:`nearlight.evaluation.gsa.sobol`;
  ``morris``: ``mu``, ``mu_star``, ``mu_star_conf``, ``sigma`` and ``steps``,
  step by step, :mod:`nearlight.evaluation.gsa.morris`), and ``blocks``
  (Sobol': analysed; Morris: trajectories with every run answered) of ``n_blocks``;
- ``convergence.csv`` (Sobol', N ≥ 8): the same at N/4, N/2 and N (column
  ``seeds``: the replicates analysed) and, for a design of several replicates,
  each replicate alone; ``convergence_<method>.png``: each input's ST against
  N; the report says whether the inputs whose intervals do not overlap keep
  their order in each of these analyses;
- ``levels.csv`` (Sobol', with a categorical input): each other input's total
  index within each of its levels (:func:`sobol_by_level`), so the report says
  where an input's influence depends on the object's shape or the lobe family;
- ``outputs.csv``: per sample and method, the inputs' values and every
  analysed metric (the mean over the sample's seeds), in sample order;
- ``gsa.md``: the headline (which input matters most, per method and
  metric; Sobol': the inputs above the floor ranked, the others named as
  not distinguishable from zero), one table per metric, a sentence per
  influential input on where in its range it matters, the plots linked;
- ``indices_<metric>.png``: a bar chart per metric, inputs × methods
  (``ST`` with ``S1`` inside it, or ``mu_star``, with their intervals);
- ``scatter_<method>.png``: the first metric against each input, one panel
  per input (a trend or a spread that the indices summarise).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from ...files.atomic import write_text
from ...files.figures import pyplot, save_png
from ...files.outputs import check_files_in, make_folder
from .morris import step_effects
from .sobol import distinguishable, level_total_indices, split
from .study import DesignRun, Input, Study, analyse, outputs
from ..engine.provenance import record
from ..views.report import frame_table, renderers_line
from ..engine.store import read_results

#: The report's sub-folder of a design's results folder.
FOLDER = "gsa"


def index_table(study: Study, run: DesignRun, table: pd.DataFrame) -> pd.DataFrame:
    """The indices of every method × metric of ``run`` (long form, see the module docstring), from the outputs
    of :func:`output_table`."""
    rows = []
    n_blocks = run.design.blocks
    for method in run.sweep.methods:
        for metric in study.metrics:
            Y = sample_outputs(table, method.label, metric)
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


def sample_outputs(table: pd.DataFrame, method: str, metric: str) -> np.ndarray:
    """``metric`` of every sample of ``method``, in sample order, from :func:`output_table` (where each is read
    from the rows once)."""
    return table.loc[table["method"] == method, metric].to_numpy(dtype=float)


def _key(design: str) -> str:
    return "ST" if design == "sobol" else "mu_star"


def headline(indices: pd.DataFrame, design: str) -> pd.DataFrame:
    """Per method and metric, the inputs ranked by ``ST`` (Sobol') or ``mu_star`` (Morris), largest first.

    Sobol': only the inputs whose ``ST`` interval stands above the chance floor
    (:func:`~nearlight.evaluation.gsa.sobol.distinguishable`) are ranked, each with its interval; the rest are
    named as not distinguishable from zero, beside the floor."""
    key = _key(design)
    rows = []
    for (method, metric), g in indices.groupby(["method", "metric"], sort=False):
        g = g.dropna(subset=[key]).sort_values(key, ascending=False)
        if design != "sobol":
            ranked = ", ".join(f"{r.input} {getattr(r, key):.2g}" for r in g.itertuples())
            rows.append({"method": method, "metric": metric, f"inputs by {key}": ranked or "n/a (no block analysed)"})
            continue
        above = _above_floor(g)
        below = g.drop(above.index)
        ranked = ", ".join(f"{r.input} {r.ST:.2g} [{r.ST_lo:.2g}, {r.ST_hi:.2g}]" for r in above.itertuples())
        rows.append({"method": method, "metric": metric,
                     "inputs by ST [interval], above the floor": ranked or ("none" if len(g) else "n/a (no block analysed)"),
                     "not distinguishable from zero": ", ".join(below["input"]) or "none",
                     "floor (ST)": f"{g['ST_floor'].iloc[0]:.2g}" if len(g) else "n/a"})  # fmt: skip
    return pd.DataFrame(rows)


def _cells(indices: pd.DataFrame, metric: str, design: str) -> pd.DataFrame:
    """One metric's table: a row per input, a column per method, ``ST [lo, hi] (S1 [lo, hi])`` with ``≈ 0`` where the
    total index does not stand above the floor (Sobol'), or ``μ* ± conf (σ)`` (Morris)."""
    g = indices[indices["metric"] == metric]

    def cell(r: pd.Series) -> str:
        if pd.isna(r.ST if design == "sobol" else r.mu_star):
            return "n/a"
        if design == "sobol":
            mark = "" if distinguishable(r.ST_lo, r.ST_floor) else " ≈ 0"
            return f"{r.ST:.2f} [{r.ST_lo:.2f}, {r.ST_hi:.2f}]{mark} ({r.S1:.2f} [{r.S1_lo:.2f}, {r.S1_hi:.2f}])"
        return f"{r.mu_star:.3g} ± {r.mu_star_conf:.2g} ({r.sigma:.3g}; {int(r.steps)} steps)"

    wide = g.assign(cell=g.apply(cell, axis=1)).pivot_table(index="input", columns="method", values="cell",
                                                             aggfunc="first", sort=False)  # fmt: skip
    blocks = g.groupby("method", sort=False)["blocks"].first()
    extra = {"input": "blocks" if design == "sobol" else "whole trajectories",
             **{m: f"{blocks[m]}/{g['n_blocks'].iloc[0]}" for m in wide.columns}}  # fmt: skip
    if design == "sobol":
        floor = g.groupby("method", sort=False)["ST_floor"].first()
        extra = [{"input": "floor (ST)", **{m: f"{floor[m]:.2f}" for m in wide.columns}}, extra]
    return pd.concat([wide.reset_index(), pd.DataFrame(extra if isinstance(extra, list) else [extra])],
                     ignore_index=True)  # fmt: skip


#: Fractions of a Sobol' design's base samples its convergence table analyses (N/4, N/2, N).
CONVERGENCE = (4, 2, 1)


def convergence_table(study: Study, run: DesignRun, table: pd.DataFrame, indices: pd.DataFrame) -> pd.DataFrame:
    """Every Sobol' index of every method × metric analysed on the first N/4, N/2 and N base samples and, with
    several replicates, on each replicate alone, with its interval and floor.

    The first base samples of a scrambled Sobol' sequence (2^m of them) are a balanced design of their own, and
    the replicates run one after the other, so N/2 of two replicates is the first. Columns ``n``, ``seeds`` (the
    replicates' seeds, ``+``-joined), then :func:`index_table`'s (``indices``, the rows at N). Empty for Morris
    or fewer than 8 base samples."""
    design = run.design
    if design.method != "sobol" or design.blocks < 8:
        return pd.DataFrame()
    size = design.block(len(study.inputs))
    seeds = [rep.seed for rep in run.replicates]
    subsets = [(design.blocks // part, slice(0, design.blocks // part)) for part in CONVERGENCE[:-1]]
    if len(seeds) > 1:
        subsets += [(design.n, slice(j * design.n, (j + 1) * design.n)) for j in range(len(seeds))]
    frames = [indices.drop(columns="n_blocks").assign(n=design.blocks, seeds="+".join(map(str, seeds)))]
    for n, blocks in subsets:
        used = seeds[blocks.start // design.n: -(-blocks.stop // design.n)]
        rows = []
        rows_of = slice(blocks.start * size, blocks.stop * size)
        for method in run.sweep.methods:
            for metric in study.metrics:
                Y = sample_outputs(table, method.label, metric)[rows_of]
                got, kept = analyse(study.inputs, design, run.samples[rows_of], Y)
                rows += [{"method": method.label, "metric": metric, **r, "blocks": kept} for r in got]
        frames.append(pd.DataFrame(rows).assign(n=n, seeds="+".join(map(str, used))))
    conv = pd.concat(frames, ignore_index=True)
    conv = conv.drop_duplicates(subset=["n", "seeds", "method", "metric", "input"])  # one replicate's N/2 is a seed's
    conv = conv.sort_values("n", kind="stable")
    return conv[["n", "seeds", *indices.columns.drop("n_blocks")]].reset_index(drop=True)


def order_changes(conv: pd.DataFrame, method: str, metric: str) -> tuple[list[str], dict[str, list[str]]]:
    """Where the order of the total indices changes between the whole design and a part of it.

    The pairs compared are the inputs above the floor (:func:`_above_floor`) whose ``ST`` intervals at N do not
    overlap; an order is kept in a part (a ``(n, seeds)`` row group of :func:`convergence_table` other than the
    whole) when each such pair has the same order there.

    Returns
    -------
    pairs : list of str
        The pairs compared, ``"a > b"`` (the order at N).
    changes : dict
        ``"<n> (seeds <s>)"`` -> the pairs that the part turns round; an empty list where the order is kept.
    """
    g = conv[(conv["method"] == method) & (conv["metric"] == metric)]
    n_all = g["n"].max()
    whole = g[(g["n"] == n_all)]
    whole = whole[whole["seeds"] == whole["seeds"].iloc[0]] if len(whole) else whole
    above = _above_floor(whole.dropna(subset=["ST"])).set_index("input")
    pairs = [(a, b) for a in above.index for b in above.index
             if above.at[a, "ST"] > above.at[b, "ST"] and above.at[a, "ST_lo"] > above.at[b, "ST_hi"]]  # fmt: skip
    out = {}
    for (n, seeds), part in g.groupby(["n", "seeds"], sort=False):
        if n == n_all and seeds == whole["seeds"].iloc[0]:
            continue
        st = part.set_index("input")["ST"]
        out[f"{n} (seeds {seeds})"] = [f"{a} > {b}" for a, b in pairs if not st[a] > st[b]]
    return [f"{a} > {b}" for a, b in pairs], out


#: Markers of the later replicates drawn alone (hollow) in the convergence plot.
HOLLOW = ("o", "s", "^", "D")


def plot_convergence(conv: pd.DataFrame, metric: str, method: str, path: Path) -> Path:
    """Each input's ``ST`` with its interval at N/4, N/2 and N (one line per input), the floor shaded."""
    plt = pyplot()

    g = conv[(conv["metric"] == metric) & (conv["method"] == method)]
    first = g["seeds"].str.split("+").str[0] == g.loc[g["n"].idxmax(), "seeds"].split("+")[0]
    alone = g[~first]  # a later replicate alone (the first base samples start with the first): drawn hollow
    g = g[first]
    later = list(dict.fromkeys(alone["seeds"]))
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    ns = sorted(g["n"].unique())
    floor = g.groupby("n")["ST_floor"].first().reindex(ns)
    ax.fill_between(ns, 0, floor.to_numpy(), color="0.85", label="floor (chance)")
    inputs = list(dict.fromkeys(g["input"]))
    tab20 = plt.get_cmap("tab20").colors  # one colour per input (the default cycle repeats after 10): tab20's
    colours = tab20[0::2] + tab20[1::2]  # strong shades first, then their light pairs
    for j, name in enumerate(inputs):
        m = g[g["input"] == name].set_index("n").reindex(ns)
        shift = 2 ** (0.3 * (j - (len(inputs) - 1) / 2) / max(len(inputs) - 1, 1))  # spread one N's markers
        ax.errorbar(np.asarray(ns) * shift, m["ST"], yerr=[m["ST"] - m["ST_lo"], m["ST_hi"] - m["ST"]], marker="o",
                    ms=3, capsize=2, lw=1, label=name, color=colours[j % 20])  # fmt: skip
        for r in alone[alone["input"] == name].itertuples():  # another seed's replicate, right of the first
            q = later.index(r.seeds)
            ax.errorbar([r.n * 2 ** (0.35 * (q + 1)) * shift], [r.ST], yerr=[[r.ST - r.ST_lo], [r.ST_hi - r.ST]],
                        marker=HOLLOW[q % len(HOLLOW)], ms=3, mfc="white", capsize=2, lw=0, elinewidth=1,
                        color=colours[j % 20])  # fmt: skip
    for q, seeds in enumerate(later):
        ax.plot([], [], HOLLOW[q % len(HOLLOW)], mfc="white", color="0.3", ms=4, label=f"seed {seeds} alone")
    ax.set_xscale("log", base=2)
    ax.set_xticks(ns, [str(n) for n in ns])
    ax.set_xlabel("base samples N")
    ax.set_ylabel("total index ST")
    ax.set_title(f"{method}, {metric}: ST at N/4, N/2, N", fontsize=9)
    ax.legend(fontsize=6, ncol=2, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return save_png(fig, path, dpi=110)


def effects_by_level(inputs: list[Input], design_levels: int, X: np.ndarray, Y: np.ndarray) -> pd.DataFrame:
    """Morris ``mu*`` of each input over the trajectory steps taken at each level of each categorical input.

    A Morris step moves one input with every other held, so its elementary effect
    (:func:`~nearlight.evaluation.gsa.morris.step_effects`, the design's ``mu_star`` units) belongs to the level
    the categorical inputs had there. One row per input, a column ``"<categorical>=<label>"`` per level; NaN
    where no usable step of that input was taken at that level (and for the categorical input at its own).
    """
    effects, base = step_effects(X, Y, design_levels)
    columns = {}
    for c, cat in enumerate(inputs):
        if cat.labels is None:
            continue
        level = np.minimum(np.floor(X[base, c]).astype(int), len(cat.labels) - 1)
        for lv, (label, _) in enumerate(cat.labels):
            col = []
            for i in range(len(inputs)):
                e = effects[:, i][(level[:, i] == lv) & np.isfinite(effects[:, i])]
                col.append(float(np.abs(e).mean()) if i != c and e.size else math.nan)
            columns[f"{cat.name}={label}"] = col
    return pd.DataFrame({"input": [i.name for i in inputs], **columns}) if columns else pd.DataFrame()


def sobol_by_level(study: Study, run: DesignRun, table: pd.DataFrame) -> pd.DataFrame:
    """Total indices of every other input within each level of each categorical input, per method × metric.

    :func:`~nearlight.evaluation.gsa.sobol.level_total_indices` over the analysed blocks (every output finite);
    long form: ``method``, ``metric``, ``input``, ``level`` (``"<categorical>=<label>"``), ``ST``, ``ST_lo``,
    ``ST_hi``, ``ST_floor``, ``blocks`` (blocks whose ``A`` has the level). Empty for Morris or without a
    categorical input.
    """
    design, inputs = run.design, study.inputs
    cats = [(c, inp) for c, inp in enumerate(inputs) if inp.labels is not None]
    if design.method != "sobol" or not cats:
        return pd.DataFrame()
    k = len(inputs)
    size = design.block(k)
    rows = []
    for method in run.sweep.methods:
        for metric in study.metrics:
            Y = sample_outputs(table, method.label, metric)
            keep = np.isfinite(Y.reshape(-1, size)).all(axis=1)
            if keep.sum() < 2:
                continue
            X = run.samples.reshape(-1, size, k)[keep]
            Yk = Y.reshape(-1, size)[keep].ravel()
            A, B, _ = split(Yk, k)
            if np.ptp(np.r_[A, B]) == 0:  # no variance in A and B: no index (as sobol_indices)
                continue
            for c, cat in cats:
                level_a = np.minimum(np.floor(X[:, 0, c]).astype(int), len(cat.labels) - 1)
                level_b = np.minimum(np.floor(X[:, -1, c]).astype(int), len(cat.labels) - 1)
                for lv, (label, _) in enumerate(cat.labels):
                    got = level_total_indices(Yk, k, level_a == lv, level_b == lv, resamples=design.resamples,
                                              conf_level=design.conf_level, seed=design.seed)  # fmt: skip
                    rows += [{"method": method.label, "metric": metric, "input": inp.name,
                              "level": f"{cat.name}={label}", "ST": float(got["ST"][j]),
                              "ST_lo": float(got["ST_lo"][j]), "ST_hi": float(got["ST_hi"][j]),
                              "ST_floor": float(got["ST_floor"]), "blocks": got["blocks"]}
                             for j, inp in enumerate(inputs) if j != c]  # fmt: skip
    return pd.DataFrame(rows)


def _level_cells(levels: pd.DataFrame, method: str, metric: str) -> pd.DataFrame:
    """One method's per-level table: a row per input, a column per level, ``ST [lo, hi]`` (``≈ 0`` within the
    level's floor), and the floor and the blocks as the last rows."""
    g = levels[(levels["method"] == method) & (levels["metric"] == metric)]

    def cell(r: pd.Series) -> str:
        if pd.isna(r.ST):
            return "n/a"
        return f"{r.ST:.2f} [{r.ST_lo:.2f}, {r.ST_hi:.2f}]" + ("" if distinguishable(r.ST_lo, r.ST_floor) else " ≈ 0")

    wide = g.assign(cell=g.apply(cell, axis=1)).pivot_table(index="input", columns="level", values="cell",
                                                             aggfunc="first", sort=False).fillna("")  # fmt: skip
    per = g.groupby("level", sort=False)[["ST_floor", "blocks"]].first()
    extra = [{"input": "floor (ST)", **{lv: f"{per.at[lv, 'ST_floor']:.2f}" for lv in wide.columns}},
             {"input": "blocks", **{lv: str(int(per.at[lv, "blocks"])) for lv in wide.columns}}]  # fmt: skip
    return pd.concat([wide.reset_index(), pd.DataFrame(extra)], ignore_index=True)


def where_it_matters(table: pd.DataFrame, inp: Input, metric: str, method: str) -> str:
    """One sentence from the scatter: the median of ``metric`` over each quarter of the input's sampled range
    (each label of a categorical input), and between which quarters it moves most."""
    t = table[table["method"] == method][[inp.name, metric]].dropna()
    if t.empty:
        return f"`{inp.name}`: no finite output."
    if inp.labels is not None:
        med = t.groupby(inp.name, sort=False)[metric].median()
        return f"`{inp.name}`: median {metric} " + ", ".join(f"{v:.3g} for {k}" for k, v in med.items()) + "."
    x = t[inp.name].astype(float)
    edges = np.quantile(x, [0, 0.25, 0.5, 0.75, 1])
    bins = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, 3)
    med = t[metric].groupby(bins).median().reindex(range(4))
    steps = np.abs(np.diff(med.to_numpy()))
    j = int(np.nanargmax(steps)) if np.isfinite(steps).any() else 0
    quarters = ", ".join(f"{v:.3g} ({edges[i]:.3g}-{edges[i + 1]:.3g})" for i, v in enumerate(med))
    return (f"`{inp.name}`: median {metric} by quarter of its range {quarters}; it moves most across "
            f"{edges[j + 1]:.3g} ({med.iloc[j]:.3g} -> {med.iloc[j + 1]:.3g}).")


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


#: Panels per row of a scatter figure (a study of 14 inputs in one row is 39 inches wide).
SCATTER_COLUMNS = 5


def plot_scatter(table: pd.DataFrame, inputs: list[Input], metric: str, method: str, path: Path) -> Path:
    """``metric`` against each input for one method (one panel per input; categorical inputs by label,
    log-uniform ones on a log axis)."""
    plt = pyplot()
    import matplotlib.ticker

    t = table[table["method"] == method]
    cols = min(len(inputs), SCATTER_COLUMNS)
    rows = -(-len(inputs) // cols)
    fig, axs = plt.subplots(rows, cols, figsize=(2.8 * cols, 2.6 * rows), constrained_layout=True, sharey=True,
                            squeeze=False)  # fmt: skip
    for ax in axs.flat[len(inputs):]:
        ax.set_visible(False)
    for ax, inp in zip(axs.flat, inputs):
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
    for row in axs:
        row[0].set_ylabel(metric)
    fig.suptitle(f"{method}: {metric} against each input")
    return save_png(fig, path, dpi=100)


def check_report_out(study: Study, run: DesignRun, results_dir: str | Path) -> Path:
    """Raise :class:`UserError` unless the report of ``run`` may be written into ``results_dir/gsa/``
    (every file there that it would replace is one nearlight wrote); nothing is written. ``nearlight gsa``
    calls it for every design before any runs."""
    folder = Path(results_dir) / FOLDER
    pngs = {f"indices_{m}.png": "png" for m in study.metrics}
    pngs |= {f"scatter_{_safe(m.label)}.png": "png" for m in run.sweep.methods}
    pngs |= {f"convergence_{_safe(m.label)}.png": "png" for m in run.sweep.methods}
    check_files_in(folder, {"indices.csv": "report-csv", "outputs.csv": "report-csv", "convergence.csv": "report-csv",
                            "levels.csv": "report-csv", "gsa.md": "report-md", **pngs})  # fmt: skip
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
    read = [read_results(results_dir / rep.folder) for rep in run.replicates]
    results, complete = pd.concat([r[0] for r in read], ignore_index=True), all(r[1] for r in read)
    metrics = study.metrics
    methods = [m.label for m in run.sweep.methods]
    make_folder(folder, what="report folder")
    design = run.design.method
    table = output_table(study, run, results)
    indices = index_table(study, run, table)
    conv = convergence_table(study, run, table, indices)
    write_text(folder / "indices.csv", indices.to_csv(index=False), what="the report")
    write_text(folder / "outputs.csv", table.to_csv(index=False), what="the report")
    if not conv.empty:
        write_text(folder / "convergence.csv", conv.to_csv(index=False), what="the report")
    levels = sobol_by_level(study, run, table)
    if not levels.empty:
        write_text(folder / "levels.csv", levels.to_csv(index=False), what="the report")
    what = ("Sobol' indices (Saltelli sample, SALib's estimators): total ST [percentile bootstrap interval], "
            "first-order S1 [its interval] in brackets; `≈ 0`: the ST interval does not stand above the floor, "
            "the index a dummy input gets by chance at this N (Khorashadi Zadeh et al. 2017, as sensobol's "
            "sobol_dummy: docs/global-sensitivity.md)" if design == "sobol" else
            "Morris screening (SALib's design): mu* (mean |elementary effect|: the metric's change over a step of "
            "the input divided by the step, per input range) ± half-width of the percentile bootstrap interval, "
            "sigma (interactions and curvature) and the steps used in brackets: a step is used where the method "
            "answered at both ends (nearlight.evaluation.gsa.morris), so a refusal costs its two steps, not its "
            "trajectory; the `failed` output says what made the method refuse")
    md = [f"# Sweep report: global sensitivity of {study.name}, design {run.design.name}", "",
          f"{what}, at {int(100 * run.design.conf_level)} % confidence; "
          + ("`blocks`: Saltelli base samples analysed (a block with a failed or non-finite output is dropped whole)."
             if design == "sobol" else "`whole trajectories`: trajectories with every run answered."), "",
          f"Design: `{design}`, " + _design_text(run) + f", {len(run.samples)} samples, "
          f"{run.tasks} tasks" + ("" if complete else " (INCOMPLETE: rows missing)") + f"; "
          f"{renderers_line(results)}.", "",
          "Inputs: " + "; ".join(f"`{i.name}` {_dist(i)}" for i in study.inputs) + ".", "",
          "## Which input matters most", "", frame_table(headline(indices, design)), ""]  # fmt: skip
    for metric in metrics:
        png = f"indices_{metric}.png"
        plot_indices(indices, metric, design, folder / png)
        md += [f"## {metric}", "", frame_table(_cells(indices, metric, design)), "", f"![indices of {metric}]({png})", ""]
    if not conv.empty:
        several = len(run.replicates) > 1
        md += ["## Convergence", "", f"Every index at N = {', '.join(str(n) for n in sorted(conv['n'].unique()))} "
               "(the first base samples of the design" + (", and each replicate alone: the study under another "
               "scrambling seed" if several else "") + "): `convergence.csv`. The inputs above the floor whose "
               f"intervals at N = {run.design.blocks} do not overlap keep their order in each of these analyses "
               "unless said below. The total indices of " + f"{metrics[0]}:", ""]  # fmt: skip
        for method in methods:
            png = f"convergence_{_safe(method)}.png"
            plot_convergence(conv, metrics[0], method, folder / png)
            md += [f"![{method} convergence]({png})", ""]
            for metric in metrics:
                pairs, changes = order_changes(conv, method, metric)
                turned = [f"at N = {part}: {', '.join(t)}" for part, t in changes.items() if t]
                md += [f"- {method}, {metric}: " + (
                    "no two inputs above the floor with intervals apart, nothing to order" if not pairs else
                    "; ".join(turned) + " turned round" if turned else
                    f"the {len(pairs)} pairs apart keep their order in all {len(changes)}")]  # fmt: skip
            md += [""]
    if design == "morris" and any(i.labels is not None for i in study.inputs):
        md += ["## Where an input's effect depends on a categorical input", "",
               f"Morris mu* of {metrics[0]} over the steps taken at each level of each categorical input "
               "(steps with both ends answered):", ""]  # fmt: skip
        for method in methods:
            Y = sample_outputs(table, method, metrics[0])
            by = effects_by_level(study.inputs, run.design.levels, run.samples, Y)
            md += [f"**{method}**", "", frame_table(by.round(4)), ""]
    if not levels.empty:
        md += ["## Where an input's effect depends on a categorical input", "",
               f"Total indices ST [interval] of {metrics[0]} within each level of each categorical input, as "
               "shares of that level's own variance (Jansen's estimator over the base samples whose A has the "
               "level; `≈ 0`: within that level's floor): `levels.csv` has every metric.", ""]  # fmt: skip
        for method in methods:
            md += [f"**{method}**", "", frame_table(_level_cells(levels, method, metrics[0])), ""]
    md += ["## Where each influential input matters", "",
           (f"From the scatter of {metrics[0]}: each input whose ST stands above the floor" if design == "sobol" else
            f"From the scatter of {metrics[0]}: each input whose mu* is at least a tenth of the largest"), ""]  # fmt: skip
    for method in methods:
        md += [f"**{method}**", ""]
        md += [f"- {where_it_matters(table, inp, metrics[0], method)}" for inp in _influential(indices, study, method,
                                                                                                  metrics[0], design)]
        md += [""]
    md += ["## Scatter plots", "", f"{metrics[0]} against each input (one point per sample).", ""]
    for method in methods:
        png = f"scatter_{_safe(method)}.png"
        plot_scatter(table, study.inputs, metrics[0], method, folder / png)
        md += [f"![{method}]({png})", ""]
    write_text(folder / "gsa.md", "\n".join(md), what="the report")
    record(results_dir, command=command, entry_modules=[__name__], inputs=[study.source], part="gsa")
    return folder


def _above_floor(indices: pd.DataFrame) -> pd.DataFrame:
    """The rows of Sobol' ``indices`` whose ``ST`` interval stands above the chance floor."""
    return indices[np.array([distinguishable(r.ST_lo, r.ST_floor) for r in indices.itertuples()], dtype=bool)]


def _influential(indices: pd.DataFrame, study: Study, method: str, metric: str, design: str) -> list[Input]:
    """The inputs a reader should act on, largest first: Sobol', ``ST`` above the floor; Morris, ``mu*`` at least
    a tenth of the largest (screening ranks; a tenth keeps the inputs whose effect is of the leaders' order)."""
    g = indices[(indices["method"] == method) & (indices["metric"] == metric)].dropna(subset=[_key(design)])
    if design == "sobol":
        g = _above_floor(g)
    elif len(g):
        g = g[g["mu_star"] >= 0.1 * g["mu_star"].max()]
    by_name = {i.name: i for i in study.inputs}
    return [by_name[name] for name in g.sort_values(_key(design), ascending=False)["input"]]


def _design_text(run: DesignRun) -> str:
    d = run.design
    if len(run.replicates) == 1:
        return f"n = {d.n}, seed {d.seed}"
    return f"N = {d.blocks} ({len(run.replicates)} replicates of n = {d.n}, seeds {', '.join(map(str, d.seeds))})"


def _dist(i: Input) -> str:
    if i.labels is not None:
        return "one of " + ", ".join(str(lab) for lab, _ in i.labels)
    a, b = i.bounds
    return f"normal(mean {a:g}, sd {b:g})" if i.dist == "normal" else f"{i.dist}({a:g}, {b:g})"


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)

