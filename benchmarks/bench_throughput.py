"""Study throughput: tasks per core-second for each renderer and method at the studies' resolutions.

What limits every study nearlight ships (the GSA at 120x90, the sensitivity
and realism sweeps at 160x120) is the cost of a task: a render, the noise,
the method, the score. This script runs the same tasks through the sweep
engine's own task runner (``evaluation.engine.tasks.run_task``) with the
Mitsuba renderer, with its closed form (``renderer: closed-form``, the same
scene file: what ``renderer: auto`` uses where it covers the scene) and with
the analytic captures (``renderer: analytic``), on the GSA's scene (``sweeps/global.yaml``: its board, or a
sphere in its place; its camera, lamp and Torrance-Sparrow lobe), its camera
noise and its methods. Every scene is one Dr.Jit has not rendered
before (its lamp at a distance never used; Dr.Jit compiles a kernel per
scene's values and keeps it, in memory and in ~/.drjit), as a GSA sample's is.
Each scene is rendered once and timed apart from the methods run on it
(each method's row: noise, estimate, score), so the script prints, for each
renderer: a render, each method, a task with one method (render + method)
and a GSA sample (one render, every method), in CPU seconds of the process
(all threads: Mitsuba renders on every core, so core-seconds, not wall
clock), per core-second, and each renderer's throughput as a ratio to
Mitsuba's (today's studies render with Mitsuba). Imports and the
first compilation are paid once before timing. Printed, not asserted: the
machine is shared, and a ratio inside one process is what carries over to
another machine (issue 36's throughput benchmark).

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_throughput.py         # 120x90 and 160x120, board and sphere
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_throughput.py --resolutions 120x90 --objects board --tasks 5
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

#: The GSA's sweep file: its scene (camera, board, Torrance-Sparrow lobe, lamp, analyzer), its camera noise and
#: its methods are the benchmark's, so the benchmark follows the study when the file changes.
GSA = Path(__file__).resolve().parents[1] / "sweeps" / "global.yaml"
#: The objects: the GSA's board, and the realism study's sphere (radius 0.1 m about the origin).
OBJECTS = {"board": None, "sphere": {"type": "sphere", "radius": 0.1}}


#: Lamp distances, m from the object, a new one for every scene this process renders (see the module
#: docstring): from 0.35-0.45 m (a start drawn from the clock, so no two runs share one) in 0.1 mm steps.
_DISTANCES = iter(0.35 + 1e-7 * (time.time_ns() % 10**6) + 1e-4 * np.arange(10**6))


def sweep_doc(renderer: str, obj: str, width: int, height: int, tasks: int) -> dict:
    """A sweep of ``tasks`` scenes (each its lamp distance never rendered before) and the GSA's methods, in
    ``renderer``'s scene format."""
    from nearlight.files.yamlfile import load_yaml_file

    gsa = load_yaml_file(GSA, what="sweep file")
    base = gsa["scene"]
    scene = {**base, "camera": {**base["camera"], "resolution": [width, height]},
             "object": OBJECTS[obj] or base["object"]}
    if renderer == "analytic":
        cam, lamp, mat, o = scene["camera"], scene["lamp"], scene["material"], scene["object"]
        shape = ({"shape": "board", "board_size": o["size"][0]} if o["type"] == "board"
                 else {"shape": "sphere", "sphere_radius": o["radius"], "sphere_centre": [0.0, 0.0, 0.0]})
        scene = {"width": width, "height": height, "fov_x_deg": cam["fov_x_deg"], "camera_position": cam["position"],
                 "look_at": cam["look_at"], "lamp_position": lamp["position"], "lamp_intensity": lamp["intensity"],
                 "bsdf": {k: v for k, v in mat.items() if k != "kd"}, "kd": mat["kd"],
                 "analyzer_angles_deg": scene["capture"]["analyzer_angles_deg"], "with_normals": True, **shape}
    return {"name": f"throughput-{renderer}", "renderer": renderer, "scene": scene,
            "axes": {"noise": {"gsa camera": gsa["noise"]},
                     "lamp_distance": [float(next(_DISTANCES)) for _ in range(tasks)]},
            "seeds": 1, "methods": gsa["methods"], "crlb": False}


class _Rendered:
    """A renderer that hands back one capture already rendered (the render timed apart from the method)."""

    def __init__(self, capture: object) -> None:
        self.capture = capture

    def render(self, scene: dict, *, cache_dir: object) -> object:
        return self.capture


def timed(renderer: str, obj: str, width: int, height: int, tasks: int
          ) -> tuple[list[float], dict[str, list[float]], dict[str, int]]:
    """CPU seconds of each new scene's render; of each task after it (noise, method, score) per method; and the
    count of tasks each method failed (it said why)."""
    from nearlight.evaluation.engine.run import task_payload
    from nearlight.evaluation.engine.sweep import load_sweep
    from nearlight.evaluation.engine.tasks import run_task

    warm = load_sweep(sweep_doc(renderer, obj, width, height, 1))
    for task in warm.tasks:  # imports, the first compilation, each method's first call
        run_task(task_payload(task, warm), renderer=warm.renderer, cache_dir=None)
    sweep = load_sweep(sweep_doc(renderer, obj, width, height, tasks))
    renders: list[float] = []
    per: dict[str, list[float]] = {}
    failed: dict[str, int] = {}
    captures: dict[str, object] = {}
    for task in sweep.tasks:
        if task.render_key not in captures:
            t0 = time.process_time()
            captures[task.render_key] = sweep.renderer.render(task.scene, cache_dir=None)
            renders.append(time.process_time() - t0)
        t0 = time.process_time()
        row = run_task(task_payload(task, sweep), renderer=_Rendered(captures[task.render_key]), cache_dir=None)
        per.setdefault(task.method.label, []).append(time.process_time() - t0)
        if row.get("status") == "error" and not str(row.get("error", "")).startswith("estimate:"):
            raise SystemExit(f"{renderer} {obj} {task.method.label}: {row['error']}")
        failed[task.method.label] = failed.get(task.method.label, 0) + (row.get("status") != "ok")
    return renders, per, failed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolutions", nargs="+", default=["120x90", "160x120"], help="WxH, the studies' sizes")
    ap.add_argument("--objects", nargs="+", choices=sorted(OBJECTS), default=["board", "sphere"])
    ap.add_argument("--tasks", type=int, default=3, help="scenes per renderer, each run by every method; medians")
    ap.add_argument("--renderers", nargs="+", default=["closed-form", "analytic"],
                    choices=["closed-form", "analytic"], help="timed against Mitsuba (today's studies' renderer)")
    args = ap.parse_args()
    others = args.renderers
    print("CPU seconds (all threads), median over scenes; per core-second; each renderer's throughput / Mitsuba's "
          "(ratio); how many tasks each method failed (it said why)")
    print(f"{'res':>8} {'object':<7}{'':<19}{'mitsuba s':>10}{'per core-s':>11}"
          + "".join(f"{r + ' s':>15}{'per core-s':>11}{'ratio':>7}" for r in others)
          + "  failed (mitsuba, " + ", ".join(others) + ")")  # fmt: skip
    for res in args.resolutions:
        width, height = (int(v) for v in res.lower().split("x"))
        for obj in args.objects:
            names = ["mitsuba", *others]
            got = {r: timed(r, obj, width, height, args.tasks) for r in names}
            render = {r: float(np.median(got[r][0])) for r in got}
            method = {r: {m: float(np.median(v)) for m, v in got[r][1].items()} for r in got}
            labels = list(method["mitsuba"])
            rows = [("render", {r: render[r] for r in names}, "")]
            rows += [(f"{m} (method)", {r: method[r][m] for r in names},
                      "  " + ", ".join(str(got[r][2][m]) for r in names)) for m in labels]  # fmt: skip
            rows += [(f"{m} task", {r: render[r] + method[r][m] for r in names}, "") for m in labels]
            rows.append(("GSA sample", {r: render[r] + sum(method[r].values()) for r in names}, ""))
            for label, t, tail in rows:
                print(f"{res:>8} {obj:<7}{label:<19}{t['mitsuba']:>10.3f}{1 / t['mitsuba']:>11.2f}"
                      + "".join(f"{t[r]:>15.4f}{1 / t[r]:>11.1f}{t['mitsuba'] / t[r]:>7.1f}" for r in others) + tail)


if __name__ == "__main__":
    main()
