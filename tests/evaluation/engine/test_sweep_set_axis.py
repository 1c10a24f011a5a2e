"""The ``set`` axis of sweep files: a one-at-a-time design, each label its own scene overrides."""

from __future__ import annotations

import copy
import re

import pytest
import yaml

from nearlight.errors import UserError
from nearlight.evaluation.engine.sweep import load_sweep

#: A Mitsuba board at 64x48 with one lamp (``lamp``, so labels can set ``lamp.*``); loading it renders nothing.
BOARD = {
    "name": "board",
    "renderer": "mitsuba",
    "scene": {
        "camera": {"position": [0.0, -0.35, 0.5], "look_at": [0.0, 0.0, 0.0], "fov_x_deg": 50.0,
                   "resolution": [64, 48]},
        "object": {"type": "board", "size": [0.4, 0.4]},
        "material": {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.1, "kd": [0.3, 0.4, 0.35]},
        "lamp": {"position": [0.05, 0.15, 0.35], "intensity": [2.0, 2.0, 2.0]},
        "capture": {"analyzer_angles_deg": [0, 45, 90, 135], "spp": 4},
    },
    "axes": {"lamp_distance": [0.3, 0.5], "noise": {"none": None, "sensor": {"full_well": 20000, "read_noise": 5.0,
                                                                             "bits": 12}}},
}  # fmt: skip


def _smoke(**change):
    """:data:`BOARD` with ``change``."""
    doc = copy.deepcopy(BOARD)
    doc.update(seeds=3, methods=["full"], **change)
    return doc


def _write(tmp_path, doc):
    path = tmp_path / "x.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.mark.parametrize(
    "axis, expect",
    [
        ([{"lamp.radius": 0.01}], "axes.set: expected a mapping of labels to mappings of dotted scene keys"),
        ({"foo": 3}, "axes.set: 'foo': expected a mapping of dotted scene keys"),
        ({"foo": [["lamp.radius", 0.01]]}, "axes.set: 'foo': expected a mapping of dotted scene keys"),
        ({"ok": {}, "foo": {"lamp.radiu": 0.01}}, "axes.set: 'foo': <scene>: lamp.radiu: unknown key"),
        ({"foo": {"lamp.radius": -1}}, "axes.set: 'foo': <scene>: lamp.radius:"),
        ({"foo": {"lamp.position.x": 0.1}}, "axes.set: 'foo': lamp.position: is not a section"),
        ({"foo": {"realism": "lax"}}, "axes.set: 'foo': <scene>: realism:"),
        ({"a": {"lamp.radius": 0.01}, "b": {"lamp.radius": 0.01}}, "axes.set: 'b': the same keys and values as 'a'"),
        ({}, "axes.set: expected at least one value"),
    ],
)
def test_a_bad_set_axis_is_one_line_naming_file_axis_and_label(tmp_path, axis, expect):
    path = _write(tmp_path, _smoke(axes={"set": axis}))
    with pytest.raises(UserError) as err:
        load_sweep(path, check_methods=False)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    assert expect in msg, msg


def test_a_bad_key_for_the_analytic_renderer_is_rejected_by_its_validation(tmp_path):
    doc = {"name": "t", "renderer": "analytic", "scene": {"width": 32, "height": 24}, "methods": ["full"],
           "axes": {"set": {"wide": {"width": 40}, "typo": {"widht": 3}}}}
    with pytest.raises(UserError, match=r"x\.yaml: axes\.set: 'typo': widht: not an analytic_capture argument"):
        load_sweep(_write(tmp_path, doc))


def test_each_label_applies_its_own_overrides_and_is_the_set_column():
    base = load_sweep(_smoke(axes={}), check_methods=False).tasks[0].scene
    labels = {"none": {}, "radius 5 mm": {"lamp.radius": 0.005, "lamp.samples": 4},
              "vignetting": {"nuisances.camera.vignetting": 0.15}, "gamma": {"nuisances.camera.gamma": 2.2},
              "bench": {"realism": "bench"}}
    sweep = load_sweep(_smoke(axes={"set": labels, "lamp_distance": [0.3]}), check_methods=False)
    by = {t.config["set"]: t for t in sweep.tasks}
    assert list(by) == list(labels)  # file order, one column `set` holding the label
    assert [list(t.config) for t in sweep.tasks[:1]] == [["set", "lamp_distance"]]
    # `{}` is the base scene (with the other axes applied); a label changes only its own keys
    assert by["none"].scene == load_sweep(_smoke(axes={"lamp_distance": [0.3]}), check_methods=False).tasks[0].scene
    assert by["radius 5 mm"].scene["lamp"]["radius"] == 0.005 and by["radius 5 mm"].scene["lamp"]["samples"] == 4
    assert "radius" not in by["none"].scene["lamp"] and "radius" not in base["lamp"]
    assert by["vignetting"].scene["nuisances"] == {"camera": {"vignetting": 0.15}}
    assert by["bench"].scene["realism"] == "bench" and "nuisances" not in by["bench"].scene
    # lamp_distance is applied after the label (as after dotted-key axes): the lamp moves along its ray
    assert by["radius 5 mm"].scene["lamp"]["position"] == by["none"].scene["lamp"]["position"]


def test_post_render_labels_share_a_render_and_lamp_labels_do_not():
    # nuisances.* are applied after rendering (the generator's render_key leaves them out): one render
    # serves them all; a lamp radius changes the light reaching the surface: its own render per value.
    labels = {"none": {}, "vignetting": {"nuisances.camera.vignetting": 0.15},
              "offset": {"nuisances.analyzer.offset_deg": 0.5, "nuisances.camera.gamma": 2.2},
              "holes": {"nuisances.range.holes_shiny_above": 0.9},
              "radius 2 mm": {"lamp.radius": 0.002}, "radius 5 mm": {"lamp.radius": 0.005}}
    sweep = load_sweep(_smoke(axes={"set": labels}), check_methods=False)
    key = {t.config["set"]: t.render_key for t in sweep.tasks}
    assert key["vignetting"] == key["offset"] == key["holes"] == key["none"]
    assert len({key["none"], key["radius 2 mm"], key["radius 5 mm"]}) == 3
    assert len(sweep.render_keys) == 3


def test_a_per_shot_nuisance_under_a_label_runs_every_seed():
    # analyzer jitter and lamp flicker are drawn per shot from the seed (as the bench profile's are):
    # those labels are `noisy` and run seeds 0, 1, 2; the others are deterministic and run once.
    labels = {"none": {}, "offset": {"nuisances.analyzer.offset_deg": 0.5},
              "jitter": {"nuisances.analyzer.jitter_deg": 0.3}, "flicker": {"nuisances.camera.flicker": 0.01},
              "profile bench": {"realism": "bench"}, "bench without draws": {
                  "realism": "bench", "nuisances.analyzer.jitter_deg": 0.0, "nuisances.camera.flicker": 0.0}}
    sweep = load_sweep(_smoke(axes={"set": labels}), check_methods=False)
    seeds: dict[str, list[int]] = {}
    for t in sweep.tasks:
        seeds.setdefault(t.config["set"], []).append(t.seed)
        assert t.noisy == (t.config["set"] in ("jitter", "flicker", "profile bench"))
    assert seeds == {"none": [0], "offset": [0], "jitter": [0, 1, 2], "flicker": [0, 1, 2],
                     "profile bench": [0, 1, 2], "bench without draws": [0]}
    assert len({t.task_id for t in sweep.tasks}) == len(sweep.tasks)


def test_the_set_axis_is_a_product_with_the_other_axes_and_a_profile_can_replace_it():
    doc = _smoke(axes={"object": {"board": {"type": "board", "size": [0.4, 0.4]},
                                  "sphere": {"type": "sphere", "radius": 0.1}},
                       "set": {"none": {}, "kd texture": {"material.texture.kd_contrast": 0.3}}},
                 profiles={"quick": {"axes": {"set": {"none": {}}}}})
    sweep = load_sweep(doc, check_methods=False)
    assert [(t.config["object"], t.config["set"]) for t in sweep.tasks] == [
        ("board", "none"), ("board", "kd texture"), ("sphere", "none"), ("sphere", "kd texture")]
    assert sweep.tasks[3].scene["object"]["type"] == "sphere"
    assert sweep.tasks[3].scene["material"]["texture"] == {"kd_contrast": 0.3}
    assert [t.config["set"] for t in load_sweep(doc, check_methods=False, profile="quick").tasks] == ["none", "none"]


def test_a_dotted_key_may_end_in_an_index_of_a_list_of_numbers():
    """A study's input drives one number of a vector (``nuisances.calibration.position_m.0``); a name there, or an
    index past the end, stays a one-line error."""
    from nearlight.errors import UserError
    from nearlight.files.dotted import set_dotted

    doc = {"calibration": {"position_m": [0.0, 0.0, 0.0]}}
    set_dotted(doc, "calibration.position_m.0", 0.002, where="w")
    assert doc == {"calibration": {"position_m": [0.002, 0.0, 0.0]}}
    for key, says in (("calibration.position_m.x", "calibration.position_m: is not a section"),
                      ("calibration.position_m.3", "calibration.position_m.3: calibration.position_m is a list of 3")):
        with pytest.raises(UserError, match=re.escape(f"w: {says}")):
            set_dotted(doc, key, 1.0, where="w")
