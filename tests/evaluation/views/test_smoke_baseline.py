"""The shipped smoke sweep, rendered with Mitsuba and estimated for real, against its committed baseline.

One run (session-scoped, 2 workers) serves every test here; the other runs
re-use its renders. To regenerate the baseline after an intended change
(reports/smoke-baseline/README.md)::

    nearlight baseline sweeps/smoke.yaml --out reports/smoke-baseline --workers 2 [--reason "..."]

The baseline check must hold on any machine: noise-free configurations are
compared within floors that cover another CPU's last bits, noisy ones pooled
over 10 seeds with a family-wise false-alarm rate of 5 %
(nearlight.evaluation.views.compare). The tests after it show the check has
teeth and does not cry wolf: the revert of each default of the built-in
methods, planted under the method's own name, is flagged ``worse`` where the
sweep's comments say it matters (sweeps/smoke.yaml); a planted 2 % bias of
``full`` is flagged; a re-run with 10 other seeds is not.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
import yaml

from nearlight.evaluation.engine import provenance
from nearlight.evaluation.engine.run import run_sweep
from nearlight.evaluation.engine.store import read_results
from nearlight.evaluation.engine.sweep import load_sweep
from nearlight.evaluation.views.baseline import read_verdict
from nearlight.evaluation.views.compare import compare_dirs, compare_frames

ROOT = Path(__file__).resolve().parents[3]
SMOKE = ROOT / "sweeps" / "smoke.yaml"
BASELINE = ROOT / "reports" / "smoke-baseline"

pytestmark = pytest.mark.render

#: Each default's revert: (the method label it replaces, the method entry planted under that label, and the
#: (configuration label, metric) whose check must say ``worse``: where sweeps/smoke.yaml says it matters).
REVERTS = {
    "full noise=none": ("full", {"method": "full", "options": {"noise": "none"}},
                        ("dark ggx sphere", "lamp_position_error_pct")),
    "full censoring off": ("full", {"method": "nearlight.evaluation.planted:without_censoring"},
                           ("dark ggx sphere", "lamp_position_error_pct")),
    "full lobe=torrance_sparrow": ("full", {"method": "full", "options": {"lobe": "torrance_sparrow"}},
                                   ("ward board", "lamp_position_error_pct")),
    "full separation=fit": ("full", {"method": "full", "options": {"separation": "fit"}},
                            ("ward board", "lamp_position_error_pct")),
    "full lamps=1": ("full (lamps=auto)", {"method": "full", "options": {"lamps": 1}},
                     ("two lamps", "lamp_position_error_pct")),
    "paper (corrected) origin=peak": ("paper (corrected)", {"method": "paper", "options": {"origin": "peak",
                                                                                           "am": "bounded"}},
                                      ("ts board", "lamp_position_error_pct")),
    "paper (corrected) am=printed": ("paper (corrected)", {"method": "paper", "options": {"origin": "model",
                                                                                          "am": "printed"}},
                                     ("ts board", "lamp_position_error_pct")),
}  # fmt: skip
#: A planted 2 % bias of ``full`` (its lamp moved 2 % further along the ray), run beside the reverts.
BIAS = "full 2 % further"
PLANTED = {"method": "nearlight.evaluation.planted:further_along_ray", "options": {"base": "full", "fraction": 0.02}}


def _crashes(df: pd.DataFrame) -> list[str]:
    """Errors of rows other than a method's own one-line refusal (``estimate: UserError: ...``, e.g. paper-init
    on two separate highlights): a crash, which must not pass for a verdict."""
    errors = df.loc[df["status"] == "error", "error"]
    return errors[~errors.str.startswith("estimate: UserError: ")].tolist()


def _variant(**changes) -> dict:
    """The smoke sweep file's content with some keys changed (its scene is inline)."""
    return yaml.safe_load(SMOKE.read_text()) | changes


def _run(doc: dict, out: Path, renders: Path) -> pd.DataFrame:
    """Run a variant of the smoke sweep into ``out``, re-using the session run's renders; its rows."""
    run_sweep(load_sweep(doc), out, workers=2, progress=False, cache_dir=renders)
    return read_results(out)[0]


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("smoke") / "run"
    summary = run_sweep(load_sweep(SMOKE), out, workers=2, progress=False)
    return out, summary


@pytest.fixture(scope="session")
def baseline_rows():
    return read_results(BASELINE)[0]


@pytest.fixture(scope="session")
def smoke_rows(smoke_run):
    return read_results(smoke_run[0])[0]


def _planted_checks(smoke: pd.DataFrame, planted: pd.DataFrame, base: pd.DataFrame) -> list:
    """The smoke run with one method's rows replaced by ``planted`` (already under its name), checked as the whole
    run is (the Šidák family of every method's checks)."""
    label = planted["method"].iloc[0]
    new = pd.concat([smoke[smoke["method"] != label], planted], ignore_index=True)
    return compare_frames(new, base, axes=["set", "noise"], intervals=False)


@pytest.fixture(scope="session")
def reverted_rows(smoke_run, tmp_path_factory):
    """Every revert's rows and the planted bias's from one run (each under its own name, so one sweep holds all)."""
    methods = [{"name": name, **entry} for name, (_, entry, _) in REVERTS.items()] + [{"name": BIAS, **PLANTED}]
    out = tmp_path_factory.mktemp("reverts") / "run"
    return _run(_variant(methods=methods), out, smoke_run[0] / "renders")


def test_smoke_sweep_completes_and_reuses_renders(smoke_run, smoke_rows):
    s = smoke_run[1]
    # 4 configurations x 6 methods x (noise-free: 1 seed + camera noise: 10 seeds); all re-use the 4 renders
    assert (s.tasks, s.ran, s.rendered, s.reused, s.complete) == (264, 264, 4, 260, True)
    df = smoke_rows
    assert not _crashes(df)
    # `full` on the noise-free one-lamp renders: measured 0.0008-0.022 % of the lamp's distance at 64x48 with
    # 4 spp (the baseline); 0.1 % allows 4 times the worst, still 20 times below what the 2 % bias test plants
    full = df[(df["method"] == "full") & (df["noise"] == "none") & (df["set"] != "two lamps")]
    assert len(full) == 3 and (full["lamp_position_error_pct"] < 0.1).all(), full["lamp_position_error_pct"].tolist()
    # lamps=auto finds both lamps of the two-lamp board, each within 0.1 % (measured 0.0002 %)
    two = df[(df["method"] == "full (lamps=auto)") & (df["set"] == "two lamps") & (df["noise"] == "none")]
    assert two[["n_lamps_found", "lamps_missed", "lamps_extra"]].values.tolist() == [[2, 0, 0]]
    assert (two["lamp_position_error_pct"] < 0.1).all()


def test_smoke_sweep_matches_the_committed_baseline(smoke_run):
    checks, lines = compare_dirs(smoke_run[0], BASELINE)
    assert not any(c.regression for c in checks), "\n".join(lines)
    # every noisy unit reached a verdict (10 seeds a side), none is merely inconclusive
    assert not any(c.verdict == "inconclusive" for c in checks), "\n".join(lines)
    assert not any(line.startswith("warning:") for line in lines), "\n".join(lines)


def test_baseline_has_the_verdict_of_its_regeneration():
    # `nearlight baseline` writes the verdict and the provenance together; the freshness test
    # (tests/test_reports_fresh.py) holds the provenance to this checkout's code, so this is the
    # verdict of a regeneration with today's code
    verdict = read_verdict(BASELINE)
    parts = json.loads((BASELINE / provenance.FILE).read_text())["parts"]
    assert set(parts) == {"results", "report", "verdict"}, sorted(parts)
    assert verdict["code_version"] == parts["results"]["code_version"] == parts["verdict"]["code_version"]
    if verdict["counts"]["worse"] or verdict["counts"]["missing"]:
        assert verdict["reason"], f"{BASELINE}/verdict.json: worse checks were accepted without a reason"
    assert (BASELINE / "verdict.md").is_file()


@pytest.mark.parametrize("revert", REVERTS, ids=str)
def test_revert_of_a_default_is_flagged_worse(revert, smoke_rows, baseline_rows, reverted_rows):
    label, _, (config, metric) = REVERTS[revert]
    planted = reverted_rows[reverted_rows["method"] == revert].assign(method=label)
    # a revert is a method that answers worse (or refuses, or is refused by the sanity rules), never one that crashes
    assert not _crashes(planted)
    checks = _planted_checks(smoke_rows, planted, baseline_rows)
    worse = {(c.method, c.config["set"], c.metric) for c in checks if c.regression}
    assert (label, config, metric) in worse, "\n".join(c.line() for c in checks if c.method == label)
    assert {m for m, _, _ in worse} == {label}, sorted(worse)  # the other methods are the smoke run's own


def test_planted_two_percent_bias_of_full_is_flagged(smoke_rows, baseline_rows, reverted_rows):
    planted = reverted_rows[reverted_rows["method"] == BIAS].assign(method="full")
    # every task answered: the verdict is the bias's, not failures' (the failure count is a check of its own)
    keys = ["set", "noise", "seed"]
    both = planted.merge(smoke_rows[smoke_rows["method"] == "full"], on=keys, suffixes=("", "_full"))
    assert len(both) == len(planted) and (both["status"] == both["status_full"]).all()
    checks = _planted_checks(smoke_rows, planted, baseline_rows)
    flagged = {(c.method, c.kind) for c in checks if c.regression}
    # both kinds of unit catch it: noise-free by value, noisy pooled over the seeds; the other methods are untouched
    assert flagged == {("full", "exact"), ("full", "pooled")}, "\n".join(c.line() for c in checks if c.regression)


def test_rerun_with_other_seeds_is_not_flagged(smoke_run, tmp_path):
    _run(_variant(seeds=list(range(100, 110))), tmp_path / "shifted", smoke_run[0] / "renders")
    checks, lines = compare_dirs(tmp_path / "shifted", BASELINE)
    assert not any(c.regression for c in checks), "\n".join(lines)
