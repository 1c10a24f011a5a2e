"""`nearlight compare` of two scorecards, paired case by case (analytic renderer: no Mitsuba).

A 48-case suite (3 lamp distances x 2 cameras x 8 seeds, 32x24): the same suite "built on another machine"
(every pixel moved by one ulp) compares `same`; a planted 2 % lamp bias on a quarter of the cases is `worse`;
one case that flips is not; failures are counted pair by pair; a baseline case without a new row is
`missing`; a case id whose categories disagree is a one-line error.

Why 48 cases: the paired checks of one method are 6 groups (all cases, 3 distances, 2 cameras) x 8 (failures
and 7 metrics), so the Šidák level at alpha 0.05 is 1 − 0.95^(1/48) = 1.07e-3. A regression of a quarter of
the cases (12) that moves each of them the same way has the one-sided Wilcoxon p 2^-12 = 2.4e-4 below it;
8 cases (a quarter of 32) could not (2^-8 = 3.9e-3).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from nearlight.capture import read_capture, write_capture
from nearlight.cli import main
from nearlight.errors import UserError
from nearlight.evaluation.engine.store import read_results
from nearlight.evaluation.planted import further_along_ray_every
from nearlight.evaluation.suites.suite import MANIFEST, case_record, read_manifest
from nearlight.evaluation.views.compare import _continuous_cases, COMPARED, compare_scores, sidak_level, unpaired_cases
from nearlight.files.atomic import write_json
from nearlight.generator.analytic import analytic_capture

from .test_build import pinned_suite_file

#: Cameras quiet enough that `full`'s own lamp error (0.1-0.5 % of the distance) is well below the planted
#: 2 %: with a 12-bit camera of full well 20000 its error is ~1.5 % along the ray, and moving the lamp 2 %
#: further shrinks the error of the cases it had too close (measured: 4 of 12 moved cases got better).
SUITE = {
    "name": "paired-v1",
    "version": 1,
    "renderer": "analytic",
    "scene": {"width": 32, "height": 24},
    "axes": {
        "lamp_distance": [0.3, 0.5, 0.8],
        "noise": {"sensor": {"full_well": 400000, "read_noise": 1.0}, "dim": {"full_well": 100000, "read_noise": 2.0}},
    },
    "seeds": 8,
    "categories": ["lamp_distance", "noise"],
}
N_CASES = 48
#: The method's paired checks: (all + 3 distances + 2 cameras) x (failures + the compared metrics).
N_CHECKS = 6 * (1 + len(COMPARED))
PLANTED = "nearlight.evaluation.planted:further_along_ray_every"


@pytest.fixture(scope="module")
def builds(tmp_path_factory):
    """The suite built, and a copy with every pixel of every layer moved one ulp up or down (seeded signs)
    whose manifest records its files as a second build would (`case_record`: sha256 and digests): what the
    same suite built on another CPU looks like, Dr.Jit renders differing in their last bits."""
    root = tmp_path_factory.mktemp("paired")
    built, moved = root / "built", root / "ulp"
    assert main(["suite", "build", str(pinned_suite_file(root, SUITE)), "--out", str(built), "--quiet", "--no-cache"]) == 0
    shutil.copytree(built, moved)
    rng = np.random.default_rng(0)

    def ulp(a):
        if a is None:
            return None
        a = np.asarray(a, np.float32)
        return np.nextafter(a, np.where(rng.random(a.shape) < 0.5, -np.inf, np.inf).astype(np.float32))

    manifest = read_manifest(moved)
    for case in manifest["cases"]:
        folder = moved / case["path"]
        for sub in ("input", "truth"):
            c = read_capture(folder / sub)
            c = c.replace(P=ulp(c.P), N=ulp(c.N), stack=ulp(c.stack), specular=ulp(c.specular),
                          diffuse=ulp(c.diffuse), extra={k: ulp(v) for k, v in c.extra.items()})  # fmt: skip
            write_capture(c, folder / sub, overwrite=True)
        case.update(case_record(folder))
    write_json(moved / MANIFEST, manifest)
    return built, moved


@pytest.fixture(scope="module")
def scores(builds, tmp_path_factory):
    """``scores(build, method, *set_options)``: the score folder of a method on the suite or its moved copy
    (scored once per module)."""
    root, done = tmp_path_factory.mktemp("scores"), {}
    suite = dict(zip(("built", "ulp"), builds))

    def get(build, method, *options):
        key = (build, method, *options)
        if key not in done:
            out = root / f"{len(done)}"
            sets = [x for o in options for x in ("--set", o)]
            assert main(["score", str(suite[build]), "--method", method, "--out", str(out), "--quiet", *sets]) == 0
            done[key] = out
        return done[key]

    return get


def _compare(capsys, new, base, *extra):
    capsys.readouterr()
    code = main(["compare", str(new), str(base), *extra])
    return code, capsys.readouterr().out.splitlines()


def _rows(folder):
    return read_results(folder)[0].set_index("task_id").sort_index()


def test_moved_build_passes_suite_verify_against_the_first(builds, capsys):
    built, moved = builds
    assert main(["suite", "verify", str(moved), "--against", str(built / MANIFEST)]) == 0
    assert f"0 case(s) identical, {N_CASES} within the tolerance" in capsys.readouterr().out


@pytest.mark.parametrize("method", ["full", "paper-init"])
def test_a_build_moved_by_one_ulp_compares_same(scores, capsys, method):
    """Every metric of every case moves (the renders differ), every paired check says `same`."""
    new, base = scores("ulp", method), scores("built", method)
    moved = (_rows(new)[list(COMPARED)] != _rows(base)[list(COMPARED)]).any(axis=1)
    assert moved.sum() >= N_CASES // 2  # not bit-identical: the comparison has something to absorb
    code, out = _compare(capsys, new, base)
    assert code == 0, "\n".join(out)
    assert out[-1].endswith(f"{N_CHECKS} checks ({N_CHECKS} paired case by case at family-wise alpha 0.05, "
                            f"tolerance 0.05): 0 worse, 0 missing, 0 better, {N_CHECKS} same, 0 inconclusive")  # fmt: skip
    assert sum(line.lstrip().startswith("same ") and "(paired, n=" in line for line in out) == N_CHECKS


def test_a_planted_bias_on_a_quarter_of_the_cases_is_worse(scores, capsys, tmp_path):
    """2 % further along the ray on the seeds 0 and 4 (12 of 48 cases): the lamp metrics over all cases are
    worse, with n, the interval and p in the line and the JSON; the reverse comparison says better."""
    planted, base = scores("built", PLANTED), scores("built", "full")
    new_rows, base_rows = _rows(planted), _rows(base)
    moved = new_rows["lamp_position_error_m"] != base_rows["lamp_position_error_m"]
    assert moved.sum() == N_CASES // 4 and set(new_rows.loc[moved, "seed"]) == {0, 4}
    code, out = _compare(capsys, planted, base, "--json", str(tmp_path / "c.json"))
    assert code == 1
    assert f"method {PLANTED!r} (new) against 'full' (baseline)" in out[0]
    worse = [line for line in out if line.lstrip().startswith("worse ")]
    for metric in ("lamp_position_error_m", "lamp_position_error_pct", "distance_error_m"):
        line = next(line for line in worse if f"full [all] {metric}:" in line)
        assert "p=0.00024" in line and line.endswith("(paired, n=48)"), line
    doc = json.loads((tmp_path / "c.json").read_text())
    level = sidak_level(0.05, N_CHECKS)
    check = next(c for c in doc["checks"] if c["metric"] == "lamp_position_error_pct" and c["config"] == {})
    assert (check["kind"], check["n_base"], check["n_new"], check["verdict"]) == ("paired", 48, 48, "worse")
    assert check["p_value"] == pytest.approx(2.0**-12) and check["p_value"] < level
    assert 0 < check["low"] < check["new"] - check["base"] < check["high"]
    # what the bias does not touch stays the same
    assert {c["verdict"] for c in doc["checks"] if c["metric"] in ("sigma_rel_error", "ks_rel_error", "failures")} == {"same"}
    # the mirror image: the real method against the planted one is better, and nothing is worse
    code, out = _compare(capsys, base, planted)
    assert code == 0
    assert any(line.lstrip().startswith("better ") and f"{PLANTED} [all] lamp_position_error_pct" in line
               for line in out)  # fmt: skip


def test_the_planted_selector_needs_a_camera_noise_seed():
    with pytest.raises(ValueError, match="records no camera-noise seed"):
        further_along_ray_every(analytic_capture(width=16, height=12))


def _full_rows(scores):
    return read_results(scores("built", "full"))[0]


def test_one_case_flip_is_not_worse(scores):
    """One case's lamp errors 20 times the mean (a brightest pixel that flips), the 47 others identical: the
    mean moves by far more than the tolerance, but one moved case cannot be significant (p = 1/2)."""
    base = _full_rows(scores)
    new = base.copy()
    lamp = ["lamp_position_error_m", "lamp_position_error_pct", "distance_error_m"]
    new.loc[0, lamp] = 20.0 * base[lamp].mean()
    checks = compare_scores(new, base, categories=["lamp_distance", "noise"])
    assert len(checks) == N_CHECKS and not any(c.regression for c in checks)
    for c in (c for c in checks if c.metric in lamp):
        assert c.verdict == "same" and c.kind == "paired"
        if c.config in ({}, {"lamp_distance": base.loc[0, "lamp_distance"]}, {"noise": base.loc[0, "noise"]}):
            assert c.new > 1.05 * c.base and c.p_value == 0.5, c.line()  # tested: the change is beyond the tolerance
    assert {c.n_base for c in checks if c.config == {}} == {N_CASES}


def test_failures_are_counted_pair_by_pair(scores):
    """McNemar: 12 cases that fail only in the new run are worse (p = 2^-12); one is not (p = 1/2); 12 that
    recover are better; as many failing as recovering is the same."""
    base = _full_rows(scores)

    def failing(df, rows):
        df = df.copy()
        df.loc[rows, "status"] = "failed"
        df.loc[rows, list(COMPARED)] = np.nan
        return df

    def verdict(new, old):
        return next(c for c in compare_scores(new, old, categories=["noise"]) if c.metric == "failures" and not c.config)

    quarter = base.index[base["seed"] % 4 == 0]
    c = verdict(failing(base, quarter), base)
    assert (c.verdict, c.base, c.new, c.p_value) == ("worse", 0, 12, pytest.approx(2.0**-12))
    assert verdict(failing(base, base.index[:1]), base).p_value == 0.5
    assert verdict(failing(base, base.index[:1]), base).verdict == "same"
    assert verdict(base, failing(base, quarter)).verdict == "better"
    assert verdict(failing(base, base.index[:6]), failing(base, base.index[6:12])).verdict == "same"


def test_missing_case_and_new_cases(scores):
    """A baseline case the new run lacks is a `missing` regression naming its categories and seed; a new
    case the baseline lacks is counted, not checked; fewer than 5 paired cases is inconclusive."""
    base = _full_rows(scores)
    checks = compare_scores(base.iloc[1:], base, categories=["lamp_distance", "noise"])
    missing = [c for c in checks if c.verdict == "missing"]
    assert len(missing) == 1 and missing[0].regression
    assert missing[0].config == {k: base.loc[0, k] for k in ("lamp_distance", "noise", "seed")}
    assert unpaired_cases(base, base.iloc[1:]) == 1 and unpaired_cases(base, base) == 0
    few = compare_scores(base.iloc[:4], base.iloc[:4], categories=["noise"])
    assert {c.verdict for c in few} == {"inconclusive"} and len(few) == 1 + len(COMPARED)


def test_a_case_whose_categories_disagree_is_a_one_line_error(scores, tmp_path, capsys):
    base = scores("built", "full")
    copy = tmp_path / "edited"
    shutil.copytree(base, copy)
    df = pd.read_parquet(copy / "results.parquet")
    df.loc[3, "noise"] = "other"
    df.to_parquet(copy / "results.parquet")
    capsys.readouterr()
    assert main(["compare", str(copy), str(base)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"case {df.loc[3, 'task_id']}: noise is" in err and "not the same case" in err
    with pytest.raises(UserError, match="seed is 0 in the baseline and 9"):
        rows = _full_rows(scores)
        compare_scores(rows.assign(seed=np.where(rows["seed"] == 0, 9, rows["seed"])), rows)


def test_a_continuous_method_is_also_checked_case_by_case(scores):
    """`full` cannot flip: the same one-case jump the paired checks let through is worse case by case (its lamp
    metrics, that case only); renamed a brightest-pixel method (`paper-init`) it gets no case checks."""
    base = _full_rows(scores)
    new = base.copy()
    lamp = ["lamp_position_error_m", "lamp_position_error_pct", "distance_error_m"]
    new.loc[0, lamp] = 20.0 * base[lamp].mean()
    checks, n = _continuous_cases(new, base, ["lamp_distance", "noise"], {})
    assert N_CASES < n <= N_CASES * (1 + len(COMPARED))  # each case: failures + each metric it has
    assert sorted(c.metric for c in checks) == sorted(lamp) and {c.verdict for c in checks} == {"worse"}
    assert {c.config["seed"] for c in checks} == {base.loc[0, "seed"]}
    flips = [df.assign(method="paper-init") for df in (new, base)]
    assert _continuous_cases(*flips, ["lamp_distance", "noise"], {}) == ([], 0)
