"""The sweep engine on analytic captures with fake estimators: rows, resume after a kill,
local processes and Dask give the same rows, re-runs are identical, compare and report."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pandas as pd
import pytest
import yaml

from nearlight.evaluation.views.compare import compare_dirs
from nearlight.evaluation.scoring.crlb import camera_noise_variance
from nearlight.evaluation.engine.run import run_sweep
from nearlight.evaluation.views.report import write_report
from nearlight.evaluation.engine.store import read_results
from nearlight.evaluation.engine.sweep import load_sweep

# Fake estimators (they read the truth: they test the engine, not estimation). `noisy` depends on the
# noisy stack, so different seeds give different numbers and equal seeds equal ones.
FAKES = '''
import time
import numpy as np
from nearlight.estimator import Estimate

def oracle(capture, *, offset=0.0, delay=0.0):
    time.sleep(delay)
    t = capture.truth
    ks = np.asarray(t["bsdf"]["ks"]) * np.asarray(t["lamp_intensity"]) / 2
    return Estimate(method="oracle", lamp_position=np.asarray(t["lamp_position"]) + offset, ks=ks,
                    sigma=t["bsdf"]["sigma"])

def noisy(capture):
    est = oracle(capture)
    est.lamp_position = est.lamp_position + [float(np.mean(capture.stack)) * 0.01, 0.0, 0.0]
    return est

def broken(capture):
    raise RuntimeError("fake estimator failed on purpose")
'''

SWEEP = {
    "name": "engine-test",
    "renderer": "analytic",
    "scene": {"width": 32, "height": 24},
    "axes": {
        "lamp_distance": [0.3, 0.5],
        "noise": {"none": None, "low": {"full_well": 1000, "read_noise": 2.0, "saturation": 1.0}},
    },
    "seeds": 2,
    "methods": ["nl_fake_estimators:oracle", "nl_fake_estimators:noisy", "nl_fake_estimators:broken"],
}
N_TASKS = 2 * (1 + 2) * 3  # distances x (noise-free: 1 seed, noisy: 2 seeds) x methods
IGNORED = ["runtime_s"]  # wall time differs between runs by nature


@pytest.fixture(scope="module")
def fakes_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fakes")
    (d / "nl_fake_estimators.py").write_text(textwrap.dedent(FAKES))
    sys.path.insert(0, str(d))
    yield d
    sys.path.remove(str(d))


@pytest.fixture(scope="module")
def sweep_file(fakes_dir, tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "engine.yaml"
    path.write_text(yaml.safe_dump(SWEEP, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def first_run(sweep_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "a"
    summary = run_sweep(load_sweep(sweep_file), out, workers=1, progress=False)
    return out, summary


def _rows(out):
    df, complete = read_results(out)
    assert complete
    return df.drop(columns=IGNORED).set_index("task_id").sort_index()


def test_one_row_per_task_with_metrics_and_errors(first_run, sweep_file):
    out, summary = first_run
    assert (summary.tasks, summary.ran, summary.failed, summary.complete) == (N_TASKS, N_TASKS, N_TASKS // 3, True)
    df, _ = read_results(out)
    assert sorted(df["task_id"]) == sorted(t.task_id for t in load_sweep(sweep_file).tasks)
    assert list(df["task_index"]) == list(range(N_TASKS))
    for col in ("lamp_distance", "noise", "seed", "method", "code_version", "status", "error", "render_key"):
        assert col in df
    oracle = df[df["method"] == "nl_fake_estimators:oracle"]
    assert (oracle["status"] == "ok").all()
    # the oracle is the truth: every error is 0 (specular RMSE: float32 storage of the truth image)
    assert (oracle[["lamp_position_error_m", "direction_error_deg", "sigma_rel_error", "ks_rel_error"]] == 0).all().all()
    assert (oracle["specular_rmse_rel"] < 1e-6).all()
    broken = df[df["method"] == "nl_fake_estimators:broken"]
    assert (broken["status"] == "error").all()
    assert broken["error"].str.contains("RuntimeError: fake estimator failed on purpose").all()
    assert broken["lamp_position_error_m"].isna().all()
    # CRLB only where there is camera noise (TS truth, ideal mode): positive and finite
    noisy = df[(df["noise"] == "low") & (df["status"] == "ok")]
    assert (noisy["crlb_lamp_m"] > 0).all() and np.isfinite(noisy["crlb_sigma_rel"]).all()
    assert df[df["noise"] == "none"]["crlb_lamp_m"].isna().all()
    # seeds give different noise, hence different `noisy` estimates
    nz = df[(df["method"] == "nl_fake_estimators:noisy") & (df["noise"] == "low")]
    assert nz.groupby("lamp_distance")["lamp_position_error_m"].nunique().eq(2).all()


def test_same_sweep_twice_gives_identical_numbers(first_run, sweep_file, tmp_path):
    run_sweep(load_sweep(sweep_file), tmp_path / "b", workers=1, progress=False)
    pd.testing.assert_frame_equal(_rows(first_run[0]), _rows(tmp_path / "b"))


def test_rerun_of_a_finished_sweep_runs_nothing(first_run, sweep_file, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(first_run[0], out)
    summary = run_sweep(load_sweep(sweep_file), out, workers=1, progress=False)
    assert (summary.ran, summary.skipped, summary.complete) == (0, N_TASKS, True)
    pd.testing.assert_frame_equal(_rows(first_run[0]), _rows(out))


def test_dask_local_cluster_gives_the_same_rows(first_run, sweep_file, tmp_path):
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            summary = run_sweep(load_sweep(sweep_file), tmp_path / "dask", scheduler=client, progress=False)
    assert summary.complete
    pd.testing.assert_frame_equal(_rows(first_run[0]), _rows(tmp_path / "dask"))


def test_local_processes_give_the_same_rows(first_run, sweep_file, tmp_path):
    summary = run_sweep(load_sweep(sweep_file), tmp_path / "procs", workers=2, progress=False)
    assert summary.complete
    pd.testing.assert_frame_equal(_rows(first_run[0]), _rows(tmp_path / "procs"))


def test_killed_sweep_resumes_with_exactly_one_row_per_task(first_run, fakes_dir, tmp_path):
    doc = dict(SWEEP, methods=[{"name": "slow", "method": "nl_fake_estimators:oracle", "options": {"delay": 0.15}},
                               *SWEEP["methods"][1:]])
    sweep_path = tmp_path / "slow.yaml"
    sweep_path.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "nearlight", "sweep", str(sweep_path), "--out", str(out), "--quiet"]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(fakes_dir), os.environ.get("PYTHONPATH", "")]))
    log = tmp_path / "killed.log"
    with open(log, "w") as err:
        proc = subprocess.Popen(cmd, env=env, start_new_session=True, stderr=err)
        deadline = time.monotonic() + 120
        while len(list((out / "parts").glob("*.parquet"))) < 6 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        assert proc.poll() is None, f"the sweep ended before it was killed: {log.read_text()}"
        os.killpg(proc.pid, signal.SIGKILL)  # the process group we started: the sweep and nothing else
        proc.wait()
    before = {p.name: p.read_bytes() for p in (out / "parts").glob("*.parquet")}
    assert 6 <= len(before) < N_TASKS, "the sweep should be killed part-way"
    assert not (out / "results.parquet").exists(), "a killed sweep must not look complete"
    assert not list((out / "parts").glob(".*")), "no half-written part may survive a kill"

    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"skipped {len(before)} already done" in done.stderr
    df, complete = read_results(out)
    assert complete and len(df) == N_TASKS and df["task_id"].is_unique
    assert sorted(df["task_id"]) == sorted(t.task_id for t in load_sweep(sweep_path).tasks)
    # rows written before the kill are kept as they were
    assert all((out / "parts" / name).read_bytes() == data for name, data in before.items())


def test_another_sweep_into_the_same_folder_is_refused(first_run, sweep_file, tmp_path):
    from nearlight.errors import UserError

    other = load_sweep(dict(SWEEP, seeds=1))
    with pytest.raises(UserError, match="holds results of another sweep"):
        run_sweep(other, first_run[0], workers=1, progress=False)


def test_compare_zero_on_itself_and_nonzero_when_worse(first_run, tmp_path):
    out = first_run[0]
    checks, lines = compare_dirs(out, out)
    assert not any(c.regression for c in checks) and lines[-1].startswith("ok: nothing worse")
    assert {c.kind for c in checks} == {"exact", "pooled"}
    # the environment recorded beside the results is the one compare finds
    assert "environment: same as the baseline's" in lines
    bad = tmp_path / "worse"
    shutil.copytree(out, bad)
    df = pd.read_parquet(bad / "results.parquet")
    sel = (df["method"] == "nl_fake_estimators:noisy") & (df["noise"] == "none")
    df.loc[sel, "direction_error_deg"] *= 1.5  # 50 % worse, well beyond the default 5 %
    df.to_parquet(bad / "results.parquet", index=False)
    worse = [c for c in compare_dirs(bad, out)[0] if c.regression]
    assert {(c.method, c.metric, c.kind) for c in worse} == {("nl_fake_estimators:noisy", "direction_error_deg", "exact")}
    # within tolerance: not a regression
    assert not any(c.regression for c in compare_dirs(bad, out, tolerance=0.6)[0])
    # a task that worked and now fails is a regression
    first_ok = df.index[(df["status"] == "ok") & (df["noise"] == "none")][0]
    df.loc[first_ok, ["status", "error"]] = ["error", "boom"]
    df.to_parquet(bad / "results.parquet", index=False)
    assert any(c.metric == "failures" and c.regression for c in compare_dirs(bad, out, tolerance=0.6)[0])

    from nearlight.cli import main

    assert main(["compare", str(out), str(out)]) == 0
    assert main(["compare", str(bad), str(out), "--json", str(tmp_path / "verdict.json")]) == 1
    doc = json.loads((tmp_path / "verdict.json").read_text())
    assert doc["regression"] is True and doc["counts"]["worse"] >= 1
    assert len(doc["checks"]) == len(compare_dirs(bad, out)[0])


def test_report_tables_and_plots(first_run):
    folder = write_report(first_run[0])
    for name in ("summary.md", "overall.csv", "by_axis.csv", "crlb.csv", "error_vs_lamp_distance.png",
                 "error_vs_noise.png"):
        assert (folder / name).is_file() and (folder / name).stat().st_size > 0, name
    overall = pd.read_csv(folder / "overall.csv")
    o = overall[(overall["method"] == "nl_fake_estimators:oracle") & (overall["metric"] == "lamp_position_error_m")]
    assert o[["mean", "median", "p90"]].to_numpy().tolist() == [[0.0, 0.0, 0.0]] and int(o["n"].iloc[0]) == 6  # 2 distances x (1 + 2 seeds)
    crlb = pd.read_csv(folder / "crlb.csv")
    assert set(crlb["noise"]) == {"low"} and (crlb["crlb_lamp_m"] > 0).all()
    # the oracle has zero error: ratio 0; the noisy fake is off by more than the bound allows
    assert (crlb[crlb["method"] == "nl_fake_estimators:oracle"]["ratio_lamp"] == 0).all()
    text = (folder / "summary.md").read_text()
    assert "## By lamp_distance" in text and "Cramér–Rao" in text and "## Failed tasks" in text


def test_camera_noise_variance_matches_the_generator(rng):
    from nearlight.capture import Camera, Capture
    from nearlight.generator import add_camera_noise

    # a flat stack at 0.3 of saturation, 20000 draws per level: the sample variance is within ~2 % (1/sqrt(N/2))
    stack = np.full((2, 100, 100, 3), 0.3, dtype=np.float32)
    stack[1] = 0.05
    cap = Capture(width=100, height=100, camera=Camera(position=np.zeros(3)), P=np.zeros((100, 100, 3)),
                  stack=stack, analyzer_angles_deg=np.array([0.0, 90.0]))
    noise = {"full_well": 2000.0, "read_noise": 5.0, "bits": 10, "saturation": 1.0}
    noisy = add_camera_noise(cap, noise=noise, seed=7).stack
    predicted = camera_noise_variance(stack, noise=noise)
    for k in range(2):
        assert np.var(noisy[k]) == pytest.approx(predicted[k].mean(), rel=0.05)


def test_a_row_holds_its_estimate_and_its_captures_come_back_from_the_sweep(first_run, sweep_file):
    # The oracle's estimate is the truth (offset 0): a row's est_* columns give it back, and the
    # noisy capture task_captures rebuilds is the one the task saw (same seed rule, same images).
    from nearlight.evaluation.engine.run import row_estimate, task_captures

    out, _ = first_run
    sweep = load_sweep(sweep_file)
    df, _ = read_results(out)
    row = df[(df["method"] == "nl_fake_estimators:noisy") & (df["noise"] == "low")].iloc[0]
    task = sweep.tasks[int(row["task_index"])]
    clean, seen = task_captures(sweep, task, out)
    assert seen.stack is not None and not np.array_equal(seen.stack, clean.stack)
    expected = np.asarray(clean.truth["lamp_position"]) + [float(np.mean(seen.stack)) * 0.01, 0.0, 0.0]
    est = row_estimate(row)
    np.testing.assert_array_equal(est.lamp_position, expected)  # exact: float64 through Parquet
    assert est.sigma == clean.truth["bsdf"]["sigma"]
    failed = df[df["status"] != "ok"].iloc[0]
    assert np.isnan(row_estimate(failed).lamp_position).all()
