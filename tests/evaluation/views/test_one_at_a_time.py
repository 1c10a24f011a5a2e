"""The report's one-at-a-time view: which imperfection (a ``set`` or ``realism`` label) breaks which method."""

from __future__ import annotations

import math
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest
import yaml

from nearlight.evaluation.engine.run import run_sweep
from nearlight.evaluation.views.one_at_a_time import cell_text, label_table, quantile_failures_worst
from nearlight.evaluation.views.report import report_files, write_report
from nearlight.evaluation.engine.store import read_results
from nearlight.evaluation.engine.sweep import load_sweep

# Fake estimators reading the truth (they test the report, not estimation): `off` is the truth moved by
# (1, 1, 1) mm, an error of sqrt(3) mm (1 cm would move the sphere's sharp highlight off its pixels: refused); `broken` always fails; `blind` returns no usable lamp (NaN)
# for the label that moves the lamp (truth lamp_position[2] == 0.6).
FAKES = '''
import numpy as np
from nearlight.estimator import Estimate

def off(capture):
    t = capture.truth
    ks = np.asarray(t["bsdf"]["ks"]) * np.asarray(t["lamp_intensity"]) / 2
    return Estimate(method="off", lamp_position=np.asarray(t["lamp_position"]) + 0.001, ks=ks, sigma=t["bsdf"]["sigma"])

def broken(capture):
    raise RuntimeError("fake estimator failed on purpose")

def blind(capture):
    est = off(capture)
    if capture.truth["lamp_position"][2] == 0.6:
        est.lamp_position = np.full(3, np.nan)
    return est
'''


def test_percentiles_count_a_failure_as_worse_than_any_error():
    x = np.array([3.0, 1.0, 4.0, 1.5, 9.0])
    # finite values: numpy's percentile (linear interpolation), unchanged
    assert quantile_failures_worst(x, 50) == np.median(x) and quantile_failures_worst(x, 90) == np.percentile(x, 90)
    # two failures of five: the median is the third-best error (4.0, of sorted 1, 1.5, 4, inf, inf), p90 failed
    y = np.array([4.0, np.nan, 1.0, np.nan, 1.5])
    assert quantile_failures_worst(y, 50) == 4.0 and quantile_failures_worst(y, 90) == math.inf
    # half or more failed: the median failed (of two: 1 and inf average to inf)
    assert quantile_failures_worst(np.array([np.nan, 2.0, np.nan, 1.0, np.nan]), 50) == math.inf
    assert quantile_failures_worst(np.array([1.0, np.nan]), 50) == math.inf
    assert math.isnan(quantile_failures_worst(np.array([]), 50))


def test_label_table_keeps_file_order_splits_by_object_and_counts_failures():
    # Hand-made rows: 2 objects x labels "none" (1 seed), "jitter" (3 seeds) x methods a, b, in task order.
    rows = []
    for obj in ("sphere", "board"):
        for label, seeds in (("none", [0]), ("jitter", [0, 1, 2])):
            for seed in seeds:
                for method in ("b", "a"):
                    err = {"a": 1.0 + seed, "b": 10.0 * (seed + 1)}[method] * (2 if obj == "board" else 1)
                    status = "ok"
                    if (obj, label, method, seed) == ("board", "jitter", "b", 1):
                        status, err = "error", float("nan")  # a failed task
                    if (obj, label, method, seed) == ("board", "jitter", "b", 2):
                        err = float("nan")  # no usable estimate
                    rows.append({"object": obj, "set": label, "seed": seed, "method": method, "status": status,
                                 "lamp_position_error_pct": err})
    df = pd.DataFrame(rows).assign(task_index=range(len(rows)))
    t = label_table(df.iloc[::-1], "set")  # the rows' order on disk does not matter: task_index does
    assert list(t[["object", "label", "method"]].itertuples(index=False, name=None)) == [
        (o, lab, m) for o in ("sphere", "board") for lab in ("none", "jitter") for m in ("b", "a")]
    cell = t.set_index(["object", "label", "method"])
    assert cell.loc[("sphere", "jitter", "a")][["n", "seeds", "failed", "median"]].tolist() == [3, 3, 0, 2.0]
    assert cell.loc[("sphere", "jitter", "a"), "p90"] == pytest.approx(np.percentile([1.0, 2.0, 3.0], 90))
    assert cell.loc[("board", "none", "b")][["n", "seeds", "failed", "median"]].tolist() == [1, 1, 0, 20.0]
    # 2 of 3 failed (one error row, one NaN): median and p90 failed, both counted
    failed = cell.loc[("board", "jitter", "b")]
    assert (failed["n"], failed["failed"], failed["median"], failed["p90"]) == (3, 2, math.inf, math.inf)



def test_a_run_that_missed_a_lamp_is_counted_as_missed_not_failed():
    # several-lamp rows (evaluation.scoring.matching): a successful run leaving a true lamp unmatched has a NaN
    # worst-lamp error and lamps_missed > 0; it ranks as a failure but the cell names it for what it is
    rows = [{"set": "25 deg", "seed": s, "method": "auto", "status": st, "lamp_position_error_pct": e,
             "n_lamps_true": 2.0, "lamps_missed": m} for s, (st, e, m) in enumerate([("ok", 0.5, 0), ("ok", np.nan, 1), ("ok", 0.7, 0),
                                                                  ("error", np.nan, np.nan), ("ok", 0.6, 0)])]
    t = label_table(pd.DataFrame(rows).assign(task_index=range(5)), "set")
    row = t.iloc[0]
    assert (row["n"], row["failed"], row["missed"], row["median"], row["p90"]) == (5, 1, 1, 0.7, math.inf)
    assert cell_text(row) == "0.7 (failed), 1/5 failed, 1/5 missed a lamp"
    assert cell_text(row, compact=True) == "0.7 (failed) ×1 −1"
    # misses alone: the percentile that falls on one reads "missed"; a missed median is named alone
    only = row.copy()
    only["failed"] = 0
    assert cell_text(only) == "0.7 (missed), 1/5 missed a lamp"
    assert cell_text(only.replace({0.7: math.inf})) == "1/5 missed a lamp"

@pytest.fixture(scope="module")
def fakes(tmp_path_factory):
    d = tmp_path_factory.mktemp("fakes_one_at_a_time")
    (d / "nl_fakes_one_at_a_time.py").write_text(textwrap.dedent(FAKES))
    sys.path.insert(0, str(d))
    yield "nl_fakes_one_at_a_time"
    sys.path.remove(str(d))


def test_the_report_of_a_set_sweep_has_the_table_and_the_heatmap(fakes, tmp_path):
    doc = {"name": "one-at-a-time", "renderer": "analytic",
           "scene": {"width": 48, "height": 36, "lamp_position": [0.05, 0.15, 0.35]},  # >= 10 highlight pixels on the sphere
           "axes": {"object": ["board", "sphere"],
                    "set": {"none": {}, "dim lamp": {"lamp_intensity": 0.5},
                            "far lamp": {"lamp_position": [0.05, 0.15, 0.6]}},
                    "noise": {"none": None, "low": {"full_well": 1000, "read_noise": 2.0, "saturation": 1.0}}},
           "seeds": 2, "methods": [f"{fakes}:off", f"{fakes}:broken", f"{fakes}:blind"]}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = tmp_path / "run"
    run_sweep(load_sweep(path), out, workers=1, progress=False)
    folder = write_report(out)

    for name in ("one_at_a_time.csv", "one_at_a_time_set.png", "error_vs_object.png", "summary.md"):
        assert (folder / name).is_file() and (folder / name).stat().st_size > 0, name
    assert not (folder / "error_vs_set.png").exists()  # a line through labels: the heatmap instead
    table = pd.read_csv(folder / "one_at_a_time.csv")
    assert list(dict.fromkeys(table["label"])) == ["none", "dim lamp", "far lamp"]
    assert list(dict.fromkeys(table["object"])) == ["board", "sphere"]
    assert (table["n"] == 3).all() and (table["seeds"] == 2).all()  # noise-free once + 2 noisy seeds, pooled
    # `off` misses by sqrt(3) mm: its percentage of each row's lamp distance, from the rows themselves
    df, _ = read_results(out)
    rows = df[df["method"] == f"{fakes}:off"]
    for (obj, label), g in rows.groupby(["object", "set"]):
        cell = table[(table["object"] == obj) & (table["label"] == label) & (table["method"] == f"{fakes}:off")]
        expect = 100 * math.sqrt(3) * 0.001 / g["lamp_distance_true_m"]
        assert cell["median"].item() == pytest.approx(np.median(expect), rel=1e-6)
        assert cell["failed"].item() == 0
    # failures are shown, not dropped: broken everywhere, blind only where its truth moved the lamp
    assert (table[table["method"] == f"{fakes}:broken"]["failed"] == 3).all()
    blind = table[table["method"] == f"{fakes}:blind"].set_index(["object", "label"])["failed"]
    assert blind.to_dict() == {(o, lab): 3 if lab == "far lamp" else 0
                               for o in ("board", "sphere") for lab in ("none", "dim lamp", "far lamp")}

    text = (folder / "summary.md").read_text()
    section = text.split("## Which imperfection breaks which method (set)")[1].split("\n## ")[0]
    assert "pooled over noise" in section and "### board" in section and "### sphere" in section
    assert "| set | " in section and "| far lamp | " in section
    # broken: every run failed, in every row; blind: those of the far lamp, beside broken's
    assert section.count("3/3 failed") == 2 * (3 + 1) and section.count("| 3/3 failed | 3/3 failed |") == 2
    assert "](one_at_a_time_set.png)" in section


def test_a_realism_axis_gets_the_view_too_and_no_line_plot_through_labels():
    files = report_files(["realism", "lamp_distance"], ["realism"])
    assert files["one_at_a_time_realism.png"] == "png" and files["one_at_a_time.csv"] == "report-csv"
    assert "error_vs_realism.png" not in files and "error_vs_lamp_distance.png" in files
    assert not any(name.startswith("one_at_a_time") for name in report_files(["lamp_distance"]))
