"""Global sensitivity analysis (``nearlight.evaluation.gsa.study``): SALib's design and analysis recover known indices.

Goldens: the Ishigami function ``sin x1 + a sin² x2 + b x3⁴ sin x1`` (a = 7, b = 0.1,
x ~ U(-π, π)³) has closed-form Sobol' indices (Ishigami & Homma 1990; Saltelli et al.,
*Global Sensitivity Analysis: The Primer*, 2008, §4.4): S1 = (0.3139, 0.4424, 0),
ST = (0.5576, 0.4424, 0.2437). A linear model ``Σ c_i u_i`` of independent uniform
inputs (u_i the input scaled to [0, 1]) has S1_i = ST_i = c_i² / Σ c_j², and every
Morris elementary effect on the unit hypercube is exactly c_i (μ* = |c_i|, σ = 0).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from nearlight.cli import main
from nearlight.evaluation.gsa.study import Design, Input, analyse, camera_position, load_study, sample

PI = math.pi
ISHIGAMI_S1 = np.array([0.3139, 0.4424, 0.0])
ISHIGAMI_ST = np.array([0.5576, 0.4424, 0.2437])


def ishigami(X: np.ndarray, a: float = 7.0, b: float = 0.1) -> np.ndarray:
    return np.sin(X[:, 0]) + a * np.sin(X[:, 1]) ** 2 + b * X[:, 2] ** 4 * np.sin(X[:, 0])


ISHIGAMI_INPUTS = [Input(f"x{i}", "uniform", (-PI, PI)) for i in (1, 2, 3)]


def test_saltelli_sample_and_sobol_analysis_recover_the_ishigami_indices_within_their_intervals():
    design = Design("sobol", "sobol", n=1024, seed=7)
    X = sample(ISHIGAMI_INPUTS, design)
    assert X.shape == (1024 * 5, 3)  # N (k + 2) without second order
    rows, blocks = analyse(ISHIGAMI_INPUTS, design, X, ishigami(X))
    assert blocks == 1024
    s1 = np.array([r["S1"] for r in rows])
    st = np.array([r["ST"] for r in rows])
    s1c = np.array([r["S1_conf"] for r in rows])
    stc = np.array([r["ST_conf"] for r in rows])
    # the golden inside the 95 % percentile bootstrap interval, and the intervals narrow enough to separate the
    # inputs (at N = 1024 the half-widths are ~0.03-0.06; 0.1 keeps the check from passing on vague intervals)
    assert _inside(rows, "S1", ISHIGAMI_S1) and _inside(rows, "ST", ISHIGAMI_ST), rows
    assert np.all(s1 <= [r["S1_hi"] for r in rows]) and np.all(st >= [r["ST_lo"] for r in rows])
    assert np.all(s1c < 0.1) and np.all(stc < 0.1)


def _inside(rows: list[dict], key: str, golden) -> bool:
    """Whether every golden value lies in its index's percentile interval."""
    return all(r[f"{key}_lo"] <= g <= r[f"{key}_hi"] for r, g in zip(rows, golden))


def test_at_n_4096_every_ishigami_index_is_resolved_to_a_half_width_of_005():
    """Issue 37's bar for the project's Sobol' path: at N = 4096 every S1 and ST holds its closed form within its
    95 % interval, and every half-width is at most 0.05 (SALib's bootstrap half-widths fall as 1/sqrt(N): about
    0.013-0.042 here, seed 11, seeded bootstrap; the bar is what the committed study's resolution rule asks of it)."""
    design = Design("sobol", "sobol", n=4096, seed=11)
    X = sample(ISHIGAMI_INPUTS, design)
    rows, blocks = analyse(ISHIGAMI_INPUTS, design, X, ishigami(X))
    assert blocks == 4096
    for key, golden in (("S1", ISHIGAMI_S1), ("ST", ISHIGAMI_ST)):
        conf = np.array([r[f"{key}_conf"] for r in rows])
        assert _inside(rows, key, golden), (key, rows)
        assert np.all(conf <= 0.05), (key, conf)


def test_an_input_the_model_never_reads_is_within_the_chance_floor_and_the_floor_is_above_zero():
    """Issue 37's floor: Ishigami with a fourth input it ignores, at N = 1024. The ignored input gets S1 = ST = 0
    from SALib's estimators (f(A_B^4) = f(A)), so its interval is [0, 0]; the floor, the dummy's index by the
    Khorashadi Zadeh estimators (evaluation/gsa/sobol.py), is what chance gives at this N: measured 0.065 (ST) and
    6.6e-5 (S1: that estimator's noise falls as N^-1.5) here, so bounded below by 0.01 and 1e-7, and above by 0.1. x1 and x2 stand
    above it; x3 has S1 = 0 (its effect is all interaction) and is not distinguishable on S1 alone."""
    from nearlight.evaluation.gsa.sobol import distinguishable

    inputs = [*ISHIGAMI_INPUTS, Input("ignored", "uniform", (0.0, 1.0))]
    design = Design("sobol", "sobol", n=1024, seed=7)
    X = sample(inputs, design)
    rows, _ = analyse(inputs, design, X, ishigami(X))
    ignored = rows[3]
    assert ignored["S1"] == ignored["ST"] == ignored["ST_lo"] == ignored["ST_hi"] == 0.0
    floor = ignored["ST_floor"]
    assert 0.01 < floor < 0.1 and 1e-7 < ignored["S1_floor"] < 0.1, ignored
    assert all(r["ST_floor"] == floor for r in rows)  # one floor per method and metric
    assert [distinguishable(r["ST_lo"], r["ST_floor"]) for r in rows] == [True, True, True, False]
    assert [distinguishable(r["S1_lo"], r["S1_floor"]) for r in rows] == [True, True, False, False]


def test_the_floor_shrinks_as_one_over_root_n():
    """The dummy's floor is sampling noise: 16 times the base samples, about a quarter of the floor (measured
    ratio 0.26 at N = 256 -> 4096 for Ishigami, seed 7: 0.131 -> 0.034; held to 0.15-0.4)."""
    inputs = [*ISHIGAMI_INPUTS, Input("ignored", "uniform", (0.0, 1.0))]
    floors = []
    for n in (256, 4096):
        design = Design("sobol", "sobol", n=n, seed=7)
        X = sample(inputs, design)
        floors.append(analyse(inputs, design, X, ishigami(X))[0][0]["ST_floor"])
    assert 0.15 < floors[1] / floors[0] < 0.4, floors


def test_a_failed_output_drops_its_saltelli_block_and_the_rest_still_recover_the_indices():
    design = Design("sobol", "sobol", n=1024, seed=7)
    X = sample(ISHIGAMI_INPUTS, design)
    Y = ishigami(X)
    Y[[3, 17, 400]] = np.nan  # rows of blocks 0, 3 and 80 (5 rows a block)
    rows, blocks = analyse(ISHIGAMI_INPUTS, design, X, Y)
    assert blocks == 1021
    assert _inside(rows, "ST", ISHIGAMI_ST), rows


@pytest.mark.parametrize("dist, bounds", [("uniform", (2.0, 4.0)), ("loguniform", (0.01, 1.0))])
def test_linear_model_sobol_indices_are_the_squared_coefficients_shares(dist, bounds):
    c = np.array([4.0, 2.0, 1.0])
    inputs = [Input(f"u{i}", dist, bounds) for i in range(3)]
    design = Design("sobol", "sobol", n=512, seed=3)
    X = sample(inputs, design)
    lo, hi = bounds
    U = (np.log(X / lo) / np.log(hi / lo)) if dist == "loguniform" else (X - lo) / (hi - lo)  # uniform on [0, 1]
    rows, _ = analyse(inputs, design, X, U @ c)
    want = c**2 / np.sum(c**2)  # 16/21, 4/21, 1/21
    assert _inside(rows, "S1", want) and _inside(rows, "ST", want), (rows, want)


def test_morris_elementary_effects_of_a_linear_model_are_its_coefficients():
    c = np.array([4.0, -2.0, 1.0, 0.0])
    inputs = [Input(f"u{i}", "uniform", (10.0, 20.0)) for i in range(4)]
    design = Design("morris", "morris", n=20, seed=5, levels=4)
    X = sample(inputs, design)
    assert X.shape == (20 * 5, 4)  # r (k + 1)
    rows, blocks = analyse(inputs, design, X, ((X - 10.0) / 10.0) @ c)
    assert blocks == 20
    # exact up to rounding: each effect is (Y(x + Δ e_i) - Y(x)) / Δ on the unit cube = c_i
    np.testing.assert_allclose([r["mu"] for r in rows], c, atol=1e-9)
    np.testing.assert_allclose([r["mu_star"] for r in rows], np.abs(c), atol=1e-9)
    np.testing.assert_allclose([r["sigma"] for r in rows], 0.0, atol=1e-9)


def test_a_categorical_input_picks_each_label_with_equal_probability():
    inp = Input("bsdf", "labels", (0.0, 2.0), [("torrance_sparrow", "torrance_sparrow"), ("ward", "ward")])
    X = sample([inp, Input("x", "uniform", (0.0, 1.0))], Design("s", "sobol", n=256, seed=1))
    picked = [inp.value(x) for x in X[:, 0]]
    assert 0.45 < picked.count("ward") / len(picked) < 0.55  # a scrambled Sobol' sequence: ~half exactly
    assert inp.value(2.0) == "ward"  # the closed upper end maps to the last label


# --------------------------------------------------------------------------- through the sweep engine and the CLI

#: A plug-in "estimator" whose lamp-position error is a known linear model of the scene it is shown:
#: (1 + 4 u_d + 2 u_r + 1 [Ward]) mm, u_d and u_r the lamp distance and the roughness scaled to [0, 1]
#: (read from the capture's truth), so the study's indices are closed-form (module docstring).
PLUGIN = '''
import numpy as np
from nearlight.estimator import Estimate, render_specular
from nearlight.estimator.observation import observation_of


def fit(capture):
    truth = capture.truth
    lamp = np.asarray(truth["lamp_position"])
    bsdf = truth["bsdf"]
    ward = bsdf["model"] == "ward"
    sigma = bsdf["alpha"] / np.sqrt(2.0) if ward else bsdf["sigma"]
    u_d = (np.linalg.norm(lamp) - 0.2) / 0.4
    u_r = (sigma - 0.05) / 0.2
    error = 1e-3 * (1.0 + 4.0 * u_d + 2.0 * u_r + 1.0 * ward)  # metres: millimetres, so the estimate stays sane
    # Ks that re-synthesises the observed specular (least squares per channel), so the sanity rules pass it
    est = Estimate(method="gsa_plugin:fit", lamp_position=lamp + [error, 0.0, 0.0], ks=np.ones(3), sigma=sigma)
    unit, seen = render_specular(capture, est), observation_of(capture).specular
    est.ks = np.sum(unit * seen, axis=(0, 1)) / np.sum(unit**2, axis=(0, 1))
    return est
'''


def _study(tmp_path, monkeypatch, design):
    (tmp_path / "gsa_plugin.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    doc = {
        "name": "linear", "renderer": "analytic",
        "scene": {"width": 40, "height": 30},  # the board at the origin: lamp distance = |lamp position|; >= 10 highlight pixels
        "methods": [{"name": "model", "method": "gsa_plugin:fit"}], "crlb": False,
        "metrics": ["lamp_position_error_m"],
        "inputs": {"lamp_distance": {"low": 0.2, "high": 0.6}, "roughness": {"low": 0.05, "high": 0.25},
                   "bsdf": {"values": ["torrance_sparrow", "ward"]}},
        "designs": {"main": design},
    }  # fmt: skip
    path = tmp_path / "linear.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_a_study_through_the_engine_and_the_cli_recovers_the_sobol_indices_of_a_linear_model(tmp_path, monkeypatch, capsys):
    path = _study(tmp_path, monkeypatch, {"method": "sobol", "n": 64, "seed": 2})
    assert main(["gsa", str(path), "--out", str(tmp_path / "res"), "--quiet"]) == 0
    out, err = capsys.readouterr()
    report = tmp_path / "res" / "main" / "gsa"
    assert out == f"{report}\n"
    # 64 blocks of (A, AB_1, AB_2, AB_3, B): AB_3 takes only bsdf from B, so it is A again when the coin
    # fell the same way (32 of 64 blocks here): identical configurations run once
    assert "sobol design, n = 64: 320 samples, 288 tasks" in err and "0 failed" in err
    got = pd.read_csv(report / "indices.csv").set_index("input")
    # variances of the three terms: 4² / 12, 2² / 12 and 1² / 4 (a fair coin): shares 16/23, 4/23, 3/23
    want = pd.Series({"lamp_distance": 16 / 23, "roughness": 4 / 23, "bsdf": 3 / 23})
    for name, w in want.items():
        r = got.loc[name]
        assert r.S1_lo <= w <= r.S1_hi and r.ST_lo <= w <= r.ST_hi, (name, r.to_dict(), w)
    assert (got["blocks"] == 64).all()
    md = (report / "gsa.md").read_text()
    # at N = 64 the chance floor is 0.19 (measured): roughness (0.17) and bsdf (0.13) are real but not yet told
    # apart from chance; the report says so rather than ranking them
    assert re.search(r"\| model \| lamp_position_error_m \| lamp_distance 0\.\d+ \[0\.\d+, 0\.\d+\] \| "
                     r"roughness, bsdf \| 0\.1\d \|", md), md
    assert "## Convergence" in md and (report / "convergence.csv").is_file()
    conv = pd.read_csv(report / "convergence.csv")
    assert sorted(conv["n"].unique()) == [16, 32, 64] and len(conv) == 3 * 3
    # within either lobe family the shares are those of the two other terms: 16/20 and 4/20
    levels = pd.read_csv(report / "levels.csv")
    assert sorted(levels["level"].unique()) == ["bsdf=torrance_sparrow", "bsdf=ward"] and len(levels) == 2 * 2
    for r in levels.itertuples():
        w = {"lamp_distance": 0.8, "roughness": 0.2}[r.input]
        assert r.ST_lo <= w <= r.ST_hi, r
    assert "## Where an input's effect depends on a categorical input" in (report / "gsa.md").read_text()
    for png in ("indices_lamp_position_error_m.png", "scatter_model.png", "convergence_model.png"):
        assert (report / png).read_bytes()[:4] == b"\x89PNG"
    prov = json.loads((tmp_path / "res" / "main" / "provenance.json").read_text())
    assert set(prov["parts"]) == {"results", "gsa"}
    assert prov["parts"]["results"]["command"].startswith(f"nearlight gsa {path} --out")
    assert "evaluation/gsa/study.py" in prov["parts"]["gsa"]["code"]

    # run again: nothing runs, the same report
    assert main(["gsa", str(path), "--out", str(tmp_path / "res"), "--quiet"]) == 0
    assert "ran 0 task(s), skipped 288 already done" in capsys.readouterr().err


def test_a_morris_study_through_the_engine_gets_the_exact_elementary_effects(tmp_path, monkeypatch, capsys):
    path = _study(tmp_path, monkeypatch, {"method": "morris", "n": 6, "seed": 4, "levels": 4})
    assert main(["gsa", str(path), "--out", str(tmp_path / "res"), "--quiet"]) == 0
    got = pd.read_csv(tmp_path / "res" / "main" / "gsa" / "indices.csv").set_index("input")
    # a step of 2/3 of the range (4 levels) always flips the coin between its halves: effect 1 / (2/3) = 1.5
    np.testing.assert_allclose(got.loc[["lamp_distance", "roughness", "bsdf"], "mu_star"], [4e-3, 2e-3, 1.5e-3], rtol=1e-6)
    np.testing.assert_allclose(got["sigma"], 0.0, atol=1e-9)


@pytest.mark.parametrize(
    "change, needle",
    [
        ({"inputs": {"lamp_distance": {"low": 0.5, "high": 0.2}, "roughness": {"low": 0.1, "high": 0.2}}},
         "inputs.lamp_distance: a uniform input needs low < high"),
        ({"inputs": {"lamp_distanse": {"low": 0.2, "high": 0.5}, "roughness": {"low": 0.1, "high": 0.2}}},
         "inputs.lamp_distanse: unknown input"),
        ({"inputs": {"bsdf": {"low": 0, "high": 1}, "roughness": {"low": 0.1, "high": 0.2}}},
         "inputs.bsdf: the bsdf axis takes labels"),
        ({"inputs": {"noise.read_noise": {"low": 1, "high": 5}, "roughness": {"low": 0.1, "high": 0.2}}},
         "inputs.noise.read_noise: needs the file's noise"),
        ({"designs": {"main": {"method": "fast", "n": 4}}}, "designs.main.method:"),
        ({"designs": {"main": {"method": "sobol", "n": 100}}}, "designs.main: a sobol design needs n a power of 2"),
        ({"designs": {"main": {"method": "morris", "n": 4, "replicates": 2}}},
         "designs.main: replicates: a morris design has none"),
        ({"designs": {"main": {"method": "sobol", "n": 4, "replicates": 0}}}, "designs.main.replicates:"),
        ({"metrics": ["lamp_error"]}, "metrics: unknown metric 'lamp_error'"),
        ({"designs": {"main": {"method": "morris", "n": 4, "levels": 5}}},
         "designs.main.levels: 5 is not a multiple of the 2 labels of input bsdf"),
        ({"inputs": {"roughness": {"low": -0.1, "high": 0.2}, "lamp_distance": {"low": 0.2, "high": 0.5}}},
         "designs.main: sample 10 (lamp_distance=0.2023, roughness=-0.03323): axes.roughness: "),
        ({"axes": {"roughness": [0.1, 0.2]}}, "axes: a GSA file has `inputs` and `designs` instead of a sweep's axes"),
        ({"seeds": 0}, "seeds: expected a positive count"),  # the sweep file's own rule (one schema)
    ],
)
def test_a_bad_gsa_file_is_one_line_naming_file_and_key(tmp_path, monkeypatch, capsys, change, needle):
    path = _study(tmp_path, monkeypatch, {"method": "sobol", "n": 4})
    doc = yaml.safe_load(path.read_text())
    doc.update(change)
    path.write_text(yaml.safe_dump(doc))
    assert main(["gsa", str(path), "--out", str(tmp_path / "res")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith(f"nearlight: error: {path}: ") and needle in err, err
    assert not (tmp_path / "res").exists()


# --------------------------------------------------------------------------- the shipped study: inputs to scene keys

GLOBAL = Path(__file__).resolve().parents[3] / "sweeps" / "global.yaml"


def test_each_sample_of_the_shipped_study_sets_the_scene_keys_its_inputs_drive():
    study = load_study(GLOBAL, settings={"designs.screening.n": 2}, design="screening")
    run = study.runs["screening"]
    assert run.samples.shape == (2 * 15, 14)
    assert [m.label for m in run.sweep.methods] == ["paper-init", "paper", "full", "distant", "paper-init (model origin)",
                                                    "paper (model origin, bounded AM)"]  # fmt: skip
    names = [i.name for i in study.inputs]
    labels = {i.name: i for i in study.inputs}
    for x, ids in zip(run.samples, run.sample_tasks):
        v = dict(zip(names, x))
        task = next(t for t in run.sweep.tasks if t.task_id == ids["full"][0])
        scene = task.scene
        assert scene["object"]["type"] == labels["object"].label(v["object"])
        assert scene["material"]["model"] == labels["bsdf"].label(v["bsdf"])
        assert scene["lamp"]["radius"] == pytest.approx(v["lamp.radius"]) and scene["lamp"]["anisotropy_k"] == v["lamp.anisotropy_k"]
        nz = scene["nuisances"]
        assert (nz["camera"]["gamma"], nz["camera"]["vignetting"], nz["range"]["quantum_m"]) == pytest.approx(
            (v["nuisances.camera.gamma"], v["nuisances.camera.vignetting"], v["nuisances.range.quantum_m"]))
        assert nz["calibration"]["position_m"] == pytest.approx([v["nuisances.calibration.position_m.0"], 0.0, 0.0])
        cam = np.asarray(task.scene["camera"]["position"])  # look_at is the origin, the board's normal +z
        assert np.linalg.norm(cam) == pytest.approx(v["camera_distance"], rel=1e-9)
        assert math.degrees(math.acos(cam[2] / np.linalg.norm(cam))) == pytest.approx(v["viewing_angle"], abs=1e-9)
        assert cam[0] == pytest.approx(0.0, abs=1e-12) and cam[1] < 0  # in the base camera's plane, on its side
        assert np.linalg.norm(task.scene["lamp"]["position"]) == pytest.approx(v["lamp_distance"], rel=1e-9)
        if scene["material"]["model"] == "torrance_sparrow":  # Ward's alpha is sqrt(2) sigma (convert_bsdf)
            assert scene["material"]["sigma"] == pytest.approx(v["roughness"], rel=1e-12)
        else:
            assert scene["material"]["alpha"] == pytest.approx(math.sqrt(2) * v["roughness"], rel=1e-12)
        assert task.noise == {"full_well": pytest.approx(v["noise.full_well"]), "read_noise": 5.0, "bits": 12}
        assert task.range_noise == pytest.approx(v["range_noise"]) and task.seed == 0


def test_camera_position_keeps_the_base_camera_without_inputs_and_follows_a_tilted_board():
    scene = yaml.safe_load(GLOBAL.read_text())["scene"]
    assert camera_position(scene, viewing_angle=None, camera_distance=None) == pytest.approx([0.0, -0.35, 0.5])
    tilted = {**scene, "object": {**scene["object"], "normal": [0.0, 1.0, 1.0]}}  # the board's normal at 45 deg
    cam = np.asarray(camera_position(tilted, viewing_angle=0.0, camera_distance=0.5))
    np.testing.assert_allclose(cam, 0.5 * np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0), atol=1e-12)


def test_gsa_spells_quiet_cache_and_set_as_every_verb_does(tmp_path, monkeypatch, capsys):
    from nearlight.cli import build_parser

    verbs = build_parser()._subparsers._group_actions[0].choices  # noqa: SLF001 - argparse keeps its verbs here
    assert {"--quiet", "--cache", "--no-cache", "--set", "--workers", "--scheduler", "--design"} <= {
        s for a in verbs["gsa"]._actions for s in a.option_strings
    }
    path = _study(tmp_path, monkeypatch, {"method": "morris", "n": 2})
    for argv, needle in [(["--set", "designs.main.n"], "--set 'designs.main.n': expected KEY=VALUE"),
                         (["--design", "other"], "--design other: not a design of"),
                         (["--workers", "0"], "--workers: expected a positive integer, got 0")]:  # fmt: skip
        assert main(["gsa", str(path), "--out", str(tmp_path / "res"), *argv]) == 2
        out, err = capsys.readouterr()
        assert out == "" and err.count("\n") == 1 and needle in err, err


def test_a_samples_output_is_the_mean_over_its_seeds_and_nan_when_any_failed():
    from nearlight.evaluation.gsa.study import DesignRun, outputs

    run = DesignRun(Design("d", "morris", n=1), np.zeros((3, 2)), None,
                    [{"m": ["a", "b"]}, {"m": ["c"]}, {"m": ["d", "e"]}])  # fmt: skip
    rows = pd.DataFrame({"task_id": list("abcde"), "status": ["ok", "ok", "ok", "ok", "error"],
                         "lamp_position_error_m": [1.0, 3.0, 5.0, 7.0, math.nan]})  # fmt: skip
    np.testing.assert_array_equal(outputs(run, rows, "lamp_position_error_m", "m"), [2.0, 5.0, np.nan])


def test_the_failed_output_is_one_where_the_method_gave_no_answer_and_zero_where_it_answered():
    """``metrics: [failed]`` asks which inputs make a method fail: a row that is not ``ok`` (a sanity rule's refusal,
    or the method's one-line reason, status error) is 1, as the sweep reports and ``compare`` count failures; an
    answer 0; a missing task NaN. A metric of the same rows is NaN wherever the method gave no answer."""
    from types import SimpleNamespace

    from nearlight.evaluation.gsa.study import FAILED, outputs

    results = pd.DataFrame({"task_id": ["a", "b", "c", "d"], "status": ["ok", "failed", "error", "ok"],
                            "lamp_position_error_m": [0.1, math.nan, math.nan, 0.3]})  # fmt: skip
    run = SimpleNamespace(sample_tasks=[{"m": ["a"]}, {"m": ["b"]}, {"m": ["c"]}, {"m": ["d"]}, {}])
    np.testing.assert_array_equal(outputs(run, results, FAILED, "m"), [0.0, 1.0, 1.0, 0.0, math.nan])
    np.testing.assert_array_equal(outputs(run, results, "lamp_position_error_m", "m"), [0.1, math.nan, math.nan, 0.3,
                                                                                        math.nan])


def test_morris_effects_by_level_of_a_categorical_input_are_the_slopes_there():
    """y = 4·u on the board, 1·u on the sphere, plus 2·v everywhere: u's mu* is exactly 4 at object=board and 1 at
    object=sphere (every elementary effect of a linear term is its slope), v's 2 at both, and the categorical
    input itself has no row entry of its own level."""
    from nearlight.evaluation.gsa.report import effects_by_level

    inputs = [Input("u", "uniform", (0.0, 1.0)), Input("object", "labels", (0.0, 2.0), [("board", 0), ("sphere", 1)]),
              Input("v", "uniform", (0.0, 1.0))]  # fmt: skip
    design = Design("morris", "morris", n=40, seed=5, levels=4)
    X = sample(inputs, design)
    board = np.floor(X[:, 1]) == 0
    Y = np.where(board, 4.0, 1.0) * X[:, 0] + 2.0 * X[:, 2]
    by = effects_by_level(inputs, design.levels, X, Y).set_index("input")
    assert by.loc["u", "object=board"] == pytest.approx(4.0) and by.loc["u", "object=sphere"] == pytest.approx(1.0)
    assert by.loc["v"].tolist() == pytest.approx([2.0, 2.0])
    assert by.loc["object"].isna().all()


def test_morris_step_by_step_is_salibs_morris_when_every_run_answered_and_keeps_the_steps_that_did():
    """With every output finite, mu, mu* and sigma are SALib's own (SALib.analyze.morris on the same sample); with
    refusals, only the steps with a refused end are left out: a trajectory with one refusal still gives its other
    steps (SALib would drop it whole)."""
    from SALib.analyze import morris as salib_morris

    inputs = ISHIGAMI_INPUTS
    design = Design("morris", "morris", n=30, seed=4, levels=4)
    X = sample(inputs, design)
    Y = ishigami(X)
    rows, _ = analyse(inputs, design, X, Y)
    ref = salib_morris.analyze({"num_vars": 3, "names": ["x1", "x2", "x3"], "bounds": [[-PI, PI]] * 3}, X, Y,
                               num_levels=4, seed=4)  # fmt: skip
    for j, r in enumerate(rows):
        assert (r["mu"], r["mu_star"], r["sigma"]) == pytest.approx((ref["mu"][j], ref["mu_star"][j], ref["sigma"][j]),
                                                                    rel=1e-12)  # fmt: skip
        assert r["steps"] == 30
    Y[[1, 4 * 7 + 2]] = np.nan  # row 1: trajectory 0's steps 0 and 1; row 30: trajectory 7's steps 1 and 2
    rows, blocks = analyse(inputs, design, X, Y)
    assert blocks == 28 and sum(r["steps"] for r in rows) == 3 * 30 - 4


def test_outputs_that_vary_only_off_a_and_b_give_no_index_and_no_warning():
    """A rare failure (the ``failed`` output of a method that almost always answers) may fall only in rows A_B^i:
    A and B then show no variance, every index and the floor are undefined (NaN), quietly (filterwarnings=error)."""
    design = Design("sobol", "sobol", n=64, seed=7)
    X = sample(ISHIGAMI_INPUTS, design)
    Y = np.zeros(len(X))
    Y[[1, 12]] = 1.0  # rows A_B^1 of blocks 0 and 2
    rows, blocks = analyse(ISHIGAMI_INPUTS, design, X, Y)
    assert blocks == 64 and all(math.isnan(r["ST"]) and math.isnan(r["ST_floor"]) for r in rows)


def test_replicates_run_as_sweeps_of_their_own_and_pool_into_one_analysis(tmp_path, monkeypatch, capsys):
    """Two replicates of n = 32 (seeds 2 and 3): each a sweep in seed-<s>/, the indices over all 64 blocks equal
    one analysis of the two samples put together, and each replicate's own indices are in convergence.csv."""
    from nearlight.evaluation.gsa.report import order_changes

    path = _study(tmp_path, monkeypatch, {"method": "sobol", "n": 32, "seed": 2, "replicates": 2})
    assert main(["gsa", str(path), "--out", str(tmp_path / "res"), "--quiet"]) == 0
    err = capsys.readouterr().err
    design = tmp_path / "res" / "main"
    assert "main replicate seed 2 (seed-2, 2 in all): sobol design, n = 32: 160 samples" in err, err
    assert "main replicate seed 3 (seed-3, 2 in all)" in err, err
    assert (design / "seed-2" / "results.parquet").is_file() and (design / "seed-3" / "results.parquet").is_file()
    study = load_study(path)
    run = study.runs["main"]
    assert [r.seed for r in run.replicates] == [2, 3] and run.samples.shape == (2 * 32 * 5, 3)
    # the replicates are differently scrambled samples, each SALib's own for its seed
    np.testing.assert_array_equal(run.samples[:160], sample(study.inputs, run.design, 2))
    assert not np.allclose(run.samples[:160], run.samples[160:])
    got = pd.read_csv(design / "gsa" / "indices.csv").set_index("input")
    assert (got["blocks"] == 64).all() and (got["n_blocks"] == 64).all()
    outputs_csv = pd.read_csv(design / "gsa" / "outputs.csv")
    Y = outputs_csv["lamp_position_error_m"].to_numpy()
    want, _ = analyse(study.inputs, run.design, run.samples, Y)
    np.testing.assert_allclose(got.loc[[r["input"] for r in want], "ST"], [r["ST"] for r in want], rtol=1e-12)
    conv = pd.read_csv(design / "gsa" / "convergence.csv", dtype={"seeds": str})
    assert sorted(set(zip(conv["n"], conv["seeds"]))) == [(16, "2"), (32, "2"), (32, "3"), (64, "2+3")]
    alone = conv[conv["seeds"] == "3"].set_index("input")
    want3, _ = analyse(study.inputs, run.design, run.samples[160:], Y[160:])
    np.testing.assert_allclose(alone.loc[[r["input"] for r in want3], "ST"], [r["ST"] for r in want3], rtol=1e-12)
    assert set(order_changes(conv, "model", "lamp_position_error_m")[1]) == {"16 (seeds 2)", "32 (seeds 2)", "32 (seeds 3)"}
    md = (design / "gsa" / "gsa.md").read_text()
    assert "N = 64 (2 replicates of n = 32, seeds 2, 3)" in md, md
    assert re.search(r"- model, lamp_position_error_m: (the \d pairs apart keep their order in all 3|no two inputs)", md), md

    # a third replicate runs only itself
    doc = yaml.safe_load(path.read_text())
    doc["designs"]["main"]["replicates"] = 3
    path.write_text(yaml.safe_dump(doc, sort_keys=False))  # the inputs in their order: the same samples
    assert main(["gsa", str(path), "--out", str(tmp_path / "res"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.count("ran 0 task(s)") == 2 and "seed-4" in err, err
    assert (pd.read_csv(design / "gsa" / "indices.csv")["blocks"] == 96).all()


def test_order_changes_names_the_pairs_a_part_turns_round():
    from nearlight.evaluation.gsa.report import order_changes

    def rows(n, seeds, st):
        return [{"n": n, "seeds": seeds, "method": "m", "metric": "y", "input": name, "ST": v, "ST_lo": v - 0.05,
                 "ST_hi": v + 0.05, "ST_floor": 0.02} for name, v in st.items()]  # fmt: skip

    conv = pd.DataFrame(rows(64, "1+2", {"a": 0.6, "b": 0.3, "c": 0.28, "d": 0.0})  # b, c overlap: not compared
                        + rows(32, "1", {"a": 0.5, "b": 0.2, "c": 0.3, "d": 0.01})
                        + rows(32, "2", {"a": 0.2, "b": 0.4, "c": 0.1, "d": 0.3}))  # fmt: skip
    assert order_changes(conv, "m", "y") == (["a > b", "a > c"], {"32 (seeds 1)": [], "32 (seeds 2)": ["a > b"]})


def test_total_indices_within_a_level_of_a_categorical_input_are_the_closed_form_shares_there():
    """y = x1 + c·x2 with c ∈ {0, 1} a fair categorical input and x1, x2 ~ U(0, 1): where c = 0, x2 does nothing
    (ST = 0, within the level's floor) and x1 is everything (ST = 1); where c = 1, x1 and x2 share the
    variance equally (ST = 1/2 each: y = x1 + x2 has no interaction)."""
    from nearlight.evaluation.gsa.sobol import level_total_indices

    inputs = [Input("x1", "uniform", (0.0, 1.0)), Input("x2", "uniform", (0.0, 1.0)),
              Input("c", "labels", (0.0, 2.0), [("off", 0), ("on", 1)])]  # fmt: skip
    design = Design("d", "sobol", n=4096, seed=5)
    X = sample(inputs, design)
    c = np.floor(X[:, 2])
    Y = X[:, 0] + c * X[:, 1]
    blocks = X.reshape(-1, 5, 3)
    for level, want in ((0, [1.0, 0.0]), (1, [0.5, 0.5])):
        got = level_total_indices(Y, 3, np.floor(blocks[:, 0, 2]) == level, np.floor(blocks[:, -1, 2]) == level,
                                  seed=1)  # fmt: skip
        assert 1900 < got["blocks"] < 2200, got["blocks"]  # about half of the 4096 base samples
        for j, w in enumerate(want):
            assert got["ST_lo"][j] <= w <= got["ST_hi"][j] and got["ST_hi"][j] - got["ST_lo"][j] < 0.1, (level, j, got)
        assert 0 < got["ST_floor"] < 0.1
        assert (got["ST_hi"][1] <= got["ST_floor"]) == (level == 0)  # x2 within the floor only where c = 0
