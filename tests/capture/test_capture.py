"""Capture format: v1 and v2 round trips and one-line errors for bad captures."""

from __future__ import annotations

import json

import numpy as np
import OpenEXR
import pytest

from nearlight.capture import Camera, Capture, read_capture, write_capture
from nearlight.errors import UserError

H, W = 6, 8


def _capture(rng: np.random.Generator, **changes) -> Capture:
    P = rng.normal(size=(H, W, 3)).astype(np.float32)
    P[0, 0] = np.nan  # one background pixel
    cap = Capture(
        width=W,
        height=H,
        camera=Camera(position=np.array([0.0, 0.1, 0.6]), to_world=np.eye(4), fov_x_deg=40.0),
        P=P,
        N=np.tile(np.array([0, 0, 1], np.float32), (H, W, 1)),
        stack=rng.uniform(size=(4, H, W, 3)).astype(np.float32),
        analyzer_angles_deg=np.array([0.0, 45.0, 90.0, 135.0]),
        lamp_polarizer_axis=np.array([1.0, 0.0, 0.0]),
        truth={"lamp_position": [0.1, 0.2, 0.3], "bsdf": {"model": "torrance_sparrow", "sigma": 0.06}},
        extra={"truth_specular": rng.uniform(size=(H, W, 3)).astype(np.float32), "mask": np.ones((H, W), np.float32)},
        meta={"generator": {"spp": 4}},
    )
    return cap.replace(**changes)


def test_round_trip_keeps_every_array_and_key(tmp_path, rng):
    cap = _capture(rng)
    read = read_capture(write_capture(cap, tmp_path / "cap"))
    for name in ("P", "N", "stack", "analyzer_angles_deg", "lamp_polarizer_axis"):
        np.testing.assert_array_equal(getattr(read, name), getattr(cap, name), err_msg=name)
    for name in cap.extra:
        np.testing.assert_array_equal(read.extra[name], cap.extra[name], err_msg=name)
    assert read.truth == cap.truth
    assert read.meta == cap.meta
    np.testing.assert_array_equal(read.camera.position, cap.camera.position)
    assert read.camera.fov_x_deg == 40.0
    assert read.surface_mask.sum() == H * W - 1
    assert sorted(p.name for p in (tmp_path / "cap").iterdir()) == ["capture.exr", "capture.json"]


def test_separated_specular_capture_without_stack(tmp_path, rng):
    cap = _capture(rng, stack=None, analyzer_angles_deg=None, specular=np.ones((H, W, 3), np.float32))
    read = read_capture(write_capture(cap, tmp_path / "cap"))
    assert read.stack is None
    np.testing.assert_array_equal(read.specular, 1.0)


def test_half_channels_are_read_as_float32(tmp_path, rng):
    cap = _capture(rng)
    folder = write_capture(cap, tmp_path / "cap")
    with OpenEXR.File(str(folder / "capture.exr"), separate_channels=True) as f:
        chans = {k: v.pixels.astype(np.float16) for k, v in f.channels().items()}
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, chans).write(
        str(folder / "capture.exr")
    )
    read = read_capture(folder)
    assert read.stack.dtype == np.float32
    # float16 keeps 11 significant bits: relative error <= 2**-11 on values in [0, 1)
    np.testing.assert_allclose(read.stack, cap.stack, rtol=2**-11, atol=2**-14)


def _rewrite_json(folder, **changes):
    doc = json.loads((folder / "capture.json").read_text())
    doc.update(changes)
    (folder / "capture.json").write_text(json.dumps(doc))


def _rewrite_exr(folder, edit):
    with OpenEXR.File(str(folder / "capture.exr"), separate_channels=True) as f:
        chans = {k: v.pixels.copy() for k, v in f.channels().items()}
    edit(chans)
    OpenEXR.File({"type": OpenEXR.scanlineimage}, chans).write(str(folder / "capture.exr"))


@pytest.mark.parametrize(
    ("breakage", "message"),
    [
        (lambda f: (f / "capture.json").unlink(), r"capture\.json: missing"),
        (lambda f: (f / "capture.exr").unlink(), r"capture\.exr: missing"),
        (lambda f: (f / "capture.json").write_text("{"), r"capture\.json: not valid JSON"),
        (lambda f: _rewrite_json(f, format="nearlight-capture/3"), r"format: expected 'nearlight-capture/1' or 'nearlight-capture/2'"),
        (lambda f: _rewrite_json(f, width=9), r"channel .*: shape 6x8 .* capture\.json's 6x9"),
        (lambda f: _rewrite_json(f, camera={"position": [0, 1]}), r"camera\.position: expected 3 numbers"),
        (lambda f: _rewrite_json(f, analyzer_angles_deg=[0, 45, 90]), r"pol0, pol1, pol2, pol3 do not match"),
        (lambda f: (f / "capture.exr").write_bytes(b"not an exr"), r"not a readable OpenEXR file"),
        (lambda f: _rewrite_exr(f, lambda c: c.pop("P.Y")), r"channel P\.Y missing"),
        (lambda f: _rewrite_exr(f, lambda c: c.pop("pol2.G")), r"channel pol2\.G missing"),
        (lambda f: _rewrite_exr(f, lambda c: c["pol1.B"].__setitem__((3, 3), np.nan)), r"pol1: NaN or Inf"),
        (lambda f: _rewrite_exr(f, lambda c: [c.pop(k) for k in list(c) if k.startswith("pol")]), r"pol0\.R missing"),
    ],
)
def test_bad_capture_gives_one_line_error_naming_the_culprit(tmp_path, rng, breakage, message):
    folder = write_capture(_capture(rng), tmp_path / "cap")
    breakage(folder)
    with pytest.raises(UserError, match=message) as info:
        read_capture(folder)
    assert "\n" not in str(info.value)
    assert str(folder) in str(info.value)


def test_not_a_directory(tmp_path):
    with pytest.raises(UserError, match="not a capture directory"):
        read_capture(tmp_path / "nowhere")


def test_write_refuses_to_overwrite_and_leaves_no_partial_capture(tmp_path, rng):
    cap = _capture(rng)
    write_capture(cap, tmp_path / "cap")
    with pytest.raises(UserError, match="already exists"):
        write_capture(cap, tmp_path / "cap")
    bad = cap.replace(extra={"wrong": np.zeros((2, 2), np.float32)})
    with pytest.raises(ValueError, match="layer wrong"):
        write_capture(bad, tmp_path / "other")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap"]


def test_write_into_unwritable_folder_is_a_user_error(tmp_path, rng):
    (tmp_path / "file").write_text("")
    with pytest.raises(UserError, match="cannot write there"):
        write_capture(_capture(rng), tmp_path / "file" / "cap")
