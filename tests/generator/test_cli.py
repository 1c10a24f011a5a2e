"""``nearlight render`` / ``nearlight show`` end to end, the render cache, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nearlight.capture import read_capture
from nearlight.cli import main
from nearlight.errors import UserError
from nearlight.generator import load_scene, render_clean
from nearlight.generator import render as render_module

pytestmark = pytest.mark.render

SCENES = Path(__file__).resolve().parents[2] / "scenes"
TINY = ["--set", "camera.resolution=[48,36]", "--quiet", "--no-cache"]


def test_render_then_read_then_show(tmp_path, capsys):
    out = tmp_path / "cap"
    assert main(["render", str(SCENES / "ts_board.yaml"), "--out", str(out), *TINY,
                 "--set", "capture.noise={read_noise: 5}", "--set", "capture.range_noise_m=0.001"]) == 0  # fmt: skip
    cap = read_capture(out)
    assert cap.stack.shape == (8, 36, 48, 3) and cap.P.shape == (36, 48, 3)
    assert cap.N is None and "truth_N" in cap.extra  # range noise drops N (documented)
    assert {"truth_specular", "truth_diffuse", "S0", "S1", "S2", "mask"} <= set(cap.extra)
    t = cap.truth
    assert t["lamp_position"] == [0.1, 0.25, 0.45] and t["lamp_intensity"] == [2.0, 2.0, 2.0]
    assert t["bsdf"] == {"model": "torrance_sparrow", "ks": [0.3, 0.3, 0.3], "sigma": 0.1, "kd": [0.3, 0.2, 0.15],
                         "polarization": "ideal", "eta": 1.5}  # fmt: skip
    doc = json.loads((out / "capture.json").read_text())
    assert doc["camera"]["fov_x_deg"] == 40.0 and len(doc["camera"]["to_world"]) == 4
    assert doc["generator"]["scene"]["capture"]["noise"]["read_noise"] == 5
    # the camera noise is on the stack only
    assert not np.allclose(cap.stack, render_module.analyzer_stack(
        np.stack([cap.extra[f"S{i}"] for i in range(3)]), cap.analyzer_angles_deg))  # fmt: skip
    png = tmp_path / "sheet.png"
    assert main(["show", str(out), "--out", str(png)]) == 0
    import matplotlib.image

    assert matplotlib.image.imread(png).shape[2] in (3, 4)
    assert main(["show", str(out)]) == 0 and (tmp_path / "cap.png").is_file()  # default: DIR.png beside DIR


@pytest.mark.parametrize(
    ("scene", "sets", "expect"),
    [
        ("ts_board.yaml", ["lamp.positon=[0,0,1]"], "lamp.positon: unknown key"),
        ("ts_board.yaml", ["lamp.position=[0,0]"], "lamp.position: too few items"),
        ("ts_board.yaml", ["material.sigma=-0.05"], "material.sigma: Input should be greater than 0"),
        ("ts_board.yaml", ["camera.look_at=[0,-2,0.55]"], "camera: sees no part of the object"),
        ("sphere.yaml", ["lamp.position=[0.01,0,0.02]"], "lamp.position: [0.01, 0.0, 0.02] is inside the object"),
        ("torus.yaml", ["lamp.position=[0,0.06,0.005]", "object.segments=[32,16]"], "is inside the object"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_no_capture(tmp_path, capsys, scene, sets, expect):
    out = tmp_path / "cap"
    argv = ["render", str(SCENES / scene), "--out", str(out), *TINY]
    for s in sets:
        argv += ["--set", s]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("nearlight: error: ") and expect in err and "\n" not in err, err
    assert list(tmp_path.iterdir()) == []  # nothing left behind, not even a partial folder


def test_unwritable_or_existing_output_is_refused_before_rendering(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(render_module, "_render_arrays", _no_render)
    blocker = tmp_path / "afile"
    blocker.write_text("")
    assert main(["render", str(SCENES / "ts_board.yaml"), "--out", str(blocker / "cap"), *TINY]) == 2
    assert "cannot write there" in capsys.readouterr().err
    (tmp_path / "exists").mkdir()
    assert main(["render", str(SCENES / "ts_board.yaml"), "--out", str(tmp_path / "exists"), *TINY]) == 2
    assert "already exists" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "exists"]


def _no_render(*args, **kwargs):
    raise AssertionError("Mitsuba must not run")


def test_render_cache_ignores_noise_and_seed(tmp_path, monkeypatch):
    scene = load_scene(SCENES / "ts_board.yaml", overrides={"camera.resolution": [32, 24]})
    first = render_clean(scene, cache_dir=tmp_path, progress=False)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    monkeypatch.setattr(render_module, "_render_arrays", _no_render)
    noisy = load_scene(scene.model_dump(mode="json"), overrides={"capture.seed": 5, "capture.noise": {},
                                                                  "capture.analyzer_angles_deg": [0, 60, 120]})  # fmt: skip
    again = render_clean(noisy, cache_dir=tmp_path, progress=False)
    assert np.array_equal(again.extra["S0"], first.extra["S0"]) and again.stack.shape[0] == 3
    moved = load_scene(scene.model_dump(mode="json"), overrides={"lamp.position": [0.1, 0.2, 0.45]})
    assert render_module.render_key(moved) != render_module.render_key(scene)
    with pytest.raises(AssertionError, match="Mitsuba must not run"):
        render_clean(moved, cache_dir=tmp_path, progress=False)


@pytest.mark.parametrize("name", ["sphere.yaml", "cylinder.yaml", "bookend.yaml", "torus.yaml", "ward_board.yaml"])
def test_shipped_scenes_render_with_the_closed_form(name):
    # Every shipped object, rendered small: truth images equal the closed form at the capture's own P and N
    # (pixels >= 2 px from an edge; median <= 0.5 %, p99 <= 3 %), and the highlight lies inside the image.
    from scipy import ndimage

    from nearlight.physics import reflectance

    cap = render_clean(load_scene(SCENES / name, overrides={"camera.resolution": [64, 48]}), progress=False)
    m = ndimage.binary_erosion(cap.surface_mask, iterations=2)
    t = cap.truth
    args = (cap.P[m], cap.N[m], cap.camera.position, t["lamp_position"], np.asarray(t["lamp_intensity"]) / 2)
    spec = reflectance.specular_radiance(*args, t["bsdf"])
    lit = spec[..., 1] > 1e-6 * spec[..., 1].max()  # the lamp may shadow parts of closed objects
    rel = np.abs(cap.extra["truth_specular"][m][lit] - spec[lit]) / spec[lit]
    assert np.median(rel) <= 0.005 and np.percentile(rel, 99) <= 0.03
    peak = np.unravel_index(np.argmax(cap.extra["truth_specular"][..., 1]), cap.surface_mask.shape)
    assert 0 < peak[0] < 47 and 0 < peak[1] < 63


def test_mesh_object_renders_like_the_generated_torus(tmp_path):
    from nearlight.generator.shapes import torus_mesh, write_ply

    write_ply(tmp_path / "t.ply", *torus_mesh(0.06, 0.025, (64, 32)))
    base = load_scene(SCENES / "torus.yaml", overrides={"camera.resolution": [40, 30], "object.segments": [64, 32]})
    doc = base.model_dump(mode="json")
    doc["object"] = {"type": "mesh", "file": str(tmp_path / "t.ply"), "position": doc["object"]["position"]}
    a = render_clean(base, progress=False)
    b = render_clean(load_scene(doc), progress=False)
    assert np.array_equal(a.surface_mask, b.surface_mask)
    assert np.allclose(a.extra["S0"], b.extra["S0"], atol=1e-6)


def test_user_error_type_is_raised_by_the_api():
    with pytest.raises(UserError):
        render_clean(load_scene(SCENES / "ts_board.yaml", overrides={"camera.look_at": [0, -2, 0.55],
                                                                      "camera.resolution": [16, 12]}))  # fmt: skip
