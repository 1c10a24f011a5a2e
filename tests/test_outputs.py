"""Output places: ``--overwrite`` replaces only a capture; no verb replaces a file nearlight did not write."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nearlight.capture import Camera, Capture, read_capture, write_capture
from nearlight.cli import main
from nearlight.errors import UserError
from nearlight.files.outputs import check_file_out, is_capture_dir

SCENES = Path(__file__).resolve().parents[1] / "scenes"
TINY = ["--set", "camera.resolution=[24,18]", "--quiet", "--no-cache"]


def _capture(rng: np.random.Generator, value: float = 1.0) -> Capture:
    h, w = 4, 5
    P = np.dstack([*np.meshgrid(np.linspace(-0.1, 0.1, w), np.linspace(0.1, -0.1, h)), np.zeros((h, w))])
    return Capture(width=w, height=h, camera=Camera(position=np.array([0.0, 0.0, 1.0])),
                   P=P.astype(np.float32), specular=np.full((h, w, 3), value, np.float32))  # fmt: skip


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else b"<dir>" for p in sorted(folder.rglob("*"))}


def _user_folders(root: Path) -> list[Path]:
    """Folders that are not captures: someone's files, a capture with an extra file, a look-alike."""
    a = root / "thesis"
    a.mkdir()
    (a / "thesis.tex").write_text("\\chapter{Results}\n")
    b = root / "capture_plus_notes"
    write_capture(_capture(np.random.default_rng(0)), b)
    (b / "notes.txt").write_text("my notes")
    c = root / "lookalike"
    c.mkdir()
    (c / "capture.json").write_text('{"format": "something-else/1"}')
    (c / "capture.exr").write_bytes(b"\x76\x2f\x31\x01 not really")
    d = root / "empty"
    d.mkdir()
    e = root / "a_file"
    e.write_text("data")
    return [a, b, c, d, e]


def test_is_capture_dir(tmp_path, rng):
    assert is_capture_dir(write_capture(_capture(rng), tmp_path / "cap"))
    assert not any(is_capture_dir(p) for p in _user_folders(tmp_path))
    assert not is_capture_dir(tmp_path / "missing")


def test_write_capture_overwrite_refuses_what_is_not_a_capture(tmp_path, rng):
    for folder in _user_folders(tmp_path):
        before = _snapshot(tmp_path)
        with pytest.raises(UserError, match="replaces only a capture|already exists") as info:
            write_capture(_capture(rng), folder, overwrite=True)
        assert "\n" not in str(info.value) and str(folder) in str(info.value)
        assert _snapshot(tmp_path) == before  # untouched, nothing beside it either


def test_write_capture_overwrite_replaces_a_capture(tmp_path, rng):
    folder = write_capture(_capture(rng, 1.0), tmp_path / "cap")
    write_capture(_capture(rng, 2.0), folder, overwrite=True)
    assert float(read_capture(folder).specular.max()) == 2.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap"]  # no .partial/.old left behind


def test_render_overwrite_on_a_user_folder_is_refused_before_rendering(tmp_path, capsys, monkeypatch):
    from nearlight.generator import render as render_module

    def no_render(*a, **k):
        raise AssertionError("Mitsuba must not run")

    monkeypatch.setattr(render_module, "_render_arrays", no_render)
    for folder in _user_folders(tmp_path):
        before = _snapshot(tmp_path)
        assert main(["render", str(SCENES / "ts_board.yaml"), "--out", str(folder), "--overwrite", *TINY]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"nearlight: error: {folder}: "), err
        assert _snapshot(tmp_path) == before


@pytest.mark.render
def test_render_overwrite_replaces_a_real_capture(tmp_path, capsys):
    out = tmp_path / "cap"
    scene = str(SCENES / "ts_board.yaml")
    assert main(["render", scene, "--out", str(out), *TINY]) == 0
    assert is_capture_dir(out)
    assert main(["render", scene, "--out", str(out), *TINY, "--overwrite", "--set", "lamp.intensity=[4,4,4]"]) == 0
    assert read_capture(out).truth["lamp_intensity"] == [4.0, 4.0, 4.0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap"]


@pytest.mark.parametrize(
    ("name", "content", "kind", "ok"),
    [
        ("a.png", b"\x89PNG\r\n\x1a\n...", "png", True),
        ("a.png", b"my holiday photo, not a png", "png", False),
        ("a.json", json.dumps({"method": "paper", "lamp_position": [0, 0, 1]}).encode(), "estimate", True),
        ("a.json", b'{"my": "settings"}', "estimate", False),
        ("a.json", b"\xff\xfe binary", "estimate", False),
        ("summary.md", b"# Sweep report: x\n", "report-md", True),
        ("summary.md", b"# My notes\n", "report-md", False),
        ("overall.csv", b"method,metric,n\n", "report-csv", True),
        ("overall.csv", b"name,phone\n", "report-csv", False),
    ],
)
def test_file_outputs_replace_only_their_own_kind(tmp_path, name, content, kind, ok):
    path = tmp_path / name
    path.write_bytes(content)
    if ok:
        assert check_file_out(path, kind) == path
    else:
        with pytest.raises(UserError, match="exists and is not"):
            check_file_out(path, kind)
    assert path.read_bytes() == content


def test_file_output_names(tmp_path):
    with pytest.raises(UserError, match=r"ending in \.png"):
        check_file_out(tmp_path / "sheet.jpg", "png")
    (tmp_path / "d.png").mkdir()
    with pytest.raises(UserError, match="is a folder"):
        check_file_out(tmp_path / "d.png", "png")


def test_a_failing_plot_leaves_no_estimate_json_behind(tmp_path, capsys, monkeypatch):
    from nearlight.estimator import cli as estimator_cli
    from nearlight.generator.analytic import analytic_capture

    cap = write_capture(analytic_capture(width=32, height=24), tmp_path / "cap")

    def fail(capture, estimate, path):
        raise UserError(f"{path}: cannot write the figure (disk full)")

    monkeypatch.setattr(estimator_cli, "plot_estimate", fail)  # where the verb finds it
    argv = ["estimate", str(cap), "--method", "paper-init", "--json", str(tmp_path / "e.json"),
            "--plot", str(tmp_path / "e.png")]  # fmt: skip
    assert main(argv) == 2
    assert "disk full" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap"]
