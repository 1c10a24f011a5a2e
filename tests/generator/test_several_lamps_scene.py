"""Scene files with several lamps: ``lamps:`` lists, ``lamp:`` as a one-element list, ``--set`` on lamps.

No rendering here. Golden values: the scene files themselves (their positions, typed in
``scenes/two_lamps.yaml``), and the one-lamp scenes' dumps and render keys as they were before
``lamps:`` existed (measured at commit e8b09ea, the branch's base: a one-lamp scene must not
change by a bit).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from nearlight.cli import main
from nearlight.errors import UserError
from nearlight.generator import load_scene
from nearlight.generator.render import render_key
from nearlight.generator.scene import MAX_SCENE_LAMPS, Scene, SeveralLampsError

SCENES = Path(__file__).resolve().parents[2] / "scenes"
TWO = SCENES / "two_lamps.yaml"


def two_lamp_doc() -> dict:
    """The ts_board scene as a document with a second lamp (mirrored in x), ``lamps:`` form."""
    doc = load_scene(SCENES / "ts_board.yaml").model_dump(mode="json")
    lamp = doc.pop("lamp")
    doc["lamps"] = [lamp, {**lamp, "position": [-0.10, 0.25, 0.45]}]
    return doc


def test_one_lamp_scenes_dump_and_key_as_before():
    # Golden: render keys of the shipped scenes at e8b09ea (before lamps:), printed there by
    # render_key(load_scene(...)); the dump keeps its v1 key "lamp" in its place.
    scene = load_scene(SCENES / "ts_board.yaml")
    assert list(scene.model_dump(mode="json")) == ["camera", "object", "material", "lamp", "capture", "realism",
                                                   "nuisances"]  # fmt: skip
    assert render_key(load_scene(SCENES / "ts_board.yaml", overrides={"camera.resolution": [64, 48]})) == \
        "7b3792235e1db7e28c241437"
    assert len(scene.lamps) == 1 and scene.lamp is scene.lamps[0]
    assert scene.lamp.position == (0.10, 0.25, 0.45)


def test_lamp_and_a_one_element_lamps_list_are_the_same_scene():
    doc = load_scene(SCENES / "ts_board.yaml").model_dump(mode="json")
    listed = {("lamps" if k == "lamp" else k): ([v] if k == "lamp" else v) for k, v in doc.items()}
    a, b = load_scene(doc), load_scene(listed)
    assert a == b and render_key(a) == render_key(b)
    assert b.model_dump(mode="json") == doc  # one lamp always dumps as lamp:


def test_two_lamps_load_dump_and_round_trip():
    scene = load_scene(two_lamp_doc())
    assert len(scene.lamps) == 2 and [lamp.position for lamp in scene.lamps] == [(0.10, 0.25, 0.45),
                                                                               (-0.10, 0.25, 0.45)]  # fmt: skip
    doc = scene.model_dump(mode="json")
    assert "lamp" not in doc and len(doc["lamps"]) == 2
    assert list(doc).index("lamps") == 3  # where lamp: was
    assert load_scene(doc) == scene
    # each lamp's filter faces the object from its own position
    assert np.allclose(scene.facing(1), -np.array([-0.10, 0.25, 0.45]) / np.linalg.norm([-0.10, 0.25, 0.45]))
    # the render key depends on every lamp
    other = load_scene(two_lamp_doc(), overrides={"lamps.1.position": [-0.10, 0.25, 0.46]})
    assert render_key(other) != render_key(scene)


def test_scene_lamp_of_several_lamps_is_a_clear_error():
    scene = load_scene(two_lamp_doc())
    for attribute in ("lamp", "lamp_facing", "lamp_is_v1"):
        with pytest.raises(SeveralLampsError, match="the scene has 2 lamps .*use Scene.lamps"):
            getattr(scene, attribute)


def test_overrides_address_lamps_either_way():
    one = SCENES / "ts_board.yaml"
    # lamp.<key> on a one-lamp scene, as before; lamps.0.<key> is the same lamp
    assert load_scene(one, overrides=["lamp.position=[0.2, 0.1, 0.3]"]).lamp.position == (0.2, 0.1, 0.3)
    assert load_scene(one, overrides=["lamps.0.intensity=[1, 2, 3]"]).lamp.intensity == (1.0, 2.0, 3.0)
    # lamps.<i>.<key> on a lamps: list; lamp.<key> too when the list has one lamp
    two = load_scene(TWO, overrides=["lamps.1.intensity=[3, 3, 3]", "lamps.0.radius=0.002"])
    assert two.lamps[1].intensity == (3.0, 3.0, 3.0) and two.lamps[0].radius == 0.002 and two.lamps[1].radius == 0
    single = two_lamp_doc()
    single["lamps"] = single["lamps"][:1]
    assert load_scene(single, overrides=["lamp.position=[0.2, 0.1, 0.3]"]).lamp.position == (0.2, 0.1, 0.3)
    # setting lamps (or lamp) whole replaces the scene's lamps
    replaced = load_scene(one, overrides=["lamps=[{position: [0.1, 0.2, 0.4]}, {position: [-0.1, 0.2, 0.4]}]"])
    assert [lamp.position for lamp in replaced.lamps] == [(0.1, 0.2, 0.4), (-0.1, 0.2, 0.4)]
    assert load_scene(TWO, overrides=["lamp={position: [0.1, 0.2, 0.4]}"]).lamp.position == (0.1, 0.2, 0.4)


def test_realism_profile_fills_in_every_lamp(tmp_path):
    # bench: polarizer_extinction_ratio 300, anisotropy_k 1, radius 5 mm (generator/realism.py); keys a lamp sets win
    scene = load_scene(TWO, overrides=["realism=bench", "lamps.1.radius=0.001"])
    assert [lamp.polarizer_extinction_ratio for lamp in scene.lamps] == [300.0, 300.0]
    assert [lamp.anisotropy_k for lamp in scene.lamps] == [1.0, 1.0]
    assert [lamp.radius for lamp in scene.lamps] == [0.005, 0.001]


@pytest.mark.parametrize(
    ("source", "overrides", "expect"),
    [
        ("two", ["lamp.position=[0, 0, 1]"], "lamp.position: the scene has 2 lamps (lamps:); address one as "
                                             "lamps.<i>.position, i from 0 to 1"),
        ("two", ["lamps.2.position=[0, 0, 1]"], "lamps.2.position: no lamp '2': the scene has 2 lamps"),
        ("two", ["lamps.-1.position=[0, 0, 1]"], "lamps.-1.position: no lamp '-1'"),
        ("two", ["lamps.one.position=[0, 0, 1]"], "lamps.one.position: no lamp 'one'"),
        ("one", ["lamps.1.position=[0, 0, 1]"], "lamps.1.position: no lamp '1': the scene has 1 lamp (lamps.0 (or lamp))"),
        ("two", ["lamps.1.position=[1, 2]"], "lamps.1.position: too few items"),
        ("two", ["lamps.1.colour=red"], "lamps.1.colour: unknown key"),
        ("two", ["lamps.1.polarizer_axis=[0.1294, -0.2352, -0.4218]"],
         "lamps.1.polarizer_axis: points from the lamp at the object"),
        ("two", ["lamps.1.position=[0, 0, 0]"], "lamps.1.position: must differ from object.position"),
        ("two", ["lamps.1.polarizer_extinction_ratio=100"],
         "lamps.1.polarizer_extinction_ratio: every lamp's filter must have the same extinction ratio"),
        ("two", ["lamps=[]"], "lamps: Tuple should have at least 1 item"),
        ("two", [f"lamps={[{'position': [0.1, 0.2, 0.3 + i / 100]} for i in range(MAX_SCENE_LAMPS + 1)]}"],
         f"lamps: Tuple should have at most {MAX_SCENE_LAMPS} items"),
        ("one", ["lamp.position=[1, 2]"], "lamp.position: too few items"),  # v1's messages are unchanged
        ("one", ["lamp=3"], "lamp: Input should be a valid dictionary"),
    ],
)
def test_bad_lamps_are_one_line_errors_naming_the_key(source, overrides, expect):
    with pytest.raises(UserError) as err:
        load_scene(TWO if source == "two" else SCENES / "ts_board.yaml", overrides=overrides)
    msg = str(err.value)
    assert expect in msg and "\n" not in msg, msg
    assert msg.startswith(f"{TWO if source == 'two' else SCENES / 'ts_board.yaml'}: "), msg


def test_lamp_and_lamps_together_is_a_one_line_error(tmp_path, capsys):
    text = TWO.read_text() + "lamp:\n  position: [0.1, 0.25, 0.45]\n"
    path = tmp_path / "both.yaml"
    path.write_text(text)
    with pytest.raises(UserError, match=r"both.yaml: lamps: give either lamp \(one lamp\) or lamps"):
        load_scene(path)
    both = {**two_lamp_doc(), "lamp": {"position": [0.1, 0.25, 0.45]}}
    with pytest.raises(UserError, match="^<scene>: lamps: give either lamp"):  # also as a document
        load_scene(both)
    with pytest.raises(ValidationError, match="lamps: give either lamp"):  # and validating the model directly
        Scene.model_validate(both)
    # through the CLI: exit 2, one line on stderr, nothing rendered
    assert main(["render", str(path), "--out", str(tmp_path / "cap"), "--no-cache", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "both.yaml: lamps: give either lamp" in err and not (tmp_path / "cap").exists()


def test_bad_lamp_override_exits_2_through_the_cli(tmp_path, capsys):
    for key in ("lamp.position=[0,0,1]", "lamps.2.position=[0,0,1]"):
        assert main(["render", str(TWO), "--out", str(tmp_path / "cap"), "--set", key, "--no-cache", "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("nearlight: error: ") and "\n" not in err and key.split("=")[0] in err, err


def test_shipped_two_lamp_scene_geometry():
    # scenes/two_lamps.yaml: equal lamps 30° apart as seen from the board's centre, both highlights on the board.
    scene = load_scene(TWO)
    assert len(scene.lamps) == 2 and scene.lamps[0].intensity == scene.lamps[1].intensity == (2.0, 2.0, 2.0)
    centre = np.asarray(scene.object.position)
    d = [np.asarray(lamp.position) - centre for lamp in scene.lamps]
    angle = np.degrees(np.arccos(d[0] @ d[1] / np.linalg.norm(d[0]) / np.linalg.norm(d[1])))
    assert abs(angle - 30.0) < 0.005, angle  # 29.999°: positions rounded to 0.1 mm
    assert np.allclose([np.linalg.norm(x) for x in d], 0.5, atol=1e-4)  # both 0.5 m away
    # the mirror point of each lamp on the board plane z = 0 (board's half size 0.15 m): x = ±0.073, y = -0.019
    cam = np.asarray(scene.camera.position)
    for lamp, x in zip(scene.lamps, (0.0732, -0.0732)):
        p = np.asarray(lamp.position)
        t = cam[2] / (cam[2] + p[2])
        hit = cam + t * (p * [1, 1, -1] - cam)
        assert abs(hit[0] - x) < 1e-3 and abs(hit[1] + 0.0188) < 1e-3, hit
        assert np.all(np.abs(hit[:2]) < 0.15)
