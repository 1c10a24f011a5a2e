"""``renderer: closed-form`` and ``renderer: auto`` (issue 36): scene files rendered by arithmetic where the closed
form covers them, the row naming the renderer, and the same result rows as Mitsuba's within float rounding.

The paired check: one small sweep (a board, a sphere in its place, a 1 cm sphere lamp, two lamp distances, noise-free
and with camera noise, 2 seeds, ``full``) run with ``renderer: mitsuba`` and with ``renderer: auto``. Their captures
differ by Mitsuba's float32 rounding (≤ 1e-4 relative, tests/generator/test_closed_form.py), so noise-free,
``full``'s lamp error moves by that much times its sensitivity: measured ≤ 1.9e-3 percentage points (Intel Xeon,
2026-12-07); bound 0.01. With camera noise the 12-bit quantisation turns a 1e-5 difference into a whole level
where a pixel sits at a level's edge (the same noise draws, seed for seed): measured ≤ 0.030 points, against a
seed-to-seed spread of 0.8 points on the sphere; bound 0.1. A sphere lamp is Monte Carlo in Mitsuba (16 samples
by default) and exact here: its rows differ by Mitsuba's noise (measured ≤ 0.09 points), held to 0.5.
"""

from __future__ import annotations

import copy

import pandas as pd
import pytest
import yaml

from nearlight.errors import UserError
from nearlight.evaluation.engine.run import run_sweep
from nearlight.evaluation.engine.sweep import load_sweep

from ...test_fuzz_inputs import ROOT

SWEEP = {
    "name": "auto",
    "renderer": "auto",
    "scene": str(ROOT / "scenes" / "ts_board.yaml"),
    "set": {"camera.resolution": [64, 48]},
    "axes": {
        "lamp_distance": [0.4, 0.6],
        "noise": {"none": None, "sensor": {"full_well": 20000, "read_noise": 5.0, "bits": 12}},
        "set": {"board": {}, "ball": {"object": {"type": "sphere", "radius": 0.1}}, "lamp-1cm": {"lamp.radius": 0.01},
                "torus": {"object": {"type": "torus", "major_radius": 0.08, "minor_radius": 0.03}}},
    },
    "seeds": 2,
    "methods": ["full"],
}  # fmt: skip
#: Columns that differ between the two runs by design.
RUN_COLUMNS = ["task_id", "sweep", "renderer", "render_key", "runtime_s", "code_version"]


def _run(tmp_path, renderer: str) -> pd.DataFrame:
    path = tmp_path / f"{renderer}.yaml"
    path.write_text(yaml.safe_dump({**copy.deepcopy(SWEEP), "renderer": renderer, "name": renderer}))
    out = tmp_path / renderer
    summary = run_sweep(load_sweep(path), out, progress=False)
    assert summary.complete and summary.failed == 0
    return pd.read_parquet(out / "results.parquet").set_index(["set", "lamp_distance", "noise", "seed"]).sort_index()


@pytest.mark.render
def test_auto_gives_mitsubas_rows_within_float_rounding(tmp_path):
    auto, mitsuba = _run(tmp_path, "auto"), _run(tmp_path, "mitsuba")
    assert set(mitsuba["renderer"]) == {"mitsuba"}
    expect = pd.Series("closed-form", index=auto.index).where(auto.index.get_level_values("set") != "torus", "mitsuba")
    assert auto["renderer"].equals(expect)  # the torus is a mesh: Mitsuba's
    gap = (auto["lamp_position_error_pct"] - mitsuba["lamp_position_error_pct"]).abs()
    sphere_lamp = auto.index.get_level_values("set") == "lamp-1cm"
    clean = auto.index.get_level_values("noise") == "none"
    assert gap[~sphere_lamp & clean].max() <= 0.01, gap[~sphere_lamp & clean].sort_values().tail()
    assert gap[~sphere_lamp].max() <= 0.1, gap[~sphere_lamp].sort_values().tail()
    assert gap[sphere_lamp].max() <= 0.5, gap[sphere_lamp].sort_values().tail()
    torus = auto.index.get_level_values("set") == "torus"  # rendered by Mitsuba both times: the same rows
    pd.testing.assert_frame_equal(auto[torus].drop(columns=RUN_COLUMNS), mitsuba[torus].drop(columns=RUN_COLUMNS))


def test_closed_form_names_what_it_does_not_cover(tmp_path):
    doc = {**copy.deepcopy(SWEEP), "renderer": "closed-form"}
    path = tmp_path / "cf.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(UserError, match=r"cf.yaml: .*object.type torus: a triangle mesh .*renderer: auto"):
        load_sweep(path)
    doc["axes"]["set"].pop("torus")
    path.write_text(yaml.safe_dump(doc))
    sweep = load_sweep(path)
    assert sweep.renderer.extra is None and not sweep.renderer.prerender  # numpy only, nothing to cache
    assert {sweep.renderer.used_by(t.scene) for t in sweep.tasks} == {"closed-form"}


def test_the_report_says_which_renderer_made_the_rows(tmp_path):
    from nearlight.evaluation.views.report import renderers_line

    rows = pd.DataFrame({"renderer": ["closed-form"] * 5 + ["mitsuba"] * 2})
    assert renderers_line(rows) == "rendered by closed-form (5 tasks), mitsuba (2)"
    assert renderers_line(rows.iloc[:5]) == "rendered by closed-form"


def test_a_worker_renders_a_closed_form_scene_once_and_each_task_gets_its_own_capture(monkeypatch):
    """The per-worker cache: the second task of a render takes the kept arrays (no second render), its capture is
    the uncached one exactly, another analyzer stack of the same render is assembled for its own angles, and a
    task that scribbles on its capture leaves the next task's untouched."""
    import numpy as np

    from nearlight.evaluation.engine import renderers
    from nearlight.files.yamlfile import load_yaml_file
    from nearlight.generator import closed_form, load_scene

    scene = load_yaml_file(ROOT / "scenes" / "ts_board.yaml", what="scene file")
    scene["camera"]["resolution"] = [32, 24]
    scene["lamp"]["position"] = [0.0512, 0.1498, 0.3501]  # a render no other test keeps
    calls = []
    real = closed_form.closed_form_arrays
    monkeypatch.setattr(closed_form, "closed_form_arrays", lambda s: calls.append(1) or real(s))
    r = renderers.ClosedFormRenderer()
    first = r.render(scene, cache_dir=None)
    first.stack[...] = -1.0  # a task that changes its capture in place
    first.extra["S0"][...] = -1.0
    again = r.render(scene, cache_dir=None)
    three = copy.deepcopy(scene)
    three["capture"] = {**scene.get("capture", {}), "analyzer_angles_deg": [0, 60, 120]}
    other = r.render(three, cache_dir=None)
    assert len(calls) == 1
    plain = closed_form.render_closed_form(load_scene(copy.deepcopy(scene)))
    np.testing.assert_array_equal(again.stack, plain.stack)
    np.testing.assert_array_equal(again.extra["S0"], plain.extra["S0"])
    np.testing.assert_array_equal(other.stack, closed_form.render_closed_form(load_scene(three)).stack)
    assert other.stack.shape[0] == 3


def test_the_summary_counts_tasks_that_rendered_their_own(tmp_path):
    """``auto`` renders a closed-form scene in its task, a mesh ahead with Mitsuba: the summary says which is
    which (it said every closed-form task "re-used a render" before)."""
    sweep = {**copy.deepcopy(SWEEP), "axes": {"set": {"board": {}, "torus": SWEEP["axes"]["set"]["torus"]}},
             "seeds": 1, "set": {"camera.resolution": [16, 12]}}  # fmt: skip
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(sweep))
    s = run_sweep(load_sweep(path), tmp_path / "out", progress=False)
    assert (s.ran, s.rendered, s.reused, s.own) == (2, 1, 0, 1)
    assert "1 rendered, 0 task(s) re-used a render, 1 task(s) rendered their own" in s.line()
