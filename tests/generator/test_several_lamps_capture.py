"""Captures with several lamps: ``analytic_capture_lamps`` and ``truth.lamps`` in capture format v2.

numpy only. Golden values: the one-lamp analytic capture as it was before ``lamps`` existed
(``analytic_capture_lamps([one])`` must give its images bit for bit, and ``analytic_capture``'s
signature, from which the evaluation builds analytic sweeps' scenes and render keys, is unchanged), and linearity: the two-lamp images are the
sums of the one-lamp images, computed in float64 and stored in float32, so they agree to
``3u (|a| + |b|)`` (u = 2⁻²⁴: one rounding of each one-lamp image, one of their float32 sum, one of
the two-lamp image).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from nearlight.capture import read_capture, write_capture
from nearlight.errors import UserError
from nearlight.generator.analytic import analytic_capture, analytic_capture_lamps

U = 2.0**-24
L0 = {"position": [0.12, 0.1, 0.35], "intensity": [2.0, 2.0, 2.0]}
L1 = {"position": [-0.1, 0.15, 0.3], "intensity": [1.0, 3.0, 2.0], "phase_deg": 60.0, "polarizer_axis": [0, 2, 0]}


def test_one_lamp_list_is_the_v1_call_bit_for_bit():
    old = analytic_capture(lamp_position=L0["position"], lamp_intensity=L0["intensity"])
    new = analytic_capture_lamps([L0])
    assert np.array_equal(old.stack, new.stack)
    for k in ("truth_specular", "truth_diffuse"):
        assert np.array_equal(old.extra[k], new.extra[k])
    assert set(new.extra) == set(old.extra)  # no per-lamp images for one lamp
    # the v1 truth keys exactly as before, and truth.lamps beside them
    assert {k: new.truth[k] for k in old.truth} == old.truth and "lamps" not in old.truth
    assert new.truth["lamps"] == [{"position": L0["position"], "intensity": L0["intensity"], "radius_m": 0.0,
                                   "anisotropy": None, "polarizer_axis": [1.0, 0.0, 0.0],
                                   "polarizer_extinction_ratio": None}]  # fmt: skip
    assert new.rig.lamps == 1 and np.array_equal(new.lamp_polarizer_axis, [1.0, 0.0, 0.0])


@pytest.mark.parametrize("shape", ["board", "sphere"])
def test_two_lamps_add(shape):
    a = analytic_capture_lamps([L0], shape=shape)
    b = analytic_capture_lamps([L1], shape=shape, phase_deg=60.0)
    ab = analytic_capture_lamps([L0, L1], shape=shape)
    for k in ("truth_specular", "truth_diffuse"):
        x, y = (np.asarray(c.extra[k], float) for c in (a, b))
        assert np.all(np.abs(ab.extra[k] - (x + y)) <= 3 * U * (np.abs(x) + np.abs(y))), k
        for i, one in enumerate((a, b)):  # every lamp's own image: that lamp alone, bit for bit
            assert np.array_equal(ab.extra[f"{k}_lamp{i}"], one.extra[k])
    x, y = (np.asarray(c.stack, float) for c in (a, b))
    assert np.all(np.abs(ab.stack - (x + y)) <= 3 * U * (np.abs(x) + np.abs(y)))
    # each lamp through its own polarizer: I(θ) = Σ Id,i/2 + Is,i cos²(θ − βi), β0 = 0°, β1 = 60° at every pixel;
    # at θ = 135°: cos²(135°) = 0.5 and cos²(75°) = 0.0670 (the stack's last angle of 0, 45, 90, 135)
    s = [c.extra["truth_specular"].astype(float) for c in (a, b)]
    d = [c.extra["truth_diffuse"].astype(float) for c in (a, b)]
    want = (d[0] + d[1]) / 2 + s[0] * 0.5 + s[1] * np.cos(np.radians(75.0)) ** 2
    assert np.allclose(ab.stack[3], want, rtol=1e-6, atol=1e-9)


def test_truth_of_several_lamps_has_no_single_lamp():
    cap = analytic_capture_lamps([L0, L1])
    assert "lamp_position" not in cap.truth and "lamp_intensity" not in cap.truth
    assert [lamp["position"] for lamp in cap.truth["lamps"]] == [L0["position"], L1["position"]]
    assert cap.truth["lamps"][1]["intensity"] == [1.0, 3.0, 2.0]
    assert cap.truth["lamps"][1]["polarizer_axis"] == [0.0, 1.0, 0.0]  # unit
    assert cap.rig.lamps == 2 and cap.lamp_polarizer_axis is None
    # single-lamp scoring code fails loudly rather than grading against lamp 0
    with pytest.raises(KeyError):
        cap.truth["lamp_position"]


def test_separated_analytic_capture_of_two_lamps():
    cap = analytic_capture_lamps([L0, L1], analyzer_angles_deg=None)
    assert cap.stack is None
    assert np.array_equal(cap.specular, cap.extra["truth_specular"])
    assert np.array_equal(cap.diffuse, cap.extra["truth_diffuse"])


@pytest.mark.parametrize(
    ("lamps", "kwargs", "expect"),
    [
        ([L0], {"lamp_position": [0, 0, 1]}, "lamp_position: give the lamps in lamps"),
        ([L0], {"lamp_intensity": 1.0}, "lamp_intensity: give the lamps in lamps"),
        ([], {}, "lamps: expected at least one lamp"),
        ([L0, {"intensity": [1, 1, 1]}], {}, r"lamps\[1\]: expected a mapping with a position"),
        ([{**L0, "radius": 0.01}], {}, r"lamps\[0\].radius: unknown key"),
        ([{"position": [0, 1]}], {}, r"lamps\[0\].position: expected 3 numbers"),
    ],
)
def test_bad_lamps_of_analytic_capture(lamps, kwargs, expect):
    with pytest.raises(ValueError, match=expect):
        analytic_capture_lamps(lamps, **kwargs)
    with pytest.raises(TypeError):  # an argument analytic_capture does not have
        analytic_capture_lamps([L0], widht=3)


def test_analytic_capture_signature_is_unchanged():
    # evaluation/engine/renderers.py builds every analytic sweep scene from these parameters and hashes it into the
    # render key: the list (and defaults) at e8b09ea, before several lamps.
    import inspect

    params = inspect.signature(analytic_capture).parameters
    assert list(params) == ["shape", "width", "height", "fov_x_deg", "camera_position", "look_at", "up",
                            "lamp_position", "lamp_intensity", "bsdf", "kd", "analyzer_angles_deg", "phase_deg",
                            "board_size", "board_centre", "board_normal", "sphere_centre", "sphere_radius",
                            "with_normals"]  # fmt: skip
    assert params["lamp_position"].default == (0.05, 0.15, 0.35)
    assert params["lamp_intensity"].default == (2.0, 2.0, 2.0)


def test_two_lamp_capture_round_trip(tmp_path):
    cap = analytic_capture_lamps([L0, L1])
    write_capture(cap, tmp_path / "c")
    doc = json.loads((tmp_path / "c" / "capture.json").read_text())
    assert doc["rig"]["lamps"] == 2 and "lamp_polarizer_axis" not in doc and "lamp_position" not in doc["truth"]
    back = read_capture(tmp_path / "c")
    assert back.truth["lamps"] == cap.truth["lamps"] and back.rig.lamps == 2
    assert np.array_equal(back.extra["truth_specular_lamp1"], cap.extra["truth_specular_lamp1"])


def _edit(tmp_path, cap, change):
    write_capture(cap, tmp_path / "c", overwrite=True)
    path = tmp_path / "c" / "capture.json"
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))
    return tmp_path / "c"


@pytest.mark.parametrize(
    ("change", "expect"),
    [
        (lambda d: d["truth"].__setitem__("lamp_position", [0.12, 0.1, 0.35]),
         "truth.lamp_position: a capture with 2 lamps has no single lamp; each lamp is in truth.lamps"),
        (lambda d: d["truth"].__setitem__("lamp_intensity", [2, 2, 2]), "truth.lamp_intensity: a capture with 2 lamps"),
        (lambda d: d["rig"].__setitem__("lamps", 3), "truth.lamps: lists 2 lamps, rig.lamps says 3"),
        (lambda d: d["rig"].pop("lamps"), r"truth.lamps: lists 2 lamps, rig.lamps says 1 \(absent: 1\)"),
        (lambda d: d["truth"]["lamps"][1].__setitem__("position", [0, 1]), r"truth.lamps\[1\].position"),
    ],
)
def test_bad_truth_of_several_lamps_is_a_one_line_error(tmp_path, change, expect):
    where = _edit(tmp_path, analytic_capture_lamps([L0, L1]), change)
    with pytest.raises(UserError, match=expect) as err:
        read_capture(where)
    assert "\n" not in str(err.value) and "capture.json" in str(err.value)


def test_one_lamp_truth_keeps_lamp_position_beside_lamps(tmp_path):
    # a one-lamp v2 capture with both v1's keys and truth.lamps reads as before
    where = _edit(tmp_path, analytic_capture_lamps([L0]), lambda d: None)
    back = read_capture(where)
    assert back.truth["lamp_position"] == L0["position"] and len(back.truth["lamps"]) == 1
