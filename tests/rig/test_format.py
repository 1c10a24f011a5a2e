"""Capture format v2's camera.intrinsics and sensor: round trips, one-line errors, and the generator writing sensor."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nearlight.capture import Intrinsics, Sensor, read_capture, write_capture
from nearlight.errors import UserError
from nearlight.generator.analytic import analytic_capture
from nearlight.generator.noise import add_camera_noise
from nearlight.generator.nuisances import through_rig


def small():
    return analytic_capture(width=32, height=24)


def test_intrinsics_and_sensor_round_trip(tmp_path):
    cap = small()
    k = Intrinsics(fx=30.5, fy=31.0, cx=15.5, cy=11.25)
    s = Sensor(saturation=2.5, full_well=15000.0, read_noise=3.0, bits=12)
    cap = cap.replace(camera=cap.camera.__class__(position=cap.camera.position, to_world=cap.camera.to_world,
                                                  fov_x_deg=cap.camera.fov_x_deg, intrinsics=k), sensor=s)
    write_capture(cap, tmp_path / "c")
    doc = json.loads((tmp_path / "c" / "capture.json").read_text())
    # the field names the estimator reads, exactly
    assert doc["sensor"] == {"saturation": 2.5, "full_well": 15000.0, "read_noise": 3.0, "bits": 12}
    assert doc["camera"]["intrinsics"] == {"fx": 30.5, "fy": 31.0, "cx": 15.5, "cy": 11.25}
    back = read_capture(tmp_path / "c")
    assert back.sensor == s and back.camera.intrinsics == k
    assert "sensor" not in back.meta


def test_absent_means_unknown(tmp_path):
    write_capture(small(), tmp_path / "c")
    back = read_capture(tmp_path / "c")
    assert back.sensor is None and back.camera.intrinsics is None
    assert "sensor" not in json.loads((tmp_path / "c" / "capture.json").read_text())


def test_v1_keeps_its_meaning(tmp_path):
    # a v1 capture.json with a key named sensor: v1 has no such section, so it stays an unknown key (meta)
    write_capture(small(), tmp_path / "c")
    path = tmp_path / "c" / "capture.json"
    doc = json.loads(path.read_text())
    doc["format"] = "nearlight-capture/1"
    doc["sensor"] = {"anything": 1}
    path.write_text(json.dumps(doc))
    back = read_capture(tmp_path / "c")
    assert back.sensor is None and back.meta["sensor"] == {"anything": 1}


@pytest.mark.parametrize("key, value, message", [
    ("sensor", [1, 2], "sensor: expected an object"),
    ("sensor", {"saturation": 1.0, "full_well": 1e4, "read_noise": 2.0}, "sensor.bits: expected an integer"),
    ("sensor", {"saturation": 0, "full_well": 1e4, "read_noise": 2.0, "bits": 12}, "sensor.saturation: expected a number > 0"),
    ("sensor", {"saturation": 1, "full_well": 1e4, "read_noise": -1, "bits": 12}, "sensor.read_noise: expected a number >= 0"),
    ("sensor", {"saturation": 1, "full_well": 1e4, "read_noise": 1, "bits": 12, "gain": 2}, "sensor.gain: unknown key"),
    ("camera.intrinsics", {"fx": 0, "fy": 1, "cx": 1, "cy": 1}, "camera.intrinsics.fx: expected a number > 0"),
    ("camera.intrinsics", {"fx": 1, "fy": 1, "cx": 1}, "camera.intrinsics.cy: expected a number"),
])  # fmt: skip
def test_bad_keys_are_one_line_errors(tmp_path, key, value, message):
    write_capture(small(), tmp_path / "c")
    path = tmp_path / "c" / "capture.json"
    doc = json.loads(path.read_text())
    if key == "camera.intrinsics":
        doc["camera"]["intrinsics"] = value
    else:
        doc[key] = value
    path.write_text(json.dumps(doc))
    with pytest.raises(UserError) as err:
        read_capture(tmp_path / "c")
    assert str(err.value).startswith(f"{path}: {message}") and "\n" not in str(err.value)


def test_generator_writes_its_noise_model_as_sensor(tmp_path):
    # what `nearlight render` does after rendering (generator.pipeline: through_rig, then write_capture)
    noisy = through_rig(small(), noise={"full_well": 12000, "read_noise": 4, "bits": 10, "saturation": "auto"}, seed=1)
    write_capture(noisy, tmp_path / "c")
    back = read_capture(tmp_path / "c")
    # saturation "auto" resolved to the number the noise used
    assert back.sensor == Sensor(saturation=noisy.meta["noise"]["camera"]["saturation"], full_well=12000.0,
                                 read_noise=4.0, bits=10)
    assert back.sensor.saturation == pytest.approx(float(np.nanmax(small().stack)) / 0.9, rel=1e-6)
    # without camera noise there is no noise model to state
    assert through_rig(small(), noise=None).sensor is None


def test_add_camera_noise_is_unchanged_by_its_refactor():
    # adc_counts() is the loop add_camera_noise had inline: the noisy image is DN x saturation / (2^bits - 1)
    from nearlight.generator.noise import adc_counts, noise_rngs
    from nearlight.generator.scene import NoiseSpec

    cap = small()
    noise = NoiseSpec(full_well=5000, read_noise=3, bits=8, saturation=2.0)
    noisy = add_camera_noise(cap, noise=noise, seed=4)
    rng, _ = noise_rngs(4)
    zs, zr = rng.standard_normal(cap.stack.shape), rng.standard_normal(cap.stack.shape)
    dn = adc_counts(cap.stack, zs, zr, noise=noise, saturation=2.0)
    assert np.array_equal(dn, np.rint(dn)) and dn.min() >= 0 and dn.max() <= 255
    assert np.array_equal(noisy.stack, (dn.astype(np.float64) * (2.0 / 255)).astype(np.float32))
