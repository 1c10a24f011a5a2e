"""Suites of several scenes (`parts`): each part a named sweep with its own scene (camera) and axes, the
suite's `set`/`axes`/`seeds` shared; cases numbered across parts, categories naming the part; the pin
covers the part list. Analytic parts (no Mitsuba) except one tiny rendered suite, and the shipped
paper-v1 file."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from nearlight.capture import read_capture
from nearlight.cli import main
from nearlight.errors import UserError
from nearlight.evaluation.suites.suite import PART, load_suite, read_manifest

from .test_build import pinned_suite_file

REPO = Path(__file__).resolve().parents[3]
#: Two analytic parts with their own cameras (image sizes, positions) and objects, each with its own
#: lamp distances; both share the noise axis: board 2 x 2 + sphere 1 x 2 = 6 cases.
SUITE = {
    "name": "parts-v1",
    "version": 1,
    "renderer": "analytic",
    "axes": {"noise": {"clean": None, "sensor": {"full_well": 20000, "read_noise": 2.0, "saturation": 1.0}}},
    "seeds": [0],
    "parts": [
        {"name": "board", "scene": {"width": 32, "height": 24, "camera_position": [0.0, -0.35, 0.5]},
         "axes": {"lamp_distance": [0.3, 0.5]}},
        {"name": "sphere", "scene": {"shape": "sphere", "width": 20, "height": 20, "camera_position": [0.0, -0.6, 0.4],
                                     "lamp_position": [0.2, -0.1, 0.5]}, "axes": {"lamp_distance": [0.4]}},
    ],
}  # fmt: skip
#: (part, noise, lamp_distance) of each case, in case order: parts in order, each part's product in axis order
#: (the shared axes first, then the part's own).
CASES = [("board", "clean", 0.3), ("board", "clean", 0.5), ("board", "sensor", 0.3), ("board", "sensor", 0.5),
         ("sphere", "clean", 0.4), ("sphere", "sensor", 0.4)]  # fmt: skip


def write_suite(folder: Path, doc: dict | None = None) -> Path:
    """``doc`` (default the two-part suite) in ``folder``, pinned to its own cases."""
    return pinned_suite_file(folder, copy.deepcopy(SUITE if doc is None else doc))


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("parts")
    path = write_suite(root)
    assert main(["suite", "build", str(path), "--out", str(root / "built"), "--quiet", "--no-cache"]) == 0
    return path, root / "built"


def test_cases_are_numbered_across_parts_and_name_their_part(built):
    path, out = built
    suite = load_suite(path)
    assert suite.categories == [PART, "noise", "lamp_distance"]  # default: the part, then every axis
    m = read_manifest(out)
    assert m["categories"] == suite.categories
    got = [(c["categories"]["part"], c["categories"]["noise"], c["categories"]["lamp_distance"]) for c in m["cases"]]
    assert got == CASES
    assert [c["path"] for c in m["cases"]] == [f"cases/{i:03d}" for i in range(len(CASES))]
    # each part's own camera: the board's 32x24 images, the sphere's 20x20, on input and truth alike
    for c in m["cases"]:
        shape = (24, 32) if c["categories"]["part"] == "board" else (20, 20)
        for sub in ("input", "truth"):
            assert read_capture(out / c["path"] / sub).stack.shape[1:3] == shape, (c["path"], sub)
    # the shared noise axis reached both parts: noisy inputs differ from their truth, clean ones do not
    for i in (2, 5):
        c = m["cases"][i]
        assert not np.array_equal(read_capture(out / c["path"] / "input").stack, read_capture(out / c["path"] / "truth").stack)
    c = m["cases"][4]
    assert np.array_equal(read_capture(out / c["path"] / "input").stack, read_capture(out / c["path"] / "truth").stack)


def test_built_parts_verify_and_rebuild_identically(built, tmp_path, capsys):
    path, out = built
    assert main(["suite", "verify", str(out)]) == 0
    assert main(["suite", "build", str(path), "--out", str(tmp_path / "again"), "--quiet", "--no-cache"]) == 0
    capsys.readouterr()
    assert main(["suite", "verify", str(tmp_path / "again"), "--against", str(out)]) == 0
    assert f"{len(CASES)} case(s) identical, 0 within the tolerance, 0 beyond it" in capsys.readouterr().out


def _edited(doc: dict, edit: str) -> dict:
    doc = copy.deepcopy(doc)
    parts = doc["parts"]
    if edit == "drop a part":
        parts.pop()
    elif edit == "reorder the parts":
        parts.reverse()
    elif edit == "rename a part":
        parts[1]["name"] = "ball"
    elif edit == "add a part":
        parts.append({"name": "board-2", "scene": {"width": 32, "height": 24, "board_size": 0.3}, "axes": {"lamp_distance": [0.3]}})
    elif edit == "change a part's axis":
        parts[0]["axes"]["lamp_distance"] = [0.3, 0.6]
    elif edit == "change a part's scene":
        parts[1]["scene"]["width"] = 22
    elif edit == "change a shared axis":
        doc["axes"]["noise"]["sensor"]["read_noise"] = 3.0
    return doc


@pytest.mark.parametrize("edit", ["drop a part", "reorder the parts", "rename a part", "add a part",
                                  "change a part's axis", "change a part's scene", "change a shared axis"])  # fmt: skip
def test_cases_hash_refuses_an_edited_part_list(tmp_path, edit):
    """The pin covers the part list: its order (case numbers), its names (a case's categories name its
    part, so the name is in the case id) and every part's cases."""
    pinned = yaml.safe_load(write_suite(tmp_path).read_text())["cases_hash"]
    path = tmp_path / "parts-v1.yaml"
    path.write_text(yaml.safe_dump({**_edited(SUITE, edit), "cases_hash": pinned}, sort_keys=False))
    with pytest.raises(UserError, match=rf"parts-v1\.yaml: cases_hash: the cases hash to [0-9a-f]{{16}}, the file pins {pinned}"):
        load_suite(path)


def test_one_scene_in_two_parts_is_two_cases(tmp_path):
    """The part's name is in the case id: two parts may hold the same capture (e.g. a scene under two
    names for two categories) without their cases, manifest entries or score rows colliding."""
    doc = copy.deepcopy(SUITE)
    doc["parts"] = [{"name": n, "scene": {"width": 16, "height": 12}} for n in ("a", "b")]
    suite = load_suite(write_suite(tmp_path, doc))
    assert len(suite.cases) == 4 and len({c.case_id for c in suite.cases}) == 4
    assert [c.task.render_key for c in suite.cases[:2]] == [c.task.render_key for c in suite.cases[2:]]  # one render each


def test_part_keys_override_the_shared_ones(tmp_path):
    doc = copy.deepcopy(SUITE)
    doc["set"] = {"width": 40, "height": 30}
    doc["parts"][1]["set"] = {"width": 20}  # the part's value wins; height stays the shared 30
    doc["parts"][1]["axes"]["noise"] = {"clean": None}  # the part's noise axis replaces the shared one
    doc["parts"][1]["seeds"] = [3]
    suite = load_suite(write_suite(tmp_path, doc))
    board, sphere = suite.parts["board"], suite.parts["sphere"]
    assert (board.tasks[0].scene["width"], board.tasks[0].scene["height"]) == (40, 30)  # set over the part's scene
    assert (sphere.tasks[0].scene["width"], sphere.tasks[0].scene["height"]) == (20, 30)
    assert [c.categories for c in suite.cases if c.categories[PART] == "sphere"] == [
        {"part": "sphere", "noise": "clean", "lamp_distance": 0.4}]
    assert [c.task.seed for c in suite.cases] == [0, 0, 0, 0, 3]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"parts": []}, r"bad\.yaml: parts: expected a non-empty list of parts"),
        ({"parts": [{"scene": {}}]}, r"bad\.yaml: parts\[0\]: expected a mapping with a name"),
        ({"parts": [{"name": "a", "scene": {}}, {"name": "a", "scene": {}}]}, r"bad\.yaml: parts\[1\]\.name: 'a' names two parts"),
        ({"parts": [{"name": "a", "scene": {}, "renderer": "mitsuba"}]}, r"bad\.yaml: parts\.a\.renderer: unknown key"),
        ({"parts": [{"name": "a"}]}, r"bad\.yaml: parts\.a\.scene: missing"),
        ({"scene": {}}, r"bad\.yaml: scene: not a key of a suite with parts"),
        ({"parts": [{"name": "a", "scene": {}, "axes": {"colour": [1]}}]}, r"bad\.yaml: parts\.a\.axes\.colour: unknown axis"),
        ({"parts": [{"name": "a", "scene": {"widht": 3}}]}, r"bad\.yaml: parts\.a\.scene"),
        ({"parts": [{"name": "a", "scene": {}, "axes": {"lamp_distance": [0.3]}},
                    {"name": "b", "scene": {}, "axes": {"lamp_distance": {"near": 0.3}}}]},
         r"bad\.yaml: axes\.lamp_distance: its parts give it values of different kinds"),
        ({"parts": [{"name": "a", "scene": {}, "axes": {"lamp_distance": [0.3]}}, {"name": "b", "scene": {}}]},
         r"bad\.yaml: parts\.b\.axes: noise; the first part has noise, lamp_distance: every part has the same axes"),
        ({"categories": ["part", "colour"]}, r"bad\.yaml: categories: expected a list of the suite's axes \(part, noise, lamp_distance\)"),
    ],
)  # fmt: skip
def test_bad_part_files_are_one_line_errors(tmp_path, capsys, change, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({**SUITE, "cases_hash": "0", **change}))
    assert main(["suite", "build", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert not (tmp_path / "out").exists()


def test_score_groups_by_part_and_compare_matches_every_case(built, tmp_path, capsys):
    """`distant` on the two parts: a group per part and per value of each axis over both parts (the
    sphere's 0.4 m beside the board's 0.3 and 0.5 m); `compare` finds every case of a run in itself."""
    _, out = built
    assert main(["score", str(out), "--method", "distant", "--out", str(tmp_path / "d"), "--quiet"]) == 0
    card = json.loads((tmp_path / "d" / "scorecard.json").read_text())
    groups = [(g["category"], g["value"], g["n"]) for g in card["groups"]]
    assert groups == [("all", "all", 6), ("part", "board", 4), ("part", "sphere", 2), ("noise", "clean", 3),
                      ("noise", "sensor", 3), ("lamp_distance", 0.3, 2), ("lamp_distance", 0.5, 2),
                      ("lamp_distance", 0.4, 2)]  # fmt: skip
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "d"), str(tmp_path / "d")]) == 0
    assert "0 worse, 0 missing, 0 better" in capsys.readouterr().out


def test_paper_v1_holds_the_reproductions_scenes():
    """The shipped paper-v1: six parts, each at the quick size with its own scene's camera, clean and
    12-bit, ideal and bench; 24 cases, categories part, noise, realism."""
    suite = load_suite(REPO / "suites" / "paper-v1.yaml")
    assert list(suite.parts) == ["ward-board", "ts-board", "bookend", "torus", "cylinder", "sphere"]
    assert len(suite.cases) == 24 and suite.categories == [PART, "noise", "realism"]
    cams = set()
    for name, sweep in suite.parts.items():
        scene = sweep.tasks[0].scene
        assert scene["camera"]["resolution"] == [160, 120] and scene["capture"]["analyzer_angles_deg"] == [0, 45, 90, 135]
        cams.add(tuple(scene["camera"]["position"]))
        assert {(c.categories["noise"], c.categories["realism"]) for c in suite.cases if c.categories[PART] == name} == {
            ("clean", "none"), ("clean", "bench"), ("real_camera", "none"), ("real_camera", "bench")}
    assert len(cams) == 6  # six cameras: why they are parts, not one sweep


@pytest.mark.render
def test_a_rendered_suite_with_two_parts(tmp_path):
    """Two tiny Mitsuba parts (16x12) with different cameras build, and each case's capture has its part's
    image size (the render path's per-case sweep, not only the analytic one)."""
    base = {"object": {"type": "board", "size": [0.4, 0.4]},
            "material": {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.1, "kd": [0.3, 0.4, 0.35]},
            "lamp": {"position": [0.05, 0.15, 0.35], "intensity": [2.0, 2.0, 2.0]},
            "capture": {"analyzer_angles_deg": [0, 45, 90, 135]}}  # fmt: skip
    cam = {"look_at": [0.0, 0.0, 0.0], "fov_x_deg": 50.0}
    doc = {"name": "mitsuba-parts-v1", "version": 1, "renderer": "mitsuba", "parts": [
        {"name": "near", "scene": {**base, "camera": {**cam, "position": [0.0, -0.35, 0.5], "resolution": [16, 12]}}},
        {"name": "far", "scene": {**base, "camera": {**cam, "position": [0.1, -0.5, 0.7], "resolution": [12, 12]}}}]}  # fmt: skip
    out = tmp_path / "built"
    assert main(["suite", "build", str(write_suite(tmp_path, doc)), "--out", str(out), "--quiet", "--no-cache"]) == 0
    m = read_manifest(out)
    assert [c["categories"] for c in m["cases"]] == [{"part": "near"}, {"part": "far"}]
    assert [read_capture(out / c["path"] / "truth").stack.shape[1:3] for c in m["cases"]] == [(12, 16), (12, 12)]
    assert main(["suite", "verify", str(out)]) == 0
