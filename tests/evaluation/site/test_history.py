"""The site's history: every committed regeneration is a point, and a planted regression is marked where it is.

Three runs of one tiny analytic sweep (``full`` and ``paper-init``, eight camera-noise seeds), the second with
``full`` planted 2 % further along its ray (:func:`nearlight.evaluation.planted.further_along_ray`, under the name
``full``): ``nearlight site`` marks exactly that run's ``full`` lamp metrics, because ``compare`` of run 2
against run 1 finds them worse and run 3 against run 2 finds them better. Nothing renders.
"""

from __future__ import annotations

import json
import shutil
import subprocess

import pytest
import yaml

from nearlight.cli import main
from nearlight.evaluation.site.history import committed_folders, repository

from .conftest import REPORTS
from .test_site import _broken_refs

FULL = "full"
PLANTED = {"method": "nearlight.evaluation.planted:further_along_ray", "name": FULL,
           "options": {"base": "full", "fraction": 0.02}}  # fmt: skip


def _sweep(methods: list) -> dict:
    return {"name": "tiny-history", "renderer": "analytic", "scene": {"width": 40, "height": 30},
            "axes": {"noise": {"sensor": {"full_well": 20000, "read_noise": 5, "bits": 12}}}, "seeds": 8,
            "methods": methods, "crlb": False}  # fmt: skip


def test_a_planted_bias_in_one_of_three_runs_is_marked_on_exactly_that_runs_full_lamp_metrics(tmp_path, capsys):
    runs = []
    for name, full in (("run1", FULL), ("run2", PLANTED), ("run3", FULL)):
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(_sweep([full, "paper-init"])))
        assert main(["sweep", str(path), "--out", str(tmp_path / name), "--quiet"]) == 0
        runs.append(tmp_path / name)
    site = tmp_path / "site"
    assert main(["site", *map(str, runs), "--out", str(site)]) == 0
    doc = json.loads((site / "data" / "history.json").read_text())
    mine = [s for s in doc["series"] if s["origin"] == "folders"]
    assert len(mine) == 1 and [r["label"] for r in mine[0]["runs"]] == ["run1", "run2", "run3"]
    marked = {(p["run"], p["method"], p["metric"]) for p in mine[0]["points"] if p["worse"]}
    assert {(1, FULL, "lamp_position_error_pct"), (1, FULL, "lamp_position_error_m")} <= marked, marked
    # nowhere else: not run 3 (better than run 2), not paper-init, not σ, Ks or failures (the re-synthesised
    # specular's residual may move with the lamp it is rendered from)
    assert all(run == 1 and method == FULL and metric.startswith(("lamp_", "distance_", "direction_", "specular_"))
               for run, method, metric in marked), marked  # fmt: skip
    page = (site / "history.html").read_text()
    assert page.count('class="num worse"') == len(marked) and _broken_refs(site) == []


@pytest.mark.skipif(shutil.which("git") is None or repository(REPORTS) is None, reason="needs the git checkout")
def test_every_commit_of_a_committed_baseline_is_a_point_of_its_history(committed_site):
    repo = repository(REPORTS)
    folders = committed_folders(repo, [REPORTS])
    assert "reports/smoke-baseline" in folders and "reports/scores/core-v1/full" in folders
    site = committed_site
    doc = {s["name"]: s for s in json.loads((site / "data" / "history.json").read_text())["series"]}
    for folder in ("reports/smoke-baseline", "reports/scores/core-v1/full"):
        log = subprocess.run(["git", "-C", str(repo), "log", "--format=%h", "--", f"{folder}/results.parquet"],
                             capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
        assert len(doc[folder]["runs"]) == len(log) >= 2, folder
        assert [r["label"] for r in doc[folder]["runs"]] == [h[:7] for h in reversed(log)]
    assert (site / "history.html").is_file() and _broken_refs(site) == []
