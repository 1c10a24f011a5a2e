"""The sweep report's and the scorecard's covariance tables, end to end on analytic sweeps with fake methods whose
stated covariance is right, ten times too small, or absent (they test the scoring, not estimation)."""

from __future__ import annotations

import sys
import textwrap

import pandas as pd
import pytest
import yaml

from nearlight.evaluation.engine.run import run_sweep
from nearlight.evaluation.engine.store import read_results
from nearlight.evaluation.engine.sweep import load_sweep
from nearlight.evaluation.scoring.calibration import MAHALANOBIS_COLUMN
from nearlight.evaluation.suites.scorecard import scorecard, scorecard_markdown
from nearlight.evaluation.views.report import write_report

# Each fake is the truth moved by (1, 1, 1) mm. `honest` states 1 mm on each axis (d² = 3 exactly: inside the
# 95 % ellipsoid, d²/3 = 1); `proud` states 0.1 mm (d² = 300, outside, d²/3 = 100); `silent` states none.
FAKES = '''
import numpy as np
from nearlight.estimator import Estimate

def _off(capture, sd):
    t = capture.truth
    ks = np.asarray(t["bsdf"]["ks"]) * np.asarray(t["lamp_intensity"]) / 2
    cov = None if sd is None else np.diag([sd**2, sd**2, sd**2, 1e-6])
    return Estimate(method="off", lamp_position=np.asarray(t["lamp_position"]) + 0.001, ks=ks,
                    sigma=t["bsdf"]["sigma"], covariance=cov)

def honest(capture):
    return _off(capture, 1e-3)

def proud(capture):
    return _off(capture, 1e-4)

def silent(capture):
    return _off(capture, None)
'''


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("fakes_covariance")
    (d / "nl_fakes_covariance.py").write_text(textwrap.dedent(FAKES))
    sys.path.insert(0, str(d))
    doc = {"name": "covariance", "renderer": "analytic",
           "scene": {"width": 48, "height": 36, "lamp_position": [0.05, 0.15, 0.35]},
           "axes": {"object": ["board", "sphere"]}, "seeds": 1,
           "methods": [f"nl_fakes_covariance:{m}" for m in ("honest", "proud", "silent")]}
    path = d / "s.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = d / "run"
    run_sweep(load_sweep(path), out, workers=1, progress=False)
    yield out
    sys.path.remove(str(d))


def test_rows_hold_the_distance(run):
    df, _ = read_results(run)
    d2 = {m.split(":")[1]: g[MAHALANOBIS_COLUMN].tolist() for m, g in df.groupby("method")}
    assert d2["honest"] == pytest.approx([3.0, 3.0], rel=1e-9)  # float64 of 1 mm over 1 mm
    assert d2["proud"] == pytest.approx([300.0, 300.0], rel=1e-9)
    assert all(v != v for v in d2["silent"])  # NaN: no covariance


def test_the_report_says_which_ellipsoid_is_right(run):
    folder = write_report(run)
    md = (folder / "summary.md").read_text()
    assert "## Covariance: is the stated lamp ellipsoid right?" in md and "### Covariance by object" in md
    t = pd.read_csv(folder / "covariance.csv")
    overall = t[t["axis"] == "all"].set_index("method")
    assert overall.loc["nl_fakes_covariance:honest", "inside_95"].startswith("1.000 [")
    assert overall.loc["nl_fakes_covariance:honest", "mean_d2_over_3"].startswith("1 [1, 1]")
    assert overall.loc["nl_fakes_covariance:proud", "inside_95"].startswith("0.000 [")
    assert overall.loc["nl_fakes_covariance:proud", "mean_d2_over_3"].startswith("100 [")
    assert overall.loc["nl_fakes_covariance:silent", "inside_95"] == "not given"
    by = t[t["axis"] == "object"]
    assert set(by["method"]) == {"nl_fakes_covariance:honest", "nl_fakes_covariance:proud"}  # given ones only
    assert len(by) == 4


def test_the_scorecard_has_the_table_and_not_given(run):
    df, _ = read_results(run)
    manifest = {"suite": "s", "version": 1, "cases_hash": "h"}
    for method, cell in (("honest", "1.000 ["), ("proud", "0.000 ["), ("silent", "not given")):
        rows = df[df["method"] == f"nl_fakes_covariance:{method}"]
        card = scorecard(rows, manifest, label=method, categories=["object"])
        md = scorecard_markdown(card)
        assert "## Covariance: the stated lamp ellipsoid" in md
        line = md.split("## Covariance")[1].split("| all | all |")[1].splitlines()[0]
        assert cell in line, line
        assert card["groups"][0]["covariance"]["n"] == (0 if method == "silent" else 2)
