"""Capture format v2 (docs/capture-format.md): the reader reads v1 and v2, the writer writes v2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nearlight.capture import (FORMAT, FORMAT_V1, Camera, Capture, LampFilter, RangeSensor, Rig, read_capture,
                               write_capture)
from nearlight.errors import UserError

H, W = 6, 8


def _capture(rng: np.random.Generator, **changes) -> Capture:
    P = rng.normal(size=(H, W, 3)).astype(np.float32)
    P[0, 0] = np.nan
    cap = Capture(
        width=W,
        height=H,
        camera=Camera(position=np.array([0.0, 0.1, 0.6]), to_world=np.eye(4), fov_x_deg=40.0),
        P=P,
        stack=rng.uniform(size=(4, H, W, 3)).astype(np.float32),
        analyzer_angles_deg=np.array([0.0, 45.0, 90.0, 135.0]),
        truth={
            "lamp_position": [0.1, 0.2, 0.3],
            "lamp_intensity": [1.0, 1.0, 1.0],
            "bsdf": {"model": "torrance_sparrow", "sigma": 0.06},
            "lamps": [{"position": [0.1, 0.2, 0.3], "intensity": [1.0, 1.0, 1.0], "radius_m": 0.01,
                       "anisotropy": {"k": 2.0, "axis": [0.0, 0.0, -1.0]}, "polarizer_axis": [1.0, 0.0, 0.0],
                       "polarizer_extinction_ratio": 1000.0}],  # fmt: skip
            "camera": {"position": [0.0, 0.1, 0.61], "fov_x_deg": 40.0},
            "nuisances": {"realism": "none", "analyzer": {"offset_deg": 0.5}},
        },
        rig=Rig(analyzer_extinction_ratio=300.0, other={"serial": "A-1"}),
    )
    return cap.replace(**changes)


def test_writer_writes_v2_and_the_reader_round_trips_rig_and_truth(tmp_path, rng):
    cap = _capture(rng)
    folder = write_capture(cap, tmp_path / "cap")
    doc = json.loads((folder / "capture.json").read_text())
    assert doc["format"] == FORMAT == "nearlight-capture/2"
    assert doc["rig"] == {"lamps": 1, "analyzer_extinction_ratio": 300.0, "serial": "A-1"}
    read = read_capture(folder)
    assert read.rig == cap.rig
    assert read.truth == cap.truth
    assert "rig" not in read.meta


def test_the_lamps_filter_round_trips(tmp_path, rng):
    rig = Rig(lamp_filter=LampFilter(axis=(1.0, 0.0, 0.0), aim=(0.0, 0.05, 0.0)))
    folder = write_capture(_capture(rng, rig=rig), tmp_path / "cap")
    doc = json.loads((folder / "capture.json").read_text())
    assert doc["rig"]["lamp_filter"] == {"axis": [1.0, 0.0, 0.0], "aim": [0.0, 0.05, 0.0]}
    assert read_capture(folder).rig == rig


def test_the_range_sensor_round_trips(tmp_path, rng):
    rig = Rig(range=RangeSensor(sigma_m=0.0002, quantum_m=0.001, axis="z", source="depth-map"))
    folder = write_capture(_capture(rng, rig=rig), tmp_path / "cap")
    doc = json.loads((folder / "capture.json").read_text())
    assert doc["rig"]["range"] == {"sigma_m": 0.0002, "quantum_m": 0.001, "axis": "z", "source": "depth-map"}
    assert read_capture(folder).rig == rig
    assert "range" not in read_capture(folder).rig.other


def test_an_unstated_range_sensor_is_none(tmp_path, rng):
    folder = write_capture(_capture(rng), tmp_path / "cap")
    doc = json.loads((folder / "capture.json").read_text())
    assert "range" not in doc["rig"]
    assert read_capture(folder).rig.range is None
    doc["rig"]["range"] = None
    (folder / "capture.json").write_text(json.dumps(doc))
    assert read_capture(folder).rig.range is None
    # source is optional (unknown)
    doc["rig"]["range"] = {"sigma_m": 0, "quantum_m": 0.0005, "axis": "ray"}
    (folder / "capture.json").write_text(json.dumps(doc))
    assert read_capture(folder).rig.range == RangeSensor(quantum_m=0.0005, axis="ray", source="unknown")


def test_v1_capture_keeps_its_meaning(tmp_path, rng):
    folder = write_capture(_capture(rng, rig=Rig()), tmp_path / "cap")
    doc = json.loads((folder / "capture.json").read_text())
    doc["format"] = FORMAT_V1
    del doc["rig"]
    (folder / "capture.json").write_text(json.dumps(doc))
    read = read_capture(folder)
    assert read.rig == Rig()  # v1: the ideal rig
    assert read.rig.lamps == 1 and read.rig.analyzer_extinction_ratio is None


def test_a_v1_capture_with_a_rig_key_keeps_it_as_an_unknown_key(tmp_path, rng):
    # v1 kept every other key on a round trip: "rig" in a v1 file is one of them, not v2's rig
    folder = write_capture(_capture(rng), tmp_path / "cap")
    doc = json.loads((folder / "capture.json").read_text())
    doc["format"] = FORMAT_V1
    (folder / "capture.json").write_text(json.dumps(doc))
    read = read_capture(folder)
    assert read.rig == Rig()
    assert read.meta["rig"]["analyzer_extinction_ratio"] == 300.0


def test_ideal_extinction_is_null_or_absent(tmp_path, rng):
    folder = write_capture(_capture(rng), tmp_path / "cap")
    doc = json.loads((folder / "capture.json").read_text())
    doc["rig"]["lamp_polarizer_extinction_ratio"] = None
    del doc["rig"]["lamps"]
    (folder / "capture.json").write_text(json.dumps(doc))
    read = read_capture(folder)
    assert read.rig.lamp_polarizer_extinction_ratio is None and read.rig.lamps == 1


def test_holes_in_P_are_read_as_no_range(tmp_path, rng):
    cap = _capture(rng)
    P = cap.P.copy()
    P[2:4, 3:5] = np.nan  # the range finder returned nothing there; the images are still finite
    read = read_capture(write_capture(cap.replace(P=P, extra={"truth_P": cap.P}), tmp_path / "cap"))
    assert read.surface_mask.sum() == H * W - 1 - 4
    np.testing.assert_array_equal(read.extra["truth_P"], cap.P)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("rig", "ideal", r"rig: expected an object"),
        ("rig.lamps", 0, r"rig\.lamps: expected a positive integer"),
        ("rig.analyzer_extinction_ratio", 0.5, r"rig\.analyzer_extinction_ratio: expected a number >= 1 or null"),
        ("truth.lamps", [{"position": [0, 1]}], r"truth\.lamps\[0\]\.position: expected 3 numbers"),
        ("truth.lamps", [{"position": [0, 0, 1], "radius_m": -0.1}], r"truth\.lamps\[0\]\.radius_m"),
        ("truth.camera", {"position": "here"}, r"truth\.camera\.position"),
        ("truth.nuisances", [], r"truth\.nuisances: expected an object"),
        ("rig.lamp_filter", [1, 0, 0], r"rig\.lamp_filter: expected an object \{axis, aim\}"),
        ("rig.lamp_filter", {"axis": [1, 0], "aim": [0, 0, 0]}, r"rig\.lamp_filter\.axis: expected 3 numbers"),
        ("rig.lamp_filter", {"axis": [0, 0, 0], "aim": [0, 0, 0]}, r"rig\.lamp_filter\.axis: expected a nonzero"),
        ("rig.lamp_filter", {"axis": [1, 0, 0], "aim": "object"}, r"rig\.lamp_filter\.aim: expected 3 numbers"),
        ("rig.range", "laser", r"rig\.range: expected an object"),
        ("rig.range", {"sigma_m": 0.001, "quantum_m": 0, "axis": "ray", "gain": 2},
         r"rig\.range\.gain: unknown key \(expected sigma_m"),
        ("rig.range", {"sigma_m": -0.001, "quantum_m": 0, "axis": "ray"},
         r"rig\.range\.sigma_m: expected a number >= 0"),
        ("rig.range", {"sigma_m": "1mm", "quantum_m": 0, "axis": "ray"}, r"rig\.range\.sigma_m: expected a number"),
        ("rig.range", {"sigma_m": 0.001, "axis": "ray"}, r"rig\.range\.quantum_m: missing"),
        ("rig.range", {"sigma_m": 0.001, "quantum_m": 0, "axis": "x"}, r'rig\.range\.axis: expected "ray" or "z"'),
        ("rig.range", {"sigma_m": 0.001, "quantum_m": 0, "axis": "ray", "source": "laser"},
         r"rig\.range\.source: expected one of depth-map"),
    ],
)
def test_bad_v2_key_is_one_line_naming_file_and_key(tmp_path, rng, key, value, message):
    folder = write_capture(_capture(rng), tmp_path / "cap")
    doc = json.loads((folder / "capture.json").read_text())
    section, _, sub = key.partition(".")
    if sub:
        doc[section][sub] = value
    else:
        doc[section] = value
    (folder / "capture.json").write_text(json.dumps(doc))
    with pytest.raises(UserError, match=message) as info:
        read_capture(folder)
    assert "\n" not in str(info.value) and "capture.json" in str(info.value)
