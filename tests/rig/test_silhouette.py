"""A depth map mirrored relative to the image: refused by `rig import` and by the estimator.

The rig simulator's round trip of an analytic board (and an off-centre
sphere) with its depth map flipped: `rig import` refuses it in one line naming
the depth file and the flip; the same capture imported with that check off
(as made elsewhere) is refused by `estimate`; the unflipped ones are accepted.
Thresholds: ``capture/silhouette.py``, measured by ``benchmarks/bench_silhouette.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.capture import write_capture
from nearlight.cli import main
from nearlight.capture.silhouette import mirrored
from nearlight.generator.analytic import analytic_capture

pytest.importorskip("polanalyser")
cv2 = pytest.importorskip("cv2")

SCENES = {
    "board": dict(width=64, height=48),
    "sphere-right": dict(width=64, height=48, shape="sphere", sphere_centre=(-0.12, 0.0, 0.1), sphere_radius=0.08,
                         look_at=(0.0, 0.0, 0.1)),
    "board-filling-the-view": dict(width=64, height=48, board_size=5.0),
}  # fmt: skip
FLIPS = {"up/down": (slice(None, None, -1), slice(None)), "left/right": (slice(None), slice(None, None, -1))}


@pytest.fixture(scope="module")
def rigs(tmp_path_factory):
    """Each scene's good rig folder, exported through the command."""
    tmp = tmp_path_factory.mktemp("rigs")
    out = {}
    for name, kw in SCENES.items():
        write_capture(analytic_capture(**kw), tmp / f"{name}-cap")
        assert main(["rig", "export", str(tmp / f"{name}-cap"), "--out", str(tmp / name)]) == 0
        out[name] = tmp / name
    return out


def flipped(rigdir, tmp_path, flip):
    import shutil

    folder = tmp_path / "rig"
    shutil.copytree(rigdir, folder)
    depth = cv2.imread(str(folder / "depth.png"), cv2.IMREAD_UNCHANGED)
    assert cv2.imwrite(str(folder / "depth.png"), np.ascontiguousarray(depth[FLIPS[flip]]))
    return folder / "rig.yaml"


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("scene, flip", [("board", "up/down"), ("sphere-right", "left/right")])
def test_rig_import_refuses_a_flipped_depth_map(rigs, tmp_path, capsys, scene, flip):
    rig = flipped(rigs[scene], tmp_path, flip)
    before = _snapshot(rig.parent)
    capsys.readouterr()
    assert main(["rig", "import", str(rig), "--out", str(tmp_path / "cap")]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"nearlight: error: {rig}: depth.file: depth.png: the depth map is mirrored"), err
    assert f"flip it {flip}" in err, err
    assert not (tmp_path / "cap").exists() and _snapshot(rig.parent) == before


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_unflipped_rigs_import_and_pass_the_estimators_check(rigs, tmp_path, capsys, scene):
    from nearlight.capture import read_capture
    from nearlight.estimator.observation import observation_of

    assert main(["rig", "import", str(rigs[scene] / "rig.yaml"), "--out", str(tmp_path / "cap")]) == 0
    observation_of(read_capture(tmp_path / "cap"))  # the estimators' first step, with the check: no UserError


def test_a_board_filling_the_view_has_no_silhouette_and_is_not_refused(rigs, tmp_path, capsys):
    """The documented blind spot: every mask is the whole image, so no flip fits better."""
    rig = flipped(rigs["board-filling-the-view"], tmp_path, "up/down")
    assert main(["rig", "import", str(rig), "--out", str(tmp_path / "cap")]) == 0, capsys.readouterr().err


def test_estimate_refuses_a_mirrored_capture_made_elsewhere(rigs, tmp_path, capsys, monkeypatch):
    from nearlight.rig import importer

    rig = flipped(rigs["board"], tmp_path, "up/down")
    with monkeypatch.context() as m:  # as another tool would have made it: no check on import
        m.setattr(importer, "check_depth_silhouette", lambda *a: None)
        assert main(["rig", "import", str(rig), "--out", str(tmp_path / "cap")]) == 0
    before = _snapshot(tmp_path / "cap")
    capsys.readouterr()
    for method in ("paper-init", "full"):
        assert main(["estimate", str(tmp_path / "cap"), "--method", method]) == 2
        out, err = capsys.readouterr()
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert err.startswith(f"nearlight: error: {tmp_path / 'cap'}: channel P: the range is mirrored"), err
        assert "flipped up/down" in err
    assert _snapshot(tmp_path / "cap") == before


def test_good_captures_are_not_mirrored():
    """The analytic originals (no noise): no flip fits better, also for a sphere half in shadow."""
    for kw in SCENES.values():
        cap = analytic_capture(**kw)
        assert mirrored(np.nanmean(cap.stack, axis=(0, -1)), cap.surface_mask) is None
        for idx in FLIPS.values():  # and the flipped P is found whenever the silhouette is not symmetric
            found = mirrored(np.nanmean(cap.stack, axis=(0, -1)), cap.surface_mask[idx])
            assert found is None or found[1] > found[2]
