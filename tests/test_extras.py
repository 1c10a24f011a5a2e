"""Optional extras: a plain install (no renderer, no cluster) estimates and evaluates; verbs that need
an extra say which in one line (exit 2). pyproject.toml: ``render`` (mitsuba, drjit), ``cluster``
(dask[distributed]), ``all``, ``test``."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
import tomllib
from pathlib import Path

import yaml

from nearlight.capture import write_capture
from nearlight.generator.analytic import analytic_capture

ROOT = Path(__file__).resolve().parents[1]

#: Runs ``nearlight`` as if the extras were not installed: importing one of their modules raises ImportError.
BLOCKED_RUNNER = textwrap.dedent(
    """
    import sys

    BLOCKED = {"mitsuba", "drjit", "dask", "distributed"}


    class Blocker:
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] in BLOCKED:
                raise ImportError(f"{name} is blocked (a plain install has no extras)")
            return None


    sys.meta_path.insert(0, Blocker())
    from nearlight.cli import main

    status = main(sys.argv[1:])
    assert not BLOCKED & set(m.partition(".")[0] for m in sys.modules), "an extra was imported"
    sys.exit(status)
    """
)

SWEEP = {"name": "plain", "renderer": "analytic", "scene": {"width": 24, "height": 18},
         "axes": {"lamp_distance": [0.3]}, "seeds": 1, "methods": ["paper-init"]}  # fmt: skip


def _blocked(tmp_path: Path, *argv: str) -> subprocess.CompletedProcess:
    runner = tmp_path / "plain_nearlight.py"
    runner.write_text(BLOCKED_RUNNER)
    env = dict(os.environ, NEARLIGHT_CACHE=str(tmp_path / "cache"))
    return subprocess.run([sys.executable, str(runner), *argv], capture_output=True, text=True, env=env,
                          cwd=tmp_path, timeout=300)  # fmt: skip


def test_extras_are_declared():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    plain = " ".join(project["dependencies"]).lower()
    assert not any(name in plain for name in ("mitsuba", "drjit", "dask", "distributed"))
    extras = project["optional-dependencies"]
    assert [r.split("=")[0] for r in extras["render"]] == ["mitsuba", "drjit"]
    assert extras["cluster"] == ["dask[distributed]>=2024.1"]
    assert [r.split("=")[0].split(";")[0] for r in extras["rig"]] == ["polanalyser", "opencv-python-headless>", "trimesh",
                                                                  "embreex"]
    assert extras["all"] == ["nearlight[render,cluster,rig]"]
    assert "-e \".[all,test]\"" in (ROOT / "scripts" / "setup").read_text()


def test_every_module_imports_without_extras(tmp_path):
    """Mitsuba, Dr.Jit and Dask are imported only inside the functions that use them."""
    walk = BLOCKED_RUNNER.split("from nearlight.cli import main")[0] + textwrap.dedent(
        """
        import importlib, pkgutil
        import nearlight

        skip = ("nearlight.tests", "nearlight.benchmarks", "nearlight.scripts", "nearlight.__main__")
        names = [m.name for m in pkgutil.walk_packages(nearlight.__path__, "nearlight.") if not m.name.startswith(skip)]
        for name in names:
            importlib.import_module(name)
        assert len(names) > 50 and not BLOCKED & set(m.partition(".")[0] for m in sys.modules)
        """
    )
    run = subprocess.run([sys.executable, "-c", walk], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert run.returncode == 0, run.stderr


def test_without_extras_estimate_and_evaluate_work_and_render_says_what_to_install(tmp_path):
    cap = write_capture(analytic_capture(width=48, height=36), tmp_path / "cap")
    run = _blocked(tmp_path, "estimate", str(cap), "--method", "paper-init", "--json", str(tmp_path / "e.json"))
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("paper-init: lamp (") and run.stdout.splitlines()[-1] == str(tmp_path / "e.json")

    run = _blocked(tmp_path, "show", str(cap))
    assert run.returncode == 0, run.stderr

    sweep = tmp_path / "plain.yaml"
    sweep.write_text(yaml.safe_dump(SWEEP))
    run = _blocked(tmp_path, "sweep", str(sweep), "--out", str(tmp_path / "res"), "--quiet")
    assert run.returncode == 0, run.stderr
    run = _blocked(tmp_path, "report", str(tmp_path / "res"))
    assert run.returncode == 0, run.stderr

    run = _blocked(tmp_path, "render", str(ROOT / "scenes" / "ts_board.yaml"), "--out", str(tmp_path / "r"))
    assert (run.returncode, run.stdout) == (2, "")
    assert run.stderr == "nearlight render: needs the renderer: pip install 'nearlight[render]'\n"
    assert not (tmp_path / "r").exists()

    run = _blocked(tmp_path, "sweep", str(sweep), "--out", str(tmp_path / "res2"), "--scheduler", "tcp://127.0.0.1:8786")
    assert (run.returncode, run.stderr) == (2, "nearlight sweep: needs the cluster: pip install 'nearlight[cluster]'\n")

    sweep.write_text(yaml.safe_dump({**SWEEP, "renderer": "mitsuba", "scene": str(ROOT / "scenes" / "ts_board.yaml"),
                                     "axes": {"lamp_distance": [0.3]}}))  # fmt: skip
    run = _blocked(tmp_path, "sweep", str(sweep), "--out", str(tmp_path / "res3"))
    assert (run.returncode, run.stderr) == (2, "nearlight sweep: needs the renderer: pip install 'nearlight[render]'\n")
    assert not (tmp_path / "res3").exists()

    # the same scene file in closed form needs no renderer (generator/closed_form.py is numpy only)
    sweep.write_text(yaml.safe_dump({**SWEEP, "renderer": "closed-form", "scene": str(ROOT / "scenes" / "ts_board.yaml"),
                                     "set": {"camera.resolution": [48, 36]}, "axes": {"lamp_distance": [0.3]}}))  # fmt: skip
    run = _blocked(tmp_path, "sweep", str(sweep), "--out", str(tmp_path / "res4"), "--quiet")
    assert run.returncode == 0, run.stderr


def test_a_plain_install_in_a_fresh_venv_estimates(tmp_path):
    """pip install -c constraints.txt <repo>, no extras: Mitsuba absent, ``nearlight estimate`` works.

    About a minute on 2 cores with pip's cache warm (63 s measured: building the wheel, installing
    numpy, scipy, pandas, matplotlib, pyarrow and the rest), so it is in the default suite."""
    venv = tmp_path / "venv"
    clock = time.perf_counter()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    pip = subprocess.run([str(py), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                          "-c", str(ROOT / "constraints.txt"), str(ROOT)],
                         capture_output=True, text=True, timeout=1200)  # fmt: skip
    assert pip.returncode == 0, pip.stderr[-3000:]
    assert subprocess.run([str(py), "-c", "import mitsuba"], capture_output=True).returncode != 0
    assert subprocess.run([str(py), "-c", "import distributed"], capture_output=True).returncode != 0

    cap = write_capture(analytic_capture(width=48, height=36), tmp_path / "cap")
    run = subprocess.run([str(venv / "bin" / "nearlight"), "estimate", str(cap), "--method", "paper-init"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=300)  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("paper-init: lamp (")
    run = subprocess.run([str(venv / "bin" / "nearlight"), "render", str(ROOT / "scenes" / "ts_board.yaml"),
                          "--out", str(tmp_path / "r")], capture_output=True, text=True, cwd=tmp_path, timeout=300)  # fmt: skip
    assert (run.returncode, run.stderr) == (2, "nearlight render: needs the renderer: pip install 'nearlight[render]'\n")
    print(f"\nfresh venv, plain install, estimate: {time.perf_counter() - clock:.0f} s")
