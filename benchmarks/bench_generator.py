"""Seconds per capture for the shipped scenes, and the ratio to a bare Mitsuba render.

Ours: ``render_clean`` (exact P/N by ray casting, specular-only and
diffuse-only renders, Stokes rotation, analyzer stack for 8 angles), and the
whole capture, i.e. plus ``write_capture`` (the ZIP-compressed EXR). Bare: ``mi.render`` of the same Mitsuba scene with the
``stokes`` integrator, once per colour channel (what a user of Mitsuba would
run to get the same RGB Stokes images), at the same samples per pixel. Each
is timed ``--repeat`` times and the best is kept (the first run also pays for
kernel compilation).

Usage::

    .venv/bin/python benchmarks/bench_generator.py                       # 640x480, 8 angles, scene spp
    .venv/bin/python benchmarks/bench_generator.py --resolution 160 120 --scenes ts_board.yaml
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

SCENES = Path(__file__).resolve().parents[1] / "scenes"
DEFAULT = ["ts_board.yaml", "ward_board.yaml", "sphere.yaml", "cylinder.yaml", "bookend.yaml", "torus.yaml"]


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", default=DEFAULT)
    p.add_argument("--resolution", nargs=2, type=int, default=[640, 480], metavar=("W", "H"))
    p.add_argument("--spp", type=int, default=None, help="samples per pixel (default: the scene's)")
    p.add_argument("--angles", type=int, default=8, help="number of analyzer angles")
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args()

    import numpy as np

    from nearlight.capture import write_capture
    from nearlight.generator import load_scene, render_clean
    from nearlight.generator.llvm import mitsuba
    from nearlight.generator.render import scene_dict

    mi = mitsuba()
    print(f"variant {mi.variant()}, {args.resolution[0]}x{args.resolution[1]}, {args.angles} analyzer angles")
    print(f"{'scene':<18}{'spp':>5}{'render s':>10}{'capture s':>11}{'bare s':>9}{'render/bare':>13}"
          f"{'capture/bare':>14}")  # fmt: skip
    for name in args.scenes:
        overrides = {
            "camera.resolution": args.resolution,
            "capture.analyzer_angles_deg": list(np.arange(args.angles) * 180.0 / args.angles),
        }
        if args.spp is not None:
            overrides["capture.spp"] = args.spp
        scene = load_scene(SCENES / name, overrides=overrides)
        spp = scene.capture.spp

        def render() -> None:
            render_clean(scene, progress=False)

        def capture() -> None:
            cap = render_clean(scene, progress=False)
            with tempfile.TemporaryDirectory() as d:
                write_capture(cap, Path(d) / "cap")

        def bare() -> None:
            with tempfile.TemporaryDirectory() as scratch:
                for c in range(3):
                    d = scene_dict(mi, scene, part="full", channel=c, scratch=Path(scratch), stokes=True)
                    np.asarray(mi.render(mi.load_dict(d), spp=spp))

        t_bare = best_of(bare, args.repeat)
        t_render, t_capture = best_of(render, args.repeat), best_of(capture, args.repeat)
        print(f"{name:<18}{spp:>5}{t_render:>10.2f}{t_capture:>11.2f}{t_bare:>9.2f}{t_render / t_bare:>13.2f}"
              f"{t_capture / t_bare:>14.2f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
