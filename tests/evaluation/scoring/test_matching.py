"""Estimated lamps matched to true ones, and the rows scored through the matching."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nearlight.errors import UserError
from nearlight.estimator import Estimate
from nearlight.evaluation.scoring.matching import GATE_FRACTION, gate_radii, match_lamps
from nearlight.evaluation.scoring.metrics import METRICS, highlight_point, score, truth_estimate
from nearlight.generator.analytic import analytic_capture, analytic_capture_lamps

A, B, C = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 1.0]), np.array([0.0, 1.0, 1.0])
GATE3 = np.full(3, 0.2)


def _pairs(m):
    return [tuple(p) for p in m.pairs.tolist()]


# --------------------------------------------------------------------------- matching by hand


def test_swapped_order_is_matched_back():
    m = match_lamps([B + 0.01, A - 0.02, C], [A, B, C], GATE3)
    assert _pairs(m) == [(1, 0), (0, 1), (2, 2)]
    assert m.missed.tolist() == [] and m.extra.tolist() == []
    np.testing.assert_allclose(m.errors_m, [0.02 * math.sqrt(3), 0.01 * math.sqrt(3), 0.0])
    assert m.estimate_of(0) == 1 and m.estimate_of(2) == 2


def test_one_missed_and_one_extra():
    missed = match_lamps([C, A], [A, B, C], GATE3)
    assert _pairs(missed) == [(1, 0), (0, 2)] and missed.missed.tolist() == [1] and missed.extra.tolist() == []
    assert missed.estimate_of(1) is None
    extra = match_lamps([A, A + [5.0, 0, 0], B], [A, B], GATE3[:2])
    assert _pairs(extra) == [(0, 0), (2, 1)] and extra.missed.tolist() == [] and extra.extra.tolist() == [1]


def test_gate_is_inclusive_and_per_lamp():
    true = [A, B]
    inside = match_lamps([A + [0.2, 0, 0]], true, [0.2, 0.1])
    assert _pairs(inside) == [(0, 0)]
    outside = match_lamps([A + [0.2001, 0, 0]], true, [0.2, 0.1])
    assert _pairs(outside) == [] and outside.missed.tolist() == [0, 1] and outside.extra.tolist() == [0]
    # the same estimate near B is out of B's smaller gate
    assert _pairs(match_lamps([B + [0, 0.15, 0]], true, [0.2, 0.1])) == []
    # no gate: any finite pair
    assert _pairs(match_lamps([A + [9.0, 0, 0]], [A])) == [(0, 0)]


def test_nearest_within_gate_wins_and_one_estimate_per_lamp():
    # both estimates are inside A's gate; the closer is A's, the other is extra
    m = match_lamps([A + [0.1, 0, 0], A + [0.05, 0, 0]], [A], [0.2])
    assert _pairs(m) == [(1, 0)] and m.extra.tolist() == [0]


def test_non_finite_and_empty_inputs():
    m = match_lamps([[np.nan, 0, 0], A], [A, B], GATE3[:2])
    assert _pairs(m) == [(1, 0)] and m.extra.tolist() == [0] and m.missed.tolist() == [1]
    assert _pairs(match_lamps([[np.nan, 0, 0]], [A])) == []  # no gate: still no match for a NaN estimate
    assert match_lamps(np.zeros((0, 3)), [A, B], GATE3[:2]).missed.tolist() == [0, 1]
    assert match_lamps([A], np.zeros((0, 3)), np.zeros(0)).extra.tolist() == [0]
    # a lamp without a highlight (NaN gate) is never matched
    assert _pairs(match_lamps([A], [A], [np.nan])) == []


def test_gate_radii():
    np.testing.assert_allclose(gate_radii([[0, 0, 2.0], [0, 3.0, 0]], [[0, 0, 0], [0, 0, 0]]),
                               [2 * GATE_FRACTION, 3 * GATE_FRACTION])
    assert np.isnan(gate_radii([[0, 0, 1.0]], [[np.nan] * 3])[0])


# --------------------------------------------------------------------------- scoring a two-lamp capture

#: Two lamps mirrored in x, 0.47 m from their highlights on the default analytic board; 0.30 m apart, so
#: their midpoint is 0.15 m = 32 % of the distance from each: outside both 20 % gates.
LAMPS = ([0.15, 0.2, 0.4], [-0.15, 0.2, 0.4])


@pytest.fixture(scope="module")
def two_lamps():
    return analytic_capture_lamps([{"position": p} for p in LAMPS], width=80, height=60)


def _est(lamp_position, lamp_positions=None):
    return Estimate(method="fake", lamp_position=lamp_position, ks=[0.3, 0.3, 0.3], sigma=0.1,
                    lamp_positions=lamp_positions)


def test_two_lamp_geometry_of_the_fixture(two_lamps):
    assert "lamp_position" not in two_lamps.truth and len(two_lamps.truth["lamps"]) == 2
    origins = [highlight_point(two_lamps.P, two_lamps.N, two_lamps.camera.position, p) for p in LAMPS]
    assert np.all(np.isfinite(origins))
    d = [np.linalg.norm(np.asarray(p) - o) for p, o in zip(LAMPS, origins)]
    half = 0.5 * np.linalg.norm(np.subtract(*LAMPS))
    assert half > 1.25 * GATE_FRACTION * max(d)  # the midpoint is well outside both gates


def test_both_lamps_found(two_lamps):
    row = score(two_lamps, _est(LAMPS[1], lamp_positions=LAMPS[::-1]))
    assert (row["n_lamps_true"], row["n_lamps_found"], row["lamps_missed"], row["lamps_extra"]) == (2, 2, 0, 0)
    for c in ("lamp_position_error_m", "lamp_position_error_pct", "direction_error_deg", "distance_error_m",
              "distance_signed_m", "lamp0_position_error_m", "lamp1_position_error_pct"):
        assert row[c] == pytest.approx(0.0, abs=1e-12), c
    assert 0.4 < row["lamp_distance_true_m"] < 0.6



def test_highlights_true_counts_separate_highlights_and_merged_ones_as_one(two_lamps):
    # the fixture's lamps 0.30 m apart light two separate highlights; 1 cm apart (the lobes, σ = 0.1,
    # are ~10 cm wide on the board) they light one blob, which the segmentation sees as one
    assert score(two_lamps, _est(LAMPS[0], lamp_positions=LAMPS))["highlights_true"] == 2.0
    near = analytic_capture_lamps([{"position": [x, 0.2, 0.4]} for x in (0.005, -0.005)], width=80, height=60)
    assert score(near, _est([0.0, 0.2, 0.4]))["highlights_true"] == 1.0
    one = analytic_capture(width=80, height=60)
    assert "highlights_true" not in score(one, truth_estimate(one))  # one-lamp rows keep their columns

def test_worst_lamp_is_the_row_error(two_lamps):
    off = np.array([0.0, 0.0, 0.02])
    row = score(two_lamps, _est(LAMPS[0], lamp_positions=[LAMPS[0], np.add(LAMPS[1], 2 * off)]))
    assert row["lamp0_position_error_m"] == pytest.approx(0.0, abs=1e-12)
    assert row["lamp1_position_error_m"] == pytest.approx(0.04)
    assert row["lamp_position_error_m"] == pytest.approx(0.04)  # the worst, not the mean (0.02)
    assert row["lamp_position_error_pct"] == pytest.approx(row["lamp1_position_error_pct"])


def test_one_of_two_found_is_one_missed_not_an_average(two_lamps):
    row = score(two_lamps, _est(LAMPS[1]))  # a one-lamp method: no lamp_positions
    assert (row["n_lamps_true"], row["n_lamps_found"], row["lamps_missed"], row["lamps_extra"]) == (2, 1, 1, 0)
    assert row["lamp1_position_error_m"] == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(row["lamp0_position_error_m"]) and math.isnan(row["lamp0_position_error_pct"])
    for c in ("lamp_position_error_m", "lamp_position_error_pct", "direction_error_deg", "distance_error_m",
              "distance_signed_m"):
        assert math.isnan(row[c]), c


def test_one_lamp_halfway_matches_neither(two_lamps):
    row = score(two_lamps, _est(np.mean(LAMPS, axis=0)))
    assert (row["n_lamps_true"], row["n_lamps_found"], row["lamps_missed"], row["lamps_extra"]) == (2, 1, 2, 1)
    assert math.isnan(row["lamp_position_error_m"]) and math.isnan(row["lamp0_position_error_pct"])
    assert math.isnan(row["lamp1_position_error_pct"])
    assert math.isfinite(row["specular_rmse"])  # the image is still graded: one lamp cannot explain two


def test_several_lamp_readers_fail_in_one_line(two_lamps):
    with pytest.raises(UserError, match=r"^capture: the oracle estimate expects a capture with one lamp; it has 2"):
        truth_estimate(two_lamps)
    from nearlight.evaluation.scoring.crlb import specular_crlb

    with pytest.raises(UserError, match="the Cramér–Rao bound expects a capture with one lamp; it has 2 lamps"):
        specular_crlb(two_lamps, noise_var=1e-4)
    from nearlight.evaluation.paper.fidelity import _lamp
    from nearlight.evaluation.paper.reproduce import _truth

    with pytest.raises(UserError, match="the paper-fidelity study expects a capture with one lamp"):
        _lamp(two_lamps)
    with pytest.raises(UserError, match="the paper reproduction expects a capture with one lamp"):
        _truth(two_lamps)


def test_crlb_column_is_skipped_not_an_error_row_for_several_lamps(two_lamps):
    from nearlight.evaluation.engine.tasks import _crlb

    assert _crlb(two_lamps, {"crlb": True, "noise": {"read_noise": 0.01}}) == {}


# --------------------------------------------------------------------------- one-lamp rows are unchanged

#: ``score()`` of the one-lamp cases of :func:`_one_lamp_cases` at the base commit 2ccb3ab (before matching
#: existed): ``git archive 2ccb3ab`` unpacked as ``/tmp/base/nearlight``, then with this venv's Python and
#: ``PYTHONPATH=/tmp/base`` the loop in ``_one_lamp_cases``'s docstring, printed as JSON (repr of each float).
#: The columns that existed then must keep exactly these numbers (and their order); new columns come after.
BASE = {
    "board_offset": {
        "lamp_position_error_m": 0.03741657386773943,
        "lamp_position_error_pct": 9.229787102778468,
        "direction_error_deg": 4.563416097918045,
        "distance_error_m": 0.01768047395911526,
        "sigma_rel_error": 0.10000000000000009,
        "ks_rel_error": 0.04670993664969147,
        "specular_rmse": 0.7096560755993961,
        "specular_rmse_rel": 0.12407703673892947,
        "distance_signed_m": 0.01768047395911526,
        "lamp_distance_true_m": 0.4053893491917686,
        "sigma_truth": 0.1,
    },
    "sphere_offset": {
        "lamp_position_error_m": 0.058309518948452994,
        "lamp_position_error_pct": 39.197039698936564,
        "direction_error_deg": 19.60199235481837,
        "distance_error_m": 0.021533766921987163,
        "sigma_rel_error": 0.12499999999999993,
        "ks_rel_error": 0.03947710169758619,
        "specular_rmse": 1.5478461497817217,
        "specular_rmse_rel": 0.032816132456808346,
        "distance_signed_m": 0.021533766921987163,
        "lamp_distance_true_m": 0.14876000686866914,
        "sigma_truth": 0.08,
    },
    "board_far": {
        "lamp_position_error_m": 0.3464101615137755,
        "lamp_position_error_pct": 85.45122416373768,
        "direction_error_deg": 16.21050225190264,
        "distance_error_m": 0.31128500445510854,
        "sigma_rel_error": 0.10000000000000009,
        "ks_rel_error": 0.04670993664969147,
        "specular_rmse": 0.9656983165791885,
        "specular_rmse_rel": 0.16884373941801883,
        "distance_signed_m": 0.31128500445510854,
        "lamp_distance_true_m": 0.4053893491917686,
        "sigma_truth": 0.1,
    },
}


def _one_lamp_cases():
    """The base values came from this, with ``nearlight`` importing the base commit's tree:

    ``for name, (kw, off) in CASES.items(): cap = analytic_capture(**kw); est = Estimate("fake",
    truth + off, [0.3, 0.25, 0.2], 0.09); print(name, score(cap, est))``
    """
    ts = {"model": "torrance_sparrow", "ks": [0.5, 0.4, 0.3], "sigma": 0.08}
    return {
        "board_offset": (dict(width=80, height=60), (0.01, -0.02, 0.03)),
        "sphere_offset": (dict(width=80, height=60, shape="sphere", bsdf=ts), (-0.03, 0.0, 0.05)),
        "board_far": (dict(width=80, height=60), (0.2, 0.2, 0.2)),
    }


@pytest.mark.parametrize("name", list(BASE))
def test_one_lamp_rows_keep_their_numbers(name):
    kw, off = _one_lamp_cases()[name]
    cap = analytic_capture(**kw)
    est = Estimate(method="fake", lamp_position=np.asarray(cap.truth["lamp_position"]) + off,
                   ks=[0.3, 0.25, 0.2], sigma=0.09)
    row = score(cap, est)
    base = BASE[name]
    assert list(row)[: len(base)] == list(base)  # same columns, same order, new ones after
    # the same numbers to float64 rounding: another CPU (its vectorised math) moves the last bits of a
    # few columns (measured: 1 ulp of ks_rel_error and direction_error_deg on an Intel Xeon against
    # the machine the base values came from), any change of the scoring moves them by far more
    for c, v in base.items():
        assert (math.isnan(row[c]) if v is None else row[c] == pytest.approx(v, rel=1e-12, abs=1e-15)), (c, row[c], v)
    # one true and one estimated lamp: no gate, 1/1/0/0 even for the far (> 20 %) estimate
    assert (row["n_lamps_true"], row["n_lamps_found"], row["lamps_missed"], row["lamps_extra"]) == (1, 1, 0, 0)
    assert not any(c.startswith("lamp0_") for c in row)


def test_one_lamp_non_finite_estimate_is_missed_with_nan_errors():
    cap = analytic_capture(width=80, height=60)
    row = score(cap, Estimate(method="fake", lamp_position=[np.nan, 0, 0], ks=[0.3] * 3, sigma=0.1))
    assert math.isnan(row["lamp_position_error_m"])
    assert (row["lamps_missed"], row["lamps_extra"]) == (1, 1)


def test_truth_is_exact_and_metrics_registry_unchanged():
    cap = analytic_capture(width=80, height=60)
    row = score(cap, truth_estimate(cap))
    assert row["lamp_position_error_m"] == 0.0 and row["lamps_missed"] == 0
    assert list(METRICS) == ["lamp_position_error_m", "lamp_position_error_pct", "direction_error_deg",
                             "distance_error_m", "sigma_rel_error", "ks_rel_error", "specular_rmse",
                             "specular_rmse_rel", "runtime_s"]


# --------------------------------------------------------------------------- the estimate's optional lamps


def test_estimate_lamp_positions_is_optional_and_serialised_only_when_set():
    one = _est([0, 0, 1])
    assert one.lamp_positions is None and one.found_lamps().shape == (1, 3)
    assert "lamp_positions" not in one.to_dict()
    two = _est([0, 0, 1], lamp_positions=[[0, 0, 1], [1, 0, 1]])
    assert two.found_lamps().shape == (2, 3) and two.to_dict()["lamp_positions"] == [[0, 0, 1], [1, 0, 1]]
    none = _est([0, 0, 1], lamp_positions=np.zeros((0, 3)))
    assert none.found_lamps().shape == (0, 3)


# --------------------------------------------------------------------------- sweep axis and tables


def test_lamp_distance_axis_on_several_lamps_is_a_one_line_error():
    from nearlight.evaluation.engine.renderers import MitsubaRenderer

    r = MitsubaRenderer()
    two = {"object": {"position": [0, 0, 0]}, "lamps": [{"position": [0.1, 0.2, 0.4]}, {"position": [-0.1, 0.2, 0.4]}]}
    with pytest.raises(UserError, match=r"^sweep: lamp_distance: expected a scene with one lamp, this one has 2"):
        r.apply_axis(two, "lamp_distance", 0.5, where="sweep")
    one = {"object": {"position": [0, 0, 0]}, "lamps": [{"position": [0.0, 0.3, 0.4]}]}
    r.apply_axis(one, "lamp_distance", 1.0, where="sweep")
    np.testing.assert_allclose(one["lamps"][0]["position"], [0.0, 0.6, 0.8])
    classic = {"object": {"position": [0, 0, 0]}, "lamp": {"position": [0.0, 0.3, 0.4]}}
    r.apply_axis(classic, "lamp_distance", 1.0, where="sweep")
    np.testing.assert_allclose(classic["lamp"]["position"], [0.0, 0.6, 0.8])


def test_lamp_table_and_compare_axes(two_lamps):
    import pandas as pd

    from nearlight.evaluation.views.compare import _axes
    from nearlight.evaluation.views.report import lamp_table

    rows = []
    for method, est in (("both", _est(LAMPS[0], lamp_positions=LAMPS)), ("one", _est(LAMPS[1])),
                        ("half", _est(np.mean(LAMPS, axis=0)))):
        rows.append({"status": "ok", "method": method, "roughness": 0.1, **score(two_lamps, est)})
    df = pd.DataFrame(rows)
    t = lamp_table(df).set_index("method")
    assert t.loc["both", ["lamps_true", "lamps_found", "matched", "missed", "extra", "all_found"]].tolist() == [2, 2, 2, 0, 0, 1]
    assert t.loc["one", ["matched", "missed", "extra", "all_found"]].tolist() == [1, 1, 0, 0]
    assert t.loc["half", ["matched", "missed", "extra"]].tolist() == [0, 2, 1]
    assert math.isnan(t.loc["one", "lamp0_median_error_pct"]) and t.loc["one", "lamp1_median_error_pct"] == 0.0
    assert _axes(df, None) == ["roughness"]  # per-lamp and count columns are results, not configuration
    one_lamp = pd.DataFrame([{"status": "ok", "method": "m", **score(analytic_capture(width=80, height=60),
                                                                       truth_estimate(analytic_capture(width=80, height=60)))}])
    assert lamp_table(one_lamp).empty  # one-lamp sweeps: no lamps section, the report is as before
    # ... unless a method counted the lamps itself (lamps=auto): then how often it found one and nothing extra
    counted = lamp_table(one_lamp.assign(lamps_counted=1.0)).set_index("method")
    assert counted.loc["m", ["tasks", "lamps_true", "lamps_found", "extra", "all_found"]].tolist() == [1, 1, 1, 0, 1]



def test_lamps_by_label_counts_every_lamp_found_per_label_and_method(two_lamps):
    import pandas as pd

    from nearlight.evaluation.views.report import lamps_by_label

    both, one = score(two_lamps, _est(LAMPS[0], lamp_positions=LAMPS)), score(two_lamps, _est(LAMPS[1]))
    rows = [{"set": "far", "method": "auto", "status": "ok", **both}, {"set": "far", "method": "one", "status": "ok", **one},
            {"set": "far", "method": "auto", "status": "error"},  # a failed task: no counts, not found
            {"set": "far", "method": "one", "status": "ok", **one}]
    t = lamps_by_label(pd.DataFrame(rows).assign(task_index=range(4)), "set").set_index("method")
    assert t.loc["auto", ["label", "tasks", "all_found", "highlights_min", "highlights_max"]].tolist() == [
        "far", 2, 1, 2.0, 2.0]
    assert t.loc["one", ["tasks", "all_found"]].tolist() == [2, 0]
    single = pd.DataFrame([{"set": "x", "method": "m", "status": "ok", "task_index": 0, "n_lamps_true": 1.0}])
    assert lamps_by_label(single, "set").empty


def test_the_summary_shows_the_highlights_range_where_other_axes_change_it():
    import pandas as pd

    from nearlight.evaluation.views.report import _lamps_by_wide, lamps_by_label

    # one label, equal lamps (two highlights) and a faint second lamp (one blob): 1–2, not a median of 1.5
    rows = [{"set": "30deg", "method": "auto", "status": "ok", "n_lamps_true": 2.0, "lamps_missed": 0.0,
             "lamps_extra": 0.0, "highlights_true": h} for h in (2.0, 1.0)]
    rows += [{"set": "40deg", "method": "auto", "status": "ok", "n_lamps_true": 2.0, "lamps_missed": 1.0,
              "lamps_extra": 0.0, "highlights_true": 2.0}]
    wide = _lamps_by_wide(lamps_by_label(pd.DataFrame(rows).assign(task_index=range(3)), "set"))
    assert wide[["set", "highlights", "auto"]].values.tolist() == [["30deg", "1–2", "2/2"], ["40deg", "2", "0/1"]]

def test_report_shows_the_lamps_section_only_for_several_lamps(two_lamps, tmp_path):
    import pandas as pd

    from nearlight.evaluation.views.report import write_report

    one_cap = analytic_capture(width=80, height=60)
    rows = []
    for k, (cap, method, est) in enumerate(((two_lamps, "both", _est(LAMPS[0], lamp_positions=LAMPS)),
                                            (two_lamps, "one", _est(LAMPS[1])),
                                            (one_cap, "one", truth_estimate(one_cap)))):
        rows.append({"task_id": f"t{k}", "task_index": k, "status": "ok", "error": "", "method": method,
                     "code_version": "test", "noisy": False, "seed": 0, "runtime_s": 1.0, **score(cap, est)})
    several, single = tmp_path / "several", tmp_path / "single"
    for folder, df in ((several, pd.DataFrame(rows)), (single, pd.DataFrame(rows[2:]))):
        folder.mkdir()
        df.to_parquet(folder / "results.parquet", index=False)
        write_report(folder)
    summary = (several / "report" / "summary.md").read_text()
    assert "## Lamps found" in summary and (several / "report" / "lamps.png").is_file()
    lamps = pd.read_csv(several / "report" / "lamps.csv").set_index("method")
    assert lamps.loc["one", ["lamps_true", "matched", "missed", "extra"]].tolist() == [3, 2, 1, 0]
    assert not (single / "report" / "lamps.csv").exists()
    assert "Lamps found" not in (single / "report" / "summary.md").read_text()


def test_a_row_records_whether_the_method_counted_the_lamps():
    from nearlight.evaluation.scoring.metrics import estimate_columns

    auto = Estimate(method="full", lamp_position=[0, 0, 1], ks=[1, 1, 1], sigma=0.1,
                    stages={"full": {"lobe": "ward", "lamps_option": "auto"}})
    assert estimate_columns(auto)["lamps_counted"] == 1.0 and estimate_columns(auto)["est_lobe"] == "ward"
    for stages in ({}, {"full": {"lobe": "ggx"}}, {"full": {"lamps_option": 2}}):  # one lamp, or a number given
        est = Estimate(method="x", lamp_position=[0, 0, 1], ks=[1, 1, 1], sigma=0.1, stages=stages)
        assert estimate_columns(est)["lamps_counted"] == 0.0
