"""Measure the silhouette overlap (IoU) of good rig round trips and of their flipped depth maps.

    .venv/bin/python benchmarks/bench_silhouette.py [--mitsuba]

Each capture is exported by the rig simulator (``rig export``: mono mosaic, 16-bit PNG depth in mm), its
depth map flipped up/down, left/right and both, and each version imported with the importer's own check
switched off; printed: the IoU of the frames' silhouette with the range's as stored and under each flip,
and what :func:`nearlight.capture.silhouette.mirrored` says (``-``: accepted). The thresholds in
``capture/silhouette.py`` and ``docs/rig-files.md`` come from this printout.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from nearlight.capture import write_capture
from nearlight.generator.analytic import analytic_capture
from nearlight.capture.silhouette import mirrored, silhouette_overlap
from nearlight.rig import importer
from nearlight.rig.export import export_rig
from nearlight.rig.rigfile import load_rig_file


def captures(with_mitsuba: bool):
    yield "board 0.4 m", analytic_capture(width=128, height=96)
    yield "board 0.25 m, off-centre", analytic_capture(width=128, height=96, board_size=0.25,
                                                        board_centre=(0.05, 0.04, 0.0))
    yield "board filling the view", analytic_capture(width=128, height=96, board_size=5.0)
    yield "sphere", analytic_capture(width=128, height=96, shape="sphere")
    yield "sphere, low", analytic_capture(width=128, height=96, shape="sphere", sphere_centre=(0.0, 0.08, 0.05),
                                          sphere_radius=0.1, look_at=(0.0, 0.0, 0.15))
    yield "sphere, right", analytic_capture(width=128, height=96, shape="sphere", sphere_centre=(-0.12, 0.0, 0.1),
                                            sphere_radius=0.08, look_at=(0.0, 0.0, 0.1))
    yield "sphere, low right", analytic_capture(width=128, height=96, shape="sphere", sphere_radius=0.07,
                                                sphere_centre=(-0.1, 0.06, 0.07), look_at=(0.0, 0.0, 0.1))
    if with_mitsuba:
        from nearlight.generator.render import render_clean
        from nearlight.generator.scene import load_scene

        for name in ("cylinder", "sphere", "ts_board", "torus"):
            scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / f"{name}.yaml",
                               overrides={"camera.resolution": [128, 96], "capture.spp": 16})
            yield f"mitsuba {name}", render_clean(scene, cache_dir=Path(tempfile.gettempdir()) / "nearlight-rigcheck-cache", progress=False)


def row(lum, valid) -> str:
    c, i = silhouette_overlap(lum, valid), silhouette_overlap(lum, valid, measure="iou")
    return " ".join(f"{c[k]:5.3f}/{i[k]:5.3f}" for k in ("as stored", "up/down", "left/right", "up/down and left/right"))


def main() -> None:
    importer_check = importer.check_depth_silhouette
    importer.check_depth_silhouette = lambda *a: None  # measure the flipped versions too
    import cv2

    print("cover: fraction of the frames' signal pixels with a valid range (decides); iou: of the two masks")
    print(f"{'capture':26s} {'depth':19s} {'as stored':>13s} {'up/down':>11s} {'left/right':>11s} {'both':>11s}  verdict")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, cap) in enumerate(captures("--mitsuba" in sys.argv)):
            d = Path(tmp) / f"c{k}"
            write_capture(cap, d / "cap")
            export_rig(cap, d / "rig", mosaic="mono", seed=0, full_well=20000.0, read_noise=5.0, bits=12,
                       depth_scale=1e-3, depth_format="png")
            depth = cv2.imread(str(d / "rig" / "depth.png"), cv2.IMREAD_UNCHANGED)
            for flip, img in {"as stored": depth, "flip up/down": depth[::-1], "flip left/right": depth[:, ::-1],
                              "flip both": depth[::-1, ::-1]}.items():
                cv2.imwrite(str(d / "rig" / "depth.png"), np.ascontiguousarray(img))
                imp = importer.rig_capture(load_rig_file(d / "rig" / "rig.yaml"))
                lum = np.nanmean(imp.stack, axis=(0, -1))
                verdict = mirrored(lum, imp.surface_mask)
                print(f"{name:26s} {flip:19s} {row(lum, imp.surface_mask)}  "
                      f"{'-' if verdict is None else 'refused: ' + verdict[0]}")
            print(f"{name:26s} {'(original capture)':19s} {row(np.nanmean(cap.stack, axis=(0, -1)), cap.surface_mask)}")
    importer.check_depth_silhouette = importer_check


if __name__ == "__main__":
    main()
