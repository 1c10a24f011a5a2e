"""Sweep files: validation with one-line errors, expansion into tasks, axes applied to scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from nearlight.errors import UserError
from nearlight.evaluation.engine.sweep import load_sweep

BASE = {
    "name": "t",
    "renderer": "analytic",
    "scene": {"width": 32, "height": 24},
    "methods": ["full"],
}


def _write(tmp_path, doc, name="s.yaml"):
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.mark.parametrize(
    "change, expect",
    [
        ({"axes": {"lamp_distanse": [0.3]}}, "axes.lamp_distanse: unknown axis"),
        ({"axes": {"lamp_distance": [0.3, -1]}}, "axes.lamp_distance: -1: expected a positive number"),
        ({"axes": {"roughness": []}}, "axes.roughness: expected at least one value"),
        ({"axes": {"polarization": ["linear"]}}, "axes.polarization: 'linear': expected 'ideal' or 'fresnel'"),
        ({"axes": {"analyzer_angles": [2]}}, "axes.analyzer_angles: 2: expected an integer >= 3"),
        ({"axes": {"noise": ["loud"]}}, "axes.noise: 'loud': expected null or a mapping"),
        ({"axes": {"roughness": [0.1, 0.1]}}, "axes.roughness: duplicate value '0.1'"),
        ({"seeds": 0}, "seeds: expected a positive count"),
        ({"methods": []}, "methods: List should have at least 1 item"),
        ({"methods": ["nonsense"]}, "methods[0]: unknown method 'nonsense'"),
        ({"methods": ["full", "full"]}, "methods: duplicate method name 'full'"),
        ({"methods": [{"method": "distant", "options": {"n_starts": 3}}]},
         "methods[0]: option 'n_starts': not accepted by method distant"),
        ({"methods": [{"method": "paper", "options": {"threshold": -1}}]},
         "methods[0]: option threshold: Input should be greater than 0"),
        ({"colour": "red"}, "colour: Extra inputs are not permitted"),
        ({"scene": "missing.yaml"}, "scene: no such scene file"),
        ({"scene": {"widht": 3}}, "scene: widht: not an analytic_capture argument"),
        ({"axes": {"polarization": ["fresnel"]}}, "supports only 'ideal' polarization"),
        ({"set": {"width.x": 3}}, "set.width.x: width: is not a section"),
        ({"profiles": {"quick": {"axes": {"roughness": [0.1]}}}},
         "profiles.quick.axes.roughness: not an axis of the sweep"),
        ({"profiles": {"quick": {"resolution": 3}}}, "profiles.quick.resolution: Extra inputs are not permitted"),
    ],
)
def test_bad_sweep_files_give_one_line_errors(tmp_path, change, expect):
    path = _write(tmp_path, {**BASE, **change})
    with pytest.raises(UserError) as err:
        load_sweep(path)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(str(path)), msg
    assert expect in msg, msg


def test_not_yaml_and_not_a_mapping(tmp_path):
    with pytest.raises(UserError, match=r"s\.yaml: not valid YAML \(line 2\)"):
        load_sweep(_write(tmp_path, "name: x\n  bad: [\n"))
    with pytest.raises(UserError, match="expected a mapping of sweep keys"):
        load_sweep(_write(tmp_path, "- 1\n- 2\n"))
    with pytest.raises(UserError, match="no such sweep file"):
        load_sweep(tmp_path / "nope.yaml")


def test_unknown_module_function_is_one_line(tmp_path):
    for spec in ("no_such_module_xyz:fn", "math:no_such_function"):
        path = _write(tmp_path, {**BASE, "methods": ["full", spec]})
        with pytest.raises(UserError) as err:
            load_sweep(path)
        assert "\n" not in str(err.value) and "methods[1]" in str(err.value) and spec in str(err.value)


def test_expansion_product_order_and_shared_renders(tmp_path):
    doc = {
        **BASE,
        "axes": {
            "lamp_distance": [0.3, 0.5],
            "noise": {"none": None, "low": {"read_noise": 1.0}},
            "range_noise": [0.0, 0.001],
            "roughness": [0.05, 0.1, 0.2],
        },
        "seeds": [3, 4],
        "methods": ["full", {"name": "paper-fine", "method": "paper", "options": {"dt": 0.0005}}],
    }
    sweep = load_sweep(_write(tmp_path, doc))
    # 2 distances x 3 roughness x 2 methods x (2 seeds for each of the 3 noisy (noise, range noise)
    # pairs + 1 seed for the noise-free pair, whose numbers do not depend on the seed)
    assert len(sweep.tasks) == 2 * 3 * 2 * (3 * 2 + 1) == 84
    # noise, range noise, seed and method re-use a render: 2 x 3 physical configurations
    assert len(sweep.render_keys) == 6
    assert len({t.task_id for t in sweep.tasks}) == 84
    first = sweep.tasks[0]
    assert first.config == {"lamp_distance": 0.3, "noise": "none", "range_noise": 0.0, "roughness": 0.05}
    assert (first.seed, first.method.label) == (3, "full")
    assert sweep.tasks[1].method.label == "paper-fine" and sweep.tasks[1].method.options == {"dt": 0.0005}
    assert [t.seed for t in sweep.tasks[:2]] == [3, 3] and not first.noisy  # noise-free: one seed
    noisy = [t for t in sweep.tasks if t.noisy]
    assert [(t.seed, t.method.label) for t in noisy[:4]] == [(3, "full"), (3, "paper-fine"), (4, "full"), (4, "paper-fine")]
    low = [t for t in sweep.tasks if t.config["noise"] == "low"]
    assert low[0].noise == {"read_noise": 1.0} and low[0].render_key == first.render_key
    # ids are stable: loading again gives the same ids and hash
    again = load_sweep(_write(tmp_path, doc, "again.yaml"))
    assert [t.task_id for t in again.tasks] == [t.task_id for t in sweep.tasks]
    assert again.sweep_hash == sweep.sweep_hash


def test_axes_change_the_scene(tmp_path):
    doc = {
        **BASE,
        "scene": {"width": 32, "height": 24, "lamp_position": [0.05, 0.15, 0.35]},
        "axes": {"lamp_distance": [0.5], "bsdf": ["ward"], "roughness": [0.1], "analyzer_angles": [6],
                 "object": ["sphere"], "bsdf.kd": [[0.1, 0.2, 0.3]]},
    }
    scene = load_sweep(_write(tmp_path, doc)).tasks[0].scene
    # lamp moved along the ray from the sphere centre (analytic_capture's default, filled into the scene)
    centre = np.array(scene["sphere_centre"])
    assert np.linalg.norm(centre) > 0  # the sphere's centre, not the board's origin
    ray = np.array([0.05, 0.15, 0.35]) - centre
    assert np.allclose(scene["lamp_position"], centre + 0.5 * ray / np.linalg.norm(ray))
    assert scene["shape"] == "sphere"
    # ward from the default TS material: alpha = sqrt(2) * roughness; rho_s = 4 pi alpha^2 ks (peak-matched)
    assert scene["bsdf"]["model"] == "ward" and scene["bsdf"]["alpha"] == pytest.approx(math.sqrt(2) * 0.1)
    assert np.allclose(scene["bsdf"]["rho_s"], 4 * math.pi * 0.02 * np.array([0.8, 0.6, 0.5]))
    assert scene["analyzer_angles_deg"] == [0.0, 30.0, 60.0, 90.0, 120.0, 150.0]
    assert scene["bsdf"]["kd"] == [0.1, 0.2, 0.3]


def test_a_profile_overrides_set_keys_and_axis_values(tmp_path):
    # A profile is the same experiment, smaller: its set after the file's, its axes replacing those values.
    doc = {**BASE, "set": {"width": 64, "height": 48}, "axes": {"lamp_distance": [0.3, 0.5, 0.7], "roughness": [0.1]},
           "profiles": {"quick": {"set": {"width": 16}, "axes": {"lamp_distance": [0.3]}}}}
    path = _write(tmp_path, doc)
    full, quick = load_sweep(path), load_sweep(path, profile="quick")
    assert (full.profile, quick.profile) == (None, "quick")
    assert [t.config["lamp_distance"] for t in full.tasks] == [0.3, 0.5, 0.7]
    assert [t.config["lamp_distance"] for t in quick.tasks] == [0.3]
    assert (full.tasks[0].scene["width"], quick.tasks[0].scene["width"]) == (64, 16)
    assert quick.tasks[0].scene["height"] == 48 and quick.sweep_hash != full.sweep_hash
    with pytest.raises(UserError, match=r"s\.yaml: profiles: no profile 'tiny' \(the file has quick\)"):
        load_sweep(path, profile="tiny")


def test_the_paper_sweeps_load_in_both_profiles():
    # sweeps/paper/*.yaml (what `nearlight reproduce` runs): valid as written (full) and with --quick.
    from nearlight.evaluation.paper.reproduce import EXPERIMENTS, load_sweeps

    for quick in (False, True):
        sweeps = load_sweeps(quick=quick)
        assert list(sweeps) == list(EXPERIMENTS)
        # the paper's experiments at 640x480 (quick: 160x120); the first-stage distribution study
        # renders 24 jittered cameras at 320x240 to stay within reproduce's 5-minute budget
        full = {"paper-first-stage": [320, 240], "paper-first-stage-corrected": [320, 240]}
        for s in sweeps.values():
            assert s.tasks[0].scene["camera"]["resolution"] == ([160, 120] if quick else full.get(s.name, [640, 480]))
            assert {t.seed for t in s.tasks} == {0} and not s.crlb


@pytest.mark.parametrize("name", ["bookend", "curved"])
def test_the_bench_seed_sweeps_are_the_paper_experiments_over_20_seeds(name):
    # sweeps/bench_seeds/*.yaml (issue 35's check of what the range quantum costs on the bench rig): the paper
    # sweep's scene, rig and camera, its bench rows with and without the quantum, `full` over seeds 0-19
    from pathlib import Path

    root = Path(__file__).resolve().parents[3] / "sweeps"
    paper, seeds = load_sweep(root / "paper" / f"{name}.yaml"), load_sweep(root / "bench_seeds" / f"{name}.yaml")
    bench = [t for t in paper.tasks if t.config["set"] in ("bench", "bench, range not quantised") and t.method.label == "full"]
    assert {t.seed for t in seeds.tasks} == set(range(20)) and {t.method.label for t in seeds.tasks} == {"full"}
    for label in ("bench", "bench, range not quantised"):
        ours = [t for t in seeds.tasks if t.config["set"] == label]
        theirs = [t for t in bench if t.config["set"] == label]
        assert len(ours) == 20 and len(theirs) == 1
        assert all(t.scene == theirs[0].scene for t in ours)


def test_realism_axis_and_per_shot_nuisances_run_every_seed():
    """`realism` is an axis (a top-level scene key); a configuration whose captures draw per-shot
    nuisances from the seed (lab: analyzer jitter, lamp flicker) runs every seed, as noise does,
    and its rows say so (`noisy`), so `compare` pools them; `none` and a jitter-free dotted
    nuisance run once."""
    from pathlib import Path

    smoke = Path(__file__).resolve().parents[3] / "sweeps" / "smoke.yaml"
    doc = yaml.safe_load(smoke.read_text())
    doc.update(seeds=3, methods=["full"], axes={"realism": ["none", "lab"],
                                               "nuisances.camera.vignetting": [0.0, 0.1]})
    sweep = load_sweep(doc, check_methods=False)
    by = {}
    for t in sweep.tasks:
        by.setdefault((t.config["realism"], t.config["nuisances.camera.vignetting"]), []).append(t)
    assert {k: [t.seed for t in v] for k, v in by.items()} == {
        ("none", 0.0): [0], ("none", 0.1): [0], ("lab", 0.0): [0, 1, 2], ("lab", 0.1): [0, 1, 2]}
    assert all(t.noisy == (t.config["realism"] == "lab") for t in sweep.tasks)
    assert sweep.tasks[0].scene.get("realism", "none") == "none" and by[("lab", 0.0)][0].scene["realism"] == "lab"
    # the lab lamp has a radius: a different render; vignetting is applied after rendering: the same one
    assert by[("lab", 0.0)][0].render_key != by[("none", 0.0)][0].render_key
    assert by[("none", 0.1)][0].render_key == by[("none", 0.0)][0].render_key


def test_a_jittering_camera_renders_once_per_seed():
    """`camera.jitter_px` moves the camera per shot: a noise-free configuration runs every seed, each seed
    its own render (the task's scene carries it as `capture.seed`, so `nearlight render` with that seed
    makes the same capture); without jitter nothing changes."""
    from pathlib import Path

    doc = yaml.safe_load((Path(__file__).resolve().parents[3] / "sweeps" / "smoke.yaml").read_text())
    doc.update(seeds=[2, 5, 7], methods=["full", "distant"], axes={"camera.jitter_px": [0.0, 0.5]})
    sweep = load_sweep(doc, check_methods=False)
    still = [t for t in sweep.tasks if t.config["camera.jitter_px"] == 0.0]
    moving = [t for t in sweep.tasks if t.config["camera.jitter_px"] == 0.5]
    assert [t.seed for t in still] == [2, 2] and not any(t.noisy for t in still)
    assert [t.seed for t in moving] == [2, 2, 5, 5, 7, 7] and all(t.noisy for t in moving)
    assert [t.scene["capture"]["seed"] for t in moving] == [t.seed for t in moving]
    keys = [t.render_key for t in moving]
    assert keys[0] == keys[1] and len(set(keys)) == 3 and still[0].render_key not in keys
    assert len({t.task_id for t in sweep.tasks}) == len(sweep.tasks)


def test_an_object_axis_of_another_type_keeps_only_the_placement():
    from pathlib import Path

    doc = yaml.safe_load((Path(__file__).resolve().parents[3] / "sweeps" / "smoke.yaml").read_text())
    doc["scene"]["object"]["position"] = [0.0, 0.0, 0.01]
    doc.update(seeds=1, methods=["full"], axes={"object": {"board": {"type": "board", "size": [0.3, 0.3]},
                                                           "sphere": {"type": "sphere", "radius": 0.1}}})
    board, sphere = (t.scene["object"] for t in load_sweep(doc, check_methods=False).tasks)
    assert board == {"type": "board", "size": [0.3, 0.3], "position": [0.0, 0.0, 0.01]}
    assert sphere == {"type": "sphere", "radius": 0.1, "position": [0.0, 0.0, 0.01]}


def test_a_labelled_bsdf_axis_takes_a_mitsuba_material_whole():
    """sweeps/render_compare.yaml: a ``bsdf`` label may be a material mapping (was a TypeError: a dict is not
    hashable); a ``model: mitsuba`` material is the whole BSDF, so the base's ``kd`` is not carried into it
    (was "material.kd: unknown key"), while a lobe family of ours keeps it."""
    from pathlib import Path

    sweep = load_sweep(Path(__file__).resolve().parents[3] / "sweeps" / "render_compare.yaml")
    material = {t.config["bsdf"]: t.scene["material"] for t in sweep.tasks}
    assert set(material) == {"torrance_sparrow", "ward", "pplastic"}
    assert material["pplastic"]["model"] == "mitsuba" and "kd" not in material["pplastic"]
    assert material["pplastic"]["bsdf"]["type"] == "pplastic"
    assert material["ward"]["model"] == "ward" and material["ward"]["kd"] == [0.3, 0.4, 0.35]
    assert len(sweep.tasks) == 4 * 3 * 3 * 2 * 4  # distances x cameras x materials x objects x methods, one seed
