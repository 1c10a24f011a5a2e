"""Bad rig files: each a one-line error naming the file and the key, exit status 2, through the command."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import yaml

from nearlight.capture import write_capture
from nearlight.cli import main
from nearlight.generator.analytic import analytic_capture

pytest.importorskip("polanalyser")


@pytest.fixture(scope="module")
def rigdir(tmp_path_factory):
    """A good rig folder (the simulator's), exported once through the command."""
    tmp = tmp_path_factory.mktemp("rig")
    write_capture(analytic_capture(width=64, height=48), tmp / "cap")
    assert main(["rig", "export", str(tmp / "cap"), "--out", str(tmp / "rig")]) == 0
    return tmp / "rig"


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def edited(rigdir, tmp_path, change):
    """A copy of the good rig folder with its rig file changed by ``change(doc, folder)``."""
    folder = tmp_path / "r"
    shutil.copytree(rigdir, folder)
    doc = yaml.safe_load((folder / "rig.yaml").read_text())
    change(doc, folder)
    (folder / "rig.yaml").write_text(yaml.safe_dump(doc))
    return folder / "rig.yaml"


def test_the_good_rig_imports(rigdir, tmp_path, capsys):
    code, out, err = run(capsys, "rig", "import", str(rigdir / "rig.yaml"), "--out", str(tmp_path / "c"))
    assert code == 0 and out.strip() == str(tmp_path / "c") and not err


def _write_png(path, img):
    import cv2

    assert cv2.imwrite(str(path), img)


CASES = {
    "missing intrinsics": (lambda d, f: d["camera"].pop("intrinsics"), "camera.intrinsics: missing"),
    "missing depth intrinsics": (lambda d, f: d["depth"].pop("intrinsics"), "depth.intrinsics: missing"),
    "depth of the wrong size": (
        lambda d, f: _write_png(f / "depth.png", np.ones((40, 64), np.uint16)),
        "depth.file: depth.png: 40x64 does not match camera.height x camera.width 48x64"),
    "mosaic of odd size": (
        lambda d, f: d["camera"].update(width=63),
        "camera.width, camera.height: a mono mosaic needs multiples of 2"),
    "frame of another size": (
        lambda d, f: _write_png(f / "frame.png", np.ones((48, 62), np.uint16)),
        "polarization.shots[0].files: frame.png: a mono mosaic frame of 48x62 does not match"),
    "unknown pattern": (lambda d, f: d["polarization"].update(pattern="IMX999"), "polarization.pattern: expected a known pattern"),
    "pattern of repeated angles": (
        lambda d, f: d["polarization"].update(pattern=[[0, 45], [90, 180]]),
        "polarization.pattern: expected 4 distinct angles"),
    "unknown mosaic": (lambda d, f: d["polarization"].update(mosaic="bayer"), "polarization.mosaic: expected one of mono, colour"),
    "angles that do not match the images": (
        lambda d, f: (d["polarization"].pop("mosaic"), d["polarization"].pop("pattern"),
                      d["polarization"].update(angles_deg=[0, 45, 90, 135])),
        "polarization.shots[0].files: 1 files do not match the angles: expected 4 files"),
    "missing file": (lambda d, f: (f / "frame.png").unlink(), "polarization.shots[0].files: frame.png: no such file"),
    "unknown key": (lambda d, f: d["camera"].update(focal=3), "camera.focal: unknown key"),
    "not a rigid pose": (lambda d, f: d["camera"].update(pose=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
                         "camera.pose: expected a 4x4 rigid transform"),
    "angles as text": (
        lambda d, f: d["polarization"].update(pattern=[["90", 45], [135, 0]]),
        "polarization.pattern: expected numbers of shape [2, 2]"),
    "wrong format": (lambda d, f: d.update(format="rig/9"), "format: expected 'nearlight-rig/1'"),
    "white below black": (lambda d, f: d["polarization"].update(black_level=5000), "polarization.white_level: expected a number > 5000"),
    "missing depth file": (lambda d, f: d["depth"].update(file="depth.jpg"), "depth.file: depth.jpg: no such file"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_rig_file_is_one_line_exit_2(rigdir, tmp_path, capsys, case):
    change, message = CASES[case]
    rig = edited(rigdir, tmp_path, change)
    before = {p.name: p.read_bytes() for p in rig.parent.iterdir()}
    code, out, err = run(capsys, "rig", "import", str(rig), "--out", str(tmp_path / "c"))
    assert code == 2 and out == ""
    assert err.count("\n") == 1, err
    assert err.startswith(f"nearlight: error: {rig}: {message}"), err
    assert not (tmp_path / "c").exists()
    assert {p.name: p.read_bytes() for p in rig.parent.iterdir()} == before  # nothing of the user's touched


def test_unknown_file_type_names_the_suffix(rigdir, tmp_path, capsys):
    rig = edited(rigdir, tmp_path, lambda d, f: (shutil.copy(f / "depth.png", f / "depth.jpg"),
                                                 d["depth"].update(file="depth.jpg")))  # fmt: skip
    code, _, err = run(capsys, "rig", "import", str(rig), "--out", str(tmp_path / "c"))
    assert code == 2 and "depth.file: depth.jpg: unknown file type '.jpg'" in err


def test_export_refuses_an_existing_folder_and_a_capture_without_a_stack(rigdir, tmp_path, capsys):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    write_capture(analytic_capture(width=64, height=48), tmp_path / "cap")
    code, _, err = run(capsys, "rig", "export", str(tmp_path / "cap"), "--out", str(tmp_path / "mine"))
    assert code == 2 and err.startswith(f"nearlight: error: {tmp_path / 'mine'}: already exists")
    assert (tmp_path / "mine" / "notes.txt").read_text() == "mine"
    write_capture(analytic_capture(width=64, height=48, analyzer_angles_deg=None), tmp_path / "spec")
    code, _, err = run(capsys, "rig", "export", str(tmp_path / "spec"), "--out", str(tmp_path / "r2"))
    assert code == 2 and "no analyzer stack" in err and err.count("\n") == 1
    code, _, err = run(capsys, "rig", "export", str(tmp_path / "cap"), "--out", str(tmp_path / "r3"), "--bits", "20")
    assert code == 2 and err.startswith("nearlight: error: --bits: expected an integer from 1 to 16")


def test_import_refuses_to_replace_what_it_did_not_write(rigdir, tmp_path, capsys):
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "notes.txt").write_text("mine")
    code, _, err = run(capsys, "rig", "import", str(rigdir / "rig.yaml"), "--out", str(tmp_path / "c"), "--overwrite")
    assert code == 2 and "replaces only a capture" in err
    assert (tmp_path / "c" / "notes.txt").read_text() == "mine"
