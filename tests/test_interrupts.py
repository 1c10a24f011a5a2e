"""Tidy exits: a killed sweep leaves no orphaned workers and resumes to exactly the clean run's rows
(damaged parts set aside and re-run); a terminated render leaves no scratch folder and no capture."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml

from nearlight.evaluation.engine.store import read_results

ROOT = Path(__file__).resolve().parents[1]

PLUGIN = '''
import os, time
import numpy as np
from nearlight.estimator import Estimate

def slow(capture, *, delay=0.3):
    folder = os.environ.get("NL_PID_DIR")
    if folder:
        open(os.path.join(folder, str(os.getpid())), "w").close()
    time.sleep(delay)
    t = capture.truth
    ks = np.asarray(t["bsdf"]["ks"]) * np.asarray(t["lamp_intensity"]) / 2
    return Estimate(method="slow", lamp_position=np.asarray(t["lamp_position"]), ks=ks, sigma=t["bsdf"]["sigma"])
'''

SWEEP = {
    "name": "interrupt-test",
    "renderer": "analytic",
    "scene": {"width": 24, "height": 18},
    # camera noise makes the seeds count (a noise-free configuration runs once whatever the seeds)
    "axes": {"lamp_distance": [0.3, 0.4, 0.5, 0.6], "noise": {"low": {"full_well": 1000, "saturation": 1.0}}},
    "seeds": 3,
    "crlb": False,
    "methods": [{"name": "slow", "method": "nl_interrupt_plugin:slow", "options": {"delay": 0.3}}],
}
N_TASKS = 12


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is dead for our purposes
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def _env(tmp_path: Path, pid_dir: Path) -> dict[str, str]:
    plugin_dir = tmp_path / "plugin"
    plugin_dir.mkdir(exist_ok=True)
    (plugin_dir / "nl_interrupt_plugin.py").write_text(textwrap.dedent(PLUGIN))
    return dict(os.environ, NL_PID_DIR=str(pid_dir),
                PYTHONPATH=os.pathsep.join([str(plugin_dir), os.environ.get("PYTHONPATH", "")]))  # fmt: skip


def test_sigkilled_sweep_leaves_no_orphan_workers_and_resumes_to_the_clean_rows(tmp_path):
    sweep = tmp_path / "s.yaml"
    sweep.write_text(yaml.safe_dump(SWEEP, sort_keys=False))
    pids = tmp_path / "pids"
    pids.mkdir()
    env = _env(tmp_path, pids)
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "nearlight", "sweep", str(sweep), "--out", str(out), "--quiet", "--workers", "2"]
    with open(tmp_path / "log", "w") as log:
        proc = subprocess.Popen(cmd, env=env, stderr=log, start_new_session=True)
        deadline = time.monotonic() + 120
        while len(list((out / "parts").glob("*.parquet"))) < 3 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        assert proc.poll() is None, (tmp_path / "log").read_text()
        os.kill(proc.pid, signal.SIGKILL)  # the parent only: its workers must notice by themselves
        proc.wait()
    workers = [int(p.name) for p in pids.iterdir()]
    assert workers and proc.pid not in workers
    deadline = time.monotonic() + 10
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [w for w in workers if _alive(w)]
    for w in left:  # do not leave them behind even when the test fails
        os.kill(w, signal.SIGKILL)
    assert not left, f"orphaned workers still running: {left}"

    parts = sorted((out / "parts").glob("*.parquet"))
    assert 3 <= len(parts) < N_TASKS
    damaged = parts[0]
    damaged.write_bytes(damaged.read_bytes()[:40])  # a part cut short (disk full, copied half)
    good = {p.name: p.read_bytes() for p in parts[1:]}
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "damaged result part was moved to" in done.stderr
    assert (out / "parts" / "damaged" / damaged.name).is_file()  # kept for a person, not deleted
    assert all((out / "parts" / n).read_bytes() == b for n, b in good.items()), "a good row was rewritten"

    clean = tmp_path / "clean"
    assert subprocess.run([*cmd[:5], "--out", str(clean), "--quiet"], env=env, capture_output=True, timeout=300).returncode == 0
    a, complete_a = read_results(out)
    b, complete_b = read_results(clean)
    assert complete_a and complete_b and len(a) == N_TASKS
    cols = [c for c in a.columns if c != "runtime_s"]
    pd.testing.assert_frame_equal(a[cols].sort_values("task_id").reset_index(drop=True),
                                  b[cols].sort_values("task_id").reset_index(drop=True))  # fmt: skip


def test_sigterm_ends_a_sweep_and_its_workers_promptly(tmp_path):
    sweep = tmp_path / "s.yaml"
    sweep.write_text(yaml.safe_dump(dict(SWEEP, methods=[dict(SWEEP["methods"][0], options={"delay": 30.0})]),
                                    sort_keys=False))  # fmt: skip
    pids = tmp_path / "pids"
    pids.mkdir()
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "nearlight", "sweep", str(sweep), "--out", str(out), "--quiet", "--workers", "2"]
    proc = subprocess.Popen(cmd, env=_env(tmp_path, pids), stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while len(list(pids.iterdir())) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, proc.stderr.read()
    start = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=60)[1]
    assert proc.returncode == 143 and err.strip().splitlines()[-1] == "nearlight: terminated", err
    assert time.monotonic() - start < 10, "the sweep waited for its running tasks instead of ending them"
    workers = [int(p.name) for p in pids.iterdir()]
    time.sleep(0.5)
    left = [w for w in workers if _alive(w)]
    for w in left:
        os.kill(w, signal.SIGKILL)
    assert not left
    assert not list((out / "parts").glob(".*")), "no half-written part may survive"


@pytest.mark.render
def test_sigterm_during_a_render_leaves_no_scratch_and_no_capture(tmp_path):
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    out = tmp_path / "out" / "cap"
    cmd = [sys.executable, "-m", "nearlight", "render", str(ROOT / "scenes" / "torus.yaml"), "--out", str(out),
           "--no-cache", "--quiet", "--set", "camera.resolution=[320,240]", "--set", "capture.spp=256",
           "--set", "capture.max_depth=3"]  # fmt: skip
    proc = subprocess.Popen(cmd, env=dict(os.environ, TMPDIR=str(scratch)), stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not list(scratch.glob("nearlight-render-*")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, proc.stderr.read()
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "nearlight: terminated"
    assert list(scratch.iterdir()) == []
    assert not (tmp_path / "out").exists() or list((tmp_path / "out").iterdir()) == []
