"""The shipped smoke sweep, rendered with Mitsuba and estimated for real, against its committed baseline.

One run (session-scoped, 2 workers) serves every test here. To refresh the
baseline after an intended change::

    nearlight sweep sweeps/smoke.yaml --out reports/smoke-baseline --workers 2
"""

from __future__ import annotations

from pathlib import Path

import pytest

from nearlight.evaluation.compare import compare_dirs
from nearlight.evaluation.engine import run_sweep
from nearlight.evaluation.store import read_results
from nearlight.evaluation.sweep import load_sweep

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "sweeps" / "smoke.yaml"
BASELINE = ROOT / "reports" / "smoke-baseline"

pytestmark = pytest.mark.render


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("smoke") / "run"
    summary = run_sweep(load_sweep(SMOKE), out, workers=2, progress=False)
    return out, summary


def test_smoke_sweep_completes_and_reuses_renders(smoke_run):
    out, s = smoke_run
    # 2 lamp distances x 2 noise levels x 1 seed x 2 methods; noise and method re-use the 2 renders
    assert (s.tasks, s.ran, s.rendered, s.reused, s.complete) == (8, 8, 2, 6, True)
    df, _ = read_results(out)
    assert (df["status"] == "ok").all(), df.loc[df["status"] != "ok", "error"].tolist()
    # `full` on a noise-free 64x48 render: the estimator's issue asks for the lamp within 0.1 % of its
    # distance at full resolution; at 64x48 with 4 spp we allow 2 % (pixel quantisation of the highlight)
    full = df[(df["method"] == "full") & (df["noise"] == "none")]
    assert (full["lamp_position_error_pct"] < 2.0).all(), full["lamp_position_error_pct"].tolist()


def test_smoke_sweep_matches_the_committed_baseline(smoke_run):
    worse, lines = compare_dirs(smoke_run[0], BASELINE)
    assert worse == [], "\n".join(lines)
