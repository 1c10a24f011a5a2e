"""`nearlight score` on a tiny analytic suite with plug-in methods: the truth out of the method's reach,
recall ladders that an oracle tops and a highlight-point guess fails, resume, output places, compare."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nearlight.capture import read_capture
from nearlight.cli import main
from nearlight.evaluation.scoring.metrics import truth_estimate
from nearlight.evaluation.suites.scorecard import LADDERS, median_ci, scorecard, scorecard_markdown
from nearlight.evaluation.suites.suite import read_manifest

from .test_build import N_CASES, write_suite

#: Test-only plug-ins. `oracle` reads the truth from a side file the test writes (oracle.json beside this
#: module), keyed by the case folder; the rest see only what `score` hands them.
PLUGINS = '''
import json
from pathlib import Path

import numpy as np

from nearlight.estimator import Estimate

HERE = Path(__file__).parent


def oracle(capture):
    t = json.loads((HERE / "oracle.json").read_text())[str(capture.source.parent)]
    return Estimate(method="oracle", lamp_position=np.array(t["lamp"]), ks=np.array(t["ks"]), sigma=t["sigma"])


def highlight(capture):
    """The lamp at the brightest surface point: 100 % of the distance off, by construction."""
    total = np.where(capture.surface_mask, capture.stack.sum(axis=(0, 3)), -np.inf)
    i, j = np.unravel_index(np.argmax(total), total.shape)
    return Estimate(method="highlight", lamp_position=capture.P[i, j], ks=np.ones(3), sigma=0.1)


def peek(capture):
    """Record what a method is handed, then answer like the oracle."""
    seen = {"truth": capture.truth, "layers": sorted(capture.extra), "meta_keys": sorted(capture.meta), "meta": json.dumps(capture.meta)}
    (HERE / f"peek-{capture.source.parent.name}.json").write_text(json.dumps(seen))
    return oracle(capture)


def cheat(capture):
    """Read the truth from the capture: gets None, so it fails (a miss), never a score."""
    return Estimate(method="cheat", lamp_position=np.array(capture.truth["lamp_position"]), ks=np.ones(3), sigma=0.1)
'''


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    root = tmp_path_factory.mktemp("suite")
    assert main(["suite", "build", str(write_suite(root)), "--out", str(root / "built"), "--quiet", "--no-cache"]) == 0
    return root / "built"


@pytest.fixture(scope="module")
def plugins(suite, tmp_path_factory):
    d = tmp_path_factory.mktemp("plugins")
    (d / "nl_score_plugins.py").write_text(textwrap.dedent(PLUGINS))
    truths = {}
    for c in read_manifest(suite)["cases"]:
        est = truth_estimate(read_capture(suite / c["path"] / "truth"))
        truths[str(suite / c["path"])] = {"lamp": est.lamp_position.tolist(), "ks": est.ks.tolist(), "sigma": est.sigma}
    (d / "oracle.json").write_text(json.dumps(truths))
    sys.path.insert(0, str(d))
    yield d
    sys.path.remove(str(d))


def _score(suite, out, method, *extra):
    return main(["score", str(suite), "--method", method, "--out", str(out), "--quiet", *extra])


def _card(out):
    return json.loads((out / "scorecard.json").read_text())


def test_oracle_reaches_full_recall_at_every_threshold(suite, plugins, tmp_path, capsys):
    out = tmp_path / "oracle"
    assert _score(suite, out, "nl_score_plugins:oracle") == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("nl_score_plugins:oracle on tiny-v1 v1: lamp recall <0.5%: 100%")
    assert printed[1:] == [str(out / n) for n in ("scorecard.md", "scorecard.json", "scorecard.png", "results.jsonl")]
    card = _card(out)
    assert card["cases"] == N_CASES and card["failed"] == 0
    assert [(g["category"], g["value"]) for g in card["groups"]] == [
        ("all", "all"), ("lamp_distance", 0.3), ("lamp_distance", 0.5), ("noise", "clean"), ("noise", "sensor")]
    for g in card["groups"]:
        for metric in LADDERS:
            assert g[metric]["recall"] == [1.0] * 5, (g["value"], metric)
            # the truth read back from float32 EXR and JSON: errors at rounding level, far below 0.5 %
            assert g[metric]["median"] < 1e-4
    assert (out / "scorecard.md").read_text().startswith("# Scorecard: nl_score_plugins:oracle on tiny-v1 v1")
    assert (out / "scorecard.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # a committed scorecard goes stale when the code that scored changes (tests/test_reports_fresh.py)
    from nearlight.evaluation.engine import provenance

    record = json.loads((out / "provenance.json").read_text())["parts"]["results"]
    assert record["command"] == f"nearlight score {suite} --method nl_score_plugins:oracle --out {out}"
    assert "evaluation/scoring/metrics.py" in record["code"] and provenance.stale(out) == []


def test_highlight_point_guess_has_no_recall_below_ten_percent(suite, plugins, tmp_path):
    out = tmp_path / "highlight"
    assert _score(suite, out, "nl_score_plugins:highlight") == 0
    card = _card(out)
    lamp = card["groups"][0]["lamp_position_error_pct"]
    assert lamp["recall"] == [0.0] * 5
    # the lamp on the surface (the brightest pixel, ~100 % of the distance off) lights nothing there with Ks 1:
    # every case refused by the sanity rules, a miss with its reason, not a number
    assert card["groups"][0]["failed"] == N_CASES
    assert all(e.startswith("estimate: ") for e in card["errors"])


def test_method_gets_no_truth(suite, plugins, tmp_path):
    assert _score(suite, tmp_path / "peek", "nl_score_plugins:peek") == 0
    seen = [json.loads(p.read_text()) for p in sorted(plugins.glob("peek-*.json"))]
    assert len(seen) == N_CASES
    lamps = [json.dumps(read_capture(suite / c["path"] / "truth").truth["lamp_position"])[1:-1].split(", ")
             for c in read_manifest(suite)["cases"]]  # fmt: skip
    for s in seen:
        assert s["truth"] is None
        assert not any(k.startswith("truth") for k in s["layers"])
        # nor in another form: the generator's record of the scene (lamp position, material) is gone
        assert "generator" not in s["meta_keys"] and not any(x in s["meta"] for lamp in lamps for x in lamp)


def test_a_method_reading_truth_gets_nothing_and_fails(suite, plugins, tmp_path):
    out = tmp_path / "cheat"
    assert _score(suite, out, "nl_score_plugins:cheat") == 0
    card = _card(out)
    assert card["failed"] == N_CASES
    assert all(r == 0.0 for metric in LADDERS for r in card["groups"][0][metric]["recall"])
    assert math.isinf(card["groups"][0]["lamp_position_error_pct"]["median"] or math.inf)  # JSON null: +inf
    assert "NoneType" in card["errors"][0] and "## Failures" in (out / "scorecard.md").read_text()


def test_rerun_skips_scored_cases_and_rescores_a_lost_one(suite, plugins, tmp_path, capsys):
    out = tmp_path / "resume"
    assert _score(suite, out, "nl_score_plugins:oracle") == 0
    first = _card(out)
    capsys.readouterr()
    assert _score(suite, out, "nl_score_plugins:oracle") == 0
    assert f"ran 0 case(s), skipped {N_CASES} already scored" in capsys.readouterr().err
    next((out / "parts").glob("*.parquet")).unlink()
    assert _score(suite, out, "nl_score_plugins:oracle") == 0
    assert f"ran 1 case(s), skipped {N_CASES - 1} already scored" in capsys.readouterr().err
    assert _card(out)["groups"] == first["groups"]


def test_two_worker_processes_give_the_same_rows(suite, plugins, tmp_path):
    """Cases sent to spawned workers (each reads its case from the suite folder) score as in-process."""
    from nearlight.evaluation.engine.store import read_results

    one, two = tmp_path / "one", tmp_path / "two"
    assert _score(suite, one, "distant") == 0 and _score(suite, two, "distant", "--workers", "2") == 0
    rows = [read_results(d)[0].drop(columns="runtime_s").set_index("task_id").sort_index() for d in (one, two)]
    pd.testing.assert_frame_equal(*rows)
    assert _card(one)["groups"] == _card(two)["groups"]


def test_bad_input_is_one_line_and_touches_nothing(suite, plugins, tmp_path, capsys):
    out = tmp_path / "o"
    assert _score(suite, out, "no-such-method") == 2
    assert "--method: unknown method 'no-such-method'" in capsys.readouterr().err
    assert _score(tmp_path, out, "full") == 2
    assert "manifest.json: missing" in capsys.readouterr().err
    # another method's results folder is not resumed
    assert _score(suite, out, "nl_score_plugins:oracle") == 0
    assert _score(suite, out, "nl_score_plugins:highlight") == 2
    assert "holds another run" in capsys.readouterr().err
    # a user's file where the scorecard goes is never replaced
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "scorecard.md").write_text("my notes\n")
    assert _score(suite, mine, "nl_score_plugins:oracle") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "scorecard.md: exists and is not a scorecard" in err
    assert (mine / "scorecard.md").read_text() == "my notes\n" and not (mine / "parts").exists()


def test_checksum_mismatch_is_refused_before_scoring(suite, tmp_path, capsys):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(suite, copy)
    (copy / "cases" / "004" / "truth" / "capture.json").write_text("{}")
    assert _score(copy, tmp_path / "o", "full") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cases/004/truth/capture.json: checksum mismatch" in err
    assert not (tmp_path / "o" / "parts").exists()


def test_compare_scorecards_method_against_method(suite, plugins, tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert _score(suite, a, "nl_score_plugins:oracle") == 0 and _score(suite, b, "nl_score_plugins:highlight") == 0
    capsys.readouterr()
    assert main(["compare", str(a), str(a)]) == 0
    assert "each case paired with its baseline case (by case id)" in capsys.readouterr().out
    assert main(["compare", str(b), str(a)]) == 1  # the highlight guess is worse than the oracle
    text = capsys.readouterr().out
    assert "'nl_score_plugins:highlight' (new) against 'nl_score_plugins:oracle' (baseline)" in text
    assert "0 missing" in text and "WORSE than" in text


def test_median_interval_counts_misses_as_infinite():
    x = np.array([1.0, 2.0, 3.0, 4.0, 5.0, np.nan, np.nan])
    med, lo, hi = median_ci(x)
    assert med == 4.0 and lo <= med <= hi and hi == np.inf  # 2 of 7 misses: resamples with >= 4 reach +inf
    med, lo, hi = median_ci(np.array([np.nan, np.nan, 1.0]))
    assert med == np.inf
    assert np.isnan(median_ci(np.array([]))[0])
    # a fixed seed: the same interval every run
    assert median_ci(np.arange(20.0)) == median_ci(np.arange(20.0))


def test_recall_ladder_on_known_errors():
    """4 cases, lamp errors 0.3, 1.5, 7 %, and one failure: recall 1/4, 1/4, 2/4, 2/4, 3/4; in millimetres 0.5, 3, 15
    and the failure (thresholds 1, 2, 5, 10, 20 mm): the same; directions 0.2°, 3°, 30° (0.5°, 1°, 2°, 5°, 10°)."""
    df = pd.DataFrame({"status": ["ok", "ok", "ok", "error"], "lamp_position_error_pct": [0.3, 1.5, 7.0, np.nan],
                       "lamp_position_error_m": [0.0005, 0.003, 0.015, np.nan],
                       "direction_error_deg": [0.2, 3.0, 30.0, np.nan],
                       "sigma_rel_error": [0.0, 0.0, 0.0, np.nan], "ks_rel_error": [0.0, 0.0, np.nan, np.nan],
                       "runtime_s": [1.0, 2.0, 3.0, np.nan], "code_version": "x", "error": ["", "", "", "boom"],
                       "k": ["a", "a", "b", "b"]})  # fmt: skip
    card = scorecard(df, {"suite": "s", "version": 1, "cases_hash": "h"}, label="m", categories=["k"])
    g = card["groups"][0]
    assert g["lamp_position_error_pct"]["recall"] == [0.25, 0.25, 0.5, 0.5, 0.75]
    assert g["lamp_position_error_m"]["recall"] == [0.25, 0.25, 0.5, 0.5, 0.75]
    assert g["direction_error_deg"]["recall"] == [0.25, 0.25, 0.25, 0.5, 0.5]
    assert g["ks_rel_error"]["recall"] == [0.5] * 5  # a NaN error is a miss too
    md = scorecard_markdown(card)
    assert "| < 1 mm | < 2 mm | < 5 mm | < 10 mm | < 20 mm |" in md
    assert "## lamp (mm) (lamp_position_error_m, absolute)" in md and "< 0.5 °" in md
    assert (card["failed"], card["runtime_s"]["total"]) == (1, 6.0)
    assert [(x["value"], x["n"], x["failed"]) for x in card["groups"][1:]] == [("a", 2, 0), ("b", 2, 1)]


def test_score_path_imports_no_renderer(suite, tmp_path):
    """A plain install scores a built suite: nothing on the score path imports Mitsuba or Dr.Jit."""
    code = textwrap.dedent(f"""
        import sys
        from nearlight.cli import main
        assert main(["score", {str(suite)!r}, "--method", "distant", "--out", {str(tmp_path / "d")!r}, "--quiet"]) == 0
        bad = sorted(m for m in sys.modules if m.split(".")[0] in ("mitsuba", "drjit"))
        assert not bad, bad
    """)
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
