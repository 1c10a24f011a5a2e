"""Seconds of the printed AM (method ``paper``, §3.4): the plain transcription vs the fast one.

Builds a noise-free analytic Torrance–Sparrow board like ``scenes/ts_board.yaml``
(camera 0.65 m off, 40° field of view, 0.3 m board, σ = 0.1) with the lamp
``--distance`` metres from the board centre along the scene's lamp direction:
the far lamp of the near-vs-distant study, where the first stage's t* is far
off and the AM walks t in 1-mm steps (about 1400 of them at 2 m). Runs the
first stage once, then in the same process
:func:`~nearlight.estimator.paper.alternating_minimisation_reference` and
:func:`~nearlight.estimator.paper.alternating_minimisation` from the same
start, and prints their seconds, the ratio, and how far their results are
apart (the same t and step counts are expected; Ks, σ to rounding).
Printed, not asserted: the machine is shared.

Usage::

    .venv/bin/python benchmarks/bench_paper_am.py                       # 640x480, ~4 min
    .venv/bin/python benchmarks/bench_paper_am.py --resolution 320 240 --distance 1.2
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nearlight.estimator.first_stage import stage_one
from nearlight.estimator.paper import Energy, alternating_minimisation, alternating_minimisation_reference
from nearlight.generator.analytic import analytic_capture


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", nargs=2, type=int, default=(640, 480), metavar=("W", "H"))
    ap.add_argument("--distance", type=float, default=2.0, help="lamp distance from the board centre, metres")
    args = ap.parse_args()
    w, h = args.resolution
    direction = np.array([0.10, 0.25, 0.45]) / np.linalg.norm([0.10, 0.25, 0.45])
    cap = analytic_capture(
        width=w, height=h, fov_x_deg=40.0, camera_position=(0.0, -0.35, 0.55), board_size=0.3,
        lamp_position=tuple(args.distance * direction), analyzer_angles_deg=None,
        bsdf={"model": "torrance_sparrow", "ks": [0.3, 0.3, 0.3], "sigma": 0.1},
    )
    init, obs = stage_one(cap)
    d = init.diagnostics
    print(f"printed AM: {w}x{h} TS board, lamp {args.distance} m, {int(obs.surface.sum())} surface pixels, "
          f"t* = {init.stages['init']['t']:.3f} m")
    runs = {}
    for name, am in (("reference", alternating_minimisation_reference), ("fast", alternating_minimisation)):
        energy = Energy(obs, np.asarray(d["ray_origin"]), np.asarray(d["ray_direction"]), t_ref=init.stages["init"]["t"])
        clock = time.perf_counter()
        out = am(energy, ks=init.ks, sigma=init.sigma, t=init.stages["init"]["t"], dt=d["dt"])
        runs[name] = (time.perf_counter() - clock, out)
        print(f"  {name:9} {runs[name][0]:8.2f} s  t = {out['t']:.6f} m  outer {out['outer']}  inner {out['inner']}  "
              f"halvings {out['halvings']}")
    (t_ref, ref), (t_fast, fast) = runs["reference"], runs["fast"]
    print(f"  speed-up {t_ref / t_fast:.1f}x; same t: {fast['t'] == ref['t']}; same outer/inner steps: "
          f"{(fast['outer'], fast['inner']) == (ref['outer'], ref['inner'])}; Ks max rel diff "
          f"{np.max(np.abs(fast['ks'] / ref['ks'] - 1)):.1e}; sigma rel diff {abs(fast['sigma'] / ref['sigma'] - 1):.1e}")


if __name__ == "__main__":
    main()
