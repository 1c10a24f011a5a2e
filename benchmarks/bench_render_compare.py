"""Benchmark: ``render-compare`` beside ``full``: lamp error, σ error and run time on small rendered boards.

The §4.1 board (``scenes/ts_board.yaml``) rendered at 160 x 120, noise-free, in
three materials:

- ``torrance_sparrow``: the scene as shipped (paper eq. 6, ``ideal``
  polarization): ``full``'s own model;
- ``pplastic``: Mitsuba's polarized plastic (``material.model: mitsuba``),
  same diffuse albedo, ``alpha`` = √2 · 0.10 so that its Beckmann-equivalent σ
  (:mod:`nearlight.rendercompare.lobes`) is the shipped board's 0.10;
- ``beckmann``: Mitsuba's Beckmann conductor (``material: none``), the same
  ``alpha``: ``render-compare``'s default lobe.

Each capture is separated from its 8-angle analyzer stack by the methods
themselves (``projected``). Errors: lamp position as % of the true lamp's
distance from the highlight point, and ``|σ − σ_true| / σ_true`` with σ_true
0.10 on all three (:mod:`nearlight.evaluation.scoring.metrics`). Run time: wall
clock of ``estimate()``, Mitsuba already initialised by the render (Dr.Jit
compiles each new kernel once per process: included). Printed, not asserted.

    .venv/bin/python benchmarks/bench_render_compare.py [--width 160 --height 120]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from nearlight.estimator import estimate
from nearlight.evaluation.scoring.metrics import highlight_point, lamp_position_error_pct, sigma_relative_error
from nearlight.generator import load_scene, render_clean

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "ts_board.yaml"
SIGMA = 0.10  # the shipped board's σ; the Mitsuba boards' alpha is its Beckmann equivalent
ALPHA = math.sqrt(2.0) * SIGMA
KD = {"type": "rgb", "value": [0.30, 0.20, 0.15]}  # the shipped board's diffuse albedo
MATERIALS = {
    "torrance_sparrow": None,
    "pplastic": {"model": "mitsuba", "bsdf": {"type": "pplastic", "diffuse_reflectance": KD, "alpha": ALPHA}},
    "beckmann": {"model": "mitsuba",
                 "bsdf": {"type": "roughconductor", "material": "none", "distribution": "beckmann", "alpha": ALPHA}},
}  # fmt: skip
RUNS = [("full", {}), ("render-compare", {}), ("render-compare", {"bsdf": "pplastic"}),
        ("render-compare", {"bsdf": "pplastic", "lamp_polarizer": False})]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=160)
    parser.add_argument("--height", type=int, default=120)
    args = parser.parse_args()
    print(f"ts_board.yaml at {args.width}x{args.height}, noise-free; sigma_true {SIGMA}")
    print(f"{'board':<17} {'method':<15} {'options':<40} {'lamp err %':>10} {'sigma err':>9} {'time s':>7} {'iters':>5}")
    for name, material in MATERIALS.items():
        overrides = {"camera.resolution": [args.width, args.height]}
        if material is not None:
            overrides["material"] = material
        cap = render_clean(load_scene(SCENE, overrides=overrides), progress=False)
        truth = np.asarray(cap.truth["lamp_position"], float)
        origin = highlight_point(cap.P, cap.N, cap.camera.position, truth)
        for method, options in RUNS:
            clock = time.perf_counter()
            est = estimate(cap, method=method, **options)
            seconds = time.perf_counter() - clock
            err = lamp_position_error_pct(est.lamp_position, truth, origin=origin)
            sig = sigma_relative_error(est.sigma, SIGMA)
            iters = est.stages.get("render-compare", {}).get("iterations", est.stages.get("full", {}).get("nfev", ""))
            opts = " ".join(f"{k}={v}" for k, v in options.items()) or "-"
            print(f"{name:<17} {method:<15} {opts:<40} {err:>10.3f} {sig:>9.4f} {seconds:>7.2f} {iters:>5}")


if __name__ == "__main__":
    main()
