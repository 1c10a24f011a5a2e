"""Render cost: the closed-form renderer against Mitsuba, per shipped scene, at the studies' resolutions.

Each shipped scene the closed form covers (``generator.closed_form.not_covered`` empty), and the TS board
with a 2 cm sphere lamp, is rendered at the GSA's 120x90 and the sweeps' 160x120 by both renderers, a new
lamp position each time (Dr.Jit compiles a kernel per scene's values, as a study's every sample is new), after
one warm-up render of each. Printed: the median CPU seconds of the process (all threads: Mitsuba renders on
every core, so core-seconds) of each renderer over ``--repeats`` scenes, and the closed form's speed-up as a
ratio of the two medians in the same process (what carries over to another machine). Printed, not asserted
(issue 36's throughput benchmark; ``bench_throughput.py`` times whole tasks).

Usage::

    .venv/bin/python benchmarks/bench_closed_form.py
    .venv/bin/python benchmarks/bench_closed_form.py --resolutions 120x90 --repeats 3
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

SCENES = Path(__file__).resolve().parents[1] / "scenes"
#: (label, scene file, overrides).
CASES = [
    ("ts board", "ts_board.yaml", {}),
    ("ward board", "ward_board.yaml", {}),
    ("sphere", "sphere.yaml", {}),
    ("cylinder", "cylinder.yaml", {}),
    ("bookend", "bookend.yaml", {}),
    ("two lamps", "two_lamps.yaml", {}),
    ("ts board, 2 cm lamp", "ts_board.yaml", {"lamp.radius": 0.02}),
]


def cpu_seconds(fn) -> float:
    t = time.process_time()
    fn()
    return time.process_time() - t


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--resolutions", default="120x90,160x120")
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    from nearlight.generator import load_scene, render_clean
    from nearlight.generator.closed_form import not_covered, render_closed_form

    print(f"{'scene':<22}{'res':>9}{'mitsuba s':>11}{'closed s':>10}{'ratio':>8}")
    for label, name, over in CASES:
        for res in args.resolutions.split(","):
            w, h = map(int, res.split("x"))
            base = load_scene(SCENES / name, overrides={**over, "camera.resolution": [w, h]})
            if not_covered(base):
                print(f"{label:<22}{res:>9}  not covered: {not_covered(base)[0]}")
                continue
            times = {"mitsuba": [], "closed": []}
            for k in range(args.repeats + 1):
                moved = {**over, "camera.resolution": [w, h]}
                key = "lamp.position" if len(base.lamps) == 1 else "lamps.0.position"
                moved[key] = list(np.add(base.lamps[0].position, [1e-4 * (k + 1) + 1e-7 * (time.time_ns() % 997), 0, 0]))
                scene = load_scene(SCENES / name, overrides=moved)
                m = cpu_seconds(lambda: render_clean(scene, progress=False))
                c = cpu_seconds(lambda: render_closed_form(scene))
                if k:  # the first of each is the warm-up (imports, the first compilation)
                    times["mitsuba"].append(m)
                    times["closed"].append(c)
            tm, tc = np.median(times["mitsuba"]), np.median(times["closed"])
            print(f"{label:<22}{res:>9}{tm:>11.3f}{tc:>10.3f}{tm / tc:>8.1f}")


if __name__ == "__main__":
    main()
