"""``nearlight estimate``: happy path and bad input (one line, exit 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nearlight.capture import write_capture
from nearlight.cli import main
from nearlight.generator.analytic import analytic_capture


@pytest.fixture
def capture_dir(tmp_path):
    return write_capture(analytic_capture(width=96, height=72), tmp_path / "cap")


def _error(capsys, argv):
    """Run the CLI, expect exit 2 and one stderr line; return that line."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nearlight: error: ")
    return err[0]


@pytest.mark.parametrize("method", ["paper-init", "full", "distant"])
def test_estimate_writes_json_and_plot(capture_dir, tmp_path, capsys, method):
    out, png = tmp_path / "est.json", tmp_path / "est.png"
    argv = ["estimate", str(capture_dir), "--method", method, "--json", str(out), "--plot", str(png)]
    if method == "distant":
        # a board under a distant light and viewer has one α: every light direction fits its constant specular
        # alike, and its own diagnostics say so (undetermined): refused, exit 1, no plot
        assert main(argv) == 1
        captured = capsys.readouterr()
        assert captured.err.startswith("nearlight estimate: distant failed (determined): ")
        assert json.loads(out.read_text())["status"] == "failed" and not png.exists()
        return
    assert main(argv) == 0
    assert capsys.readouterr().out.startswith(f"{method}: lamp (")
    doc = json.loads(out.read_text())
    assert doc["method"] == method
    assert len(doc["lamp_position"]) == 3 and len(doc["ks"]) == 3 and doc["sigma"] > 0
    assert png.stat().st_size > 10_000
    assert not list(tmp_path.glob(".*partial"))


def test_options_reach_the_method(capture_dir, tmp_path, capsys):
    out = tmp_path / "e.json"
    argv = ["estimate", str(capture_dir), "--method", "paper-init", "--json", str(out),
            "--set", "t_max=1.5", "--set", "search=scan", "--set", "dt=0.002"]
    assert main(argv) == 0
    d = json.loads(out.read_text())["diagnostics"]
    assert (d["t_max"], d["search"], d["dt"]) == (1.5, "scan", 0.002)
    assert d["ep_evaluations"] == 750  # every 2 mm step in (0, 1.5 m]


def test_missing_channel(tmp_path, capsys):
    import OpenEXR

    cap = analytic_capture(width=32, height=24, analyzer_angles_deg=None)
    folder = write_capture(cap, tmp_path / "cap")
    with OpenEXR.File(str(folder / "capture.exr"), separate_channels=True) as f:
        channels = {k: v.pixels for k, v in f.channels().items() if k != "P.Z"}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, channels).write(str(folder / "capture.exr"))
    line = _error(capsys, ["estimate", str(folder)])
    assert "capture.exr" in line and "P.Z" in line


def test_shapes_that_disagree(capture_dir, capsys):
    doc = json.loads((capture_dir / "capture.json").read_text())
    doc["width"] = 95
    (capture_dir / "capture.json").write_text(json.dumps(doc))
    line = _error(capsys, ["estimate", str(capture_dir)])
    assert "capture.exr" in line and "does not match" in line


def test_nan_in_an_image(tmp_path, capsys):
    cap = analytic_capture(width=32, height=24)
    stack = cap.stack.copy()
    stack[2, 12, 16, 1] = np.nan
    folder = write_capture(cap.replace(stack=stack), tmp_path / "cap")
    line = _error(capsys, ["estimate", str(folder)])
    assert "pol2" in line and "NaN" in line


def test_no_specular_pixel(tmp_path, capsys):
    cap = analytic_capture(width=32, height=24, analyzer_angles_deg=None)
    folder = write_capture(cap.replace(specular=np.zeros_like(cap.specular)), tmp_path / "cap")
    line = _error(capsys, ["estimate", str(folder)])
    assert "specular" in line and "no signal" in line


def test_peak_on_the_image_border(tmp_path, capsys):
    cap = analytic_capture(width=32, height=24, analyzer_angles_deg=None, board_size=2.0)  # fills the frame
    assert cap.surface_mask.all()
    ramp = np.exp(-np.arange(32) / 8.0)[None, :, None] * np.ones((24, 1, 3))
    folder = write_capture(cap.replace(specular=ramp.astype(np.float32)), tmp_path / "cap")
    line = _error(capsys, ["estimate", str(folder)])
    assert "specular" in line and "border" in line


def test_t_max_that_cannot_reach_the_lamp(capture_dir, capsys):
    # the lamp is 0.40 m from the highlight and E_p decreases until t* = 0.22 m
    line = _error(capsys, ["estimate", str(capture_dir), "--method", "paper-init", "--set", "t_max=0.05"])
    assert "t_max" in line and str(capture_dir) in line


def test_json_that_is_not_a_known_format(capture_dir, capsys):
    doc = json.loads((capture_dir / "capture.json").read_text())
    doc["format"] = "nearlight-capture/3"
    (capture_dir / "capture.json").write_text(json.dumps(doc))
    line = _error(capsys, ["estimate", str(capture_dir)])
    assert "capture.json" in line and "format" in line


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--method", "nope"], "method"),
        (["--method", "no_such_module_xyz:f"], "no_such_module_xyz"),
        (["--method", "json:no_such_function"], "no_such_function"),
        (["--set", "bogus=1"], "bogus"),
        (["--set", "=1"], "--set"),
        (["--method", "full", "--set", "loss=nope"], "loss"),
    ],
)
def test_bad_method_or_option(capture_dir, capsys, argv, needle):
    assert needle in _error(capsys, ["estimate", str(capture_dir), *argv])


# Option values of the wrong type or range (the README's `threshold=abc`, and one per declared kind), refused from each
# method's declaration (nearlight.estimator.options) before the capture is even read.
@pytest.mark.parametrize(
    ("method", "option", "needle"),
    [
        ("paper-init", "threshold=abc", "threshold: Input should be a valid number"),
        ("paper-init", "threshold=null", "threshold: Input should be a valid number"),
        ("paper-init", "threshold=-0.1", "threshold: Input should be greater than 0"),
        ("paper-init", "threshold=1.5", "threshold: Input should be less than 1"),
        ("paper-init", "t_max=[1,2]", "t_max:"),
        ("paper-init", "search=slow", "search: Value error, expected one of fast, scan"),
        ("paper-init", "n_coarse=2.5", "n_coarse: Input should be a valid integer"),
        ("full", "n_starts=-1", "n_starts: Input should be greater than or equal to 0"),
        ("full", "f_scale=-1", "f_scale: Input should be greater than 0"),
        ("full", "max_pixels=0", "max_pixels: Input should be greater than or equal to 1"),
        ("full", "strict_t_max=false", "'strict_t_max': not accepted by method full"),
        ("full", "surface=refined", "surface: Value error, expected one of auto, joint, fixed"),
        ("full", "surface=[joint]", "surface:"),
        ("paper", "max_outer=-1", "max_outer: Input should be greater than or equal to 1"),
        ("paper", "energy=joules", "energy: Value error, expected one of ratio, ratio-t, radiance"),
        ("paper", "dt=NaN", "dt:"),
        ("distant", "n_starts=3", "'n_starts': not accepted by method distant"),
    ],
)
def test_option_values_are_checked_from_the_declaration(tmp_path, capsys, method, option, needle):
    missing = tmp_path / "not-read"  # the options are refused before the capture is opened
    line = _error(capsys, ["estimate", str(missing), "--method", method, "--set", option])
    assert needle in line, line


def test_a_plugin_that_fails_is_one_line(capture_dir, capsys):
    # json.dumps takes the capture and raises TypeError (not JSON serializable): the user's function failed
    line = _error(capsys, ["estimate", str(capture_dir), "--method", "json:dumps"])
    assert "method json:dumps: failed with TypeError" in line
