"""How many lamps: count accuracy of ``full`` with ``lamps=auto`` over seeds and noise levels.

Analytic captures (``nearlight.generator.analytic``, no Mitsuba; 160×120 by
default, 4 analyzer angles) with the sensitivity study's camera noise
(``low``: 50 000 e full well, 3 e read, 14 bits; ``high``: 5 000 e, 10 e, 10
bits; ``saturation: auto``; ``none``: the noise-free capture, one seed):

- ``two``: scenes/two_lamps.yaml in closed form, two equal lamps 30° apart as
  seen from the board's centre (the acceptance bar: right count on ≥ 95 %
  of noisy captures, each lamp within 1 % of its distance);
- ``two-dim``: the same with the second lamp at a quarter of the intensity;
- ``board``, ``sphere``, ``board-near``: one lamp (the bar: no extra lamp on
  ≥ 99 % of configurations).

Per configuration and noise level: how often each count was chosen, the
median and worst lamp error (% of each true lamp's distance from its
highlight point, the nearest estimated lamp; captures with the right count),
and the mean run time. Printed, not asserted.

Measured (5 seeds, 2 shared cores, 391 s): right count 100 % in every row;
``two`` median/worst error 0.000/0.000 % noise-free, 0.117/0.150 % low,
0.261/0.499 % high; ``two-dim`` 0.095/0.207 % low, 0.218/0.659 % high.
At 20 seeds (``--seeds 20 --noise low high``, two processes on 2 cores, 360 s
and 292 s): right count on 80 of 80 two-lamp captures and 120 of 120 one-lamp
ones; ``two`` median/worst 0.067/0.241 % low, 0.234/2.801 % high; ``two-dim``
0.089/0.279 %, 0.240/0.964 %.

With the ray and split starts for K ≥ 2 (estimator/several.py; ``--seeds 5
--noise none low high``, 161 s; before, 224 s for low and high and 18 s
noise-free): right count 100 % in every row and every error as before;
s/fit two 3.2/2.7/2.9 (none/low/high; before 6.0/5.3/5.3), two-dim
3.2/4.0/4.3 (3.5/4.3/6.1), board 3.5/1.9/2.2 (4.2/3.3/6.8), board-near
5.7/0.9/1.2 (1.6/1.0/1.4), sphere 4.4/4.2/3.6 (2.7/6.4/4.5); the "before"
noisy rows ran beside other work of this session, so they are upper bounds.

With the count's s² at least the fit's own loss floor (``loss_floor``;
same command, 216 s beside a 2-worker report regeneration): right count
100 % in every row (noise-free ones included, where the floor binds),
``two`` and ``two-dim`` errors as above; one-lamp rows: board
0.200/0.260 % low, 0.462/0.818 % high; sphere 0.093/1.527 %, 1.577/3.377 %.

Usage::

    .venv/bin/python benchmarks/bench_several_lamps.py --seeds 10
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

from nearlight.estimator import estimate
from nearlight.evaluation.scoring.metrics import lamp_scores
from nearlight.generator.analytic import analytic_capture_lamps
from nearlight.generator.noise import add_camera_noise

NOISE = {
    "none": None,
    "low": {"full_well": 50000, "read_noise": 3.0, "bits": 14, "saturation": "auto"},
    "high": {"full_well": 5000, "read_noise": 10.0, "bits": 10, "saturation": "auto"},
}
#: scenes/two_lamps.yaml's geometry and material.
TWO = dict(camera_position=(0.0, -0.35, 0.55), board_size=0.3, fov_x_deg=40.0, kd=(0.3, 0.2, 0.15),
           bsdf={"model": "torrance_sparrow", "ks": [0.3, 0.3, 0.3], "sigma": 0.1})
LAMPS = [[0.1294, 0.2352, 0.4218], [-0.1294, 0.2352, 0.4218]]
CONFIGS = {
    "two": lambda w, h: analytic_capture_lamps([{"position": p} for p in LAMPS], width=w, height=h, **TWO),
    "two-dim": lambda w, h: analytic_capture_lamps(
        [{"position": LAMPS[0]}, {"position": LAMPS[1], "intensity": [0.5, 0.5, 0.5]}], width=w, height=h, **TWO),
    "board": lambda w, h: analytic_capture_lamps([{"position": [0.05, 0.15, 0.35]}], width=w, height=h),
    "board-near": lambda w, h: analytic_capture_lamps([{"position": [0.0, 0.05, 0.12]}], width=w, height=h),
    "sphere": lambda w, h: analytic_capture_lamps([{"position": [0.1, 0.1, 0.6]}], shape="sphere", width=w, height=h),
}


def lamp_errors_pct(capture, est) -> list[float]:
    """Per true lamp, the error (% of its distance from its highlight point) of the estimated lamp matched
    to it (:func:`nearlight.evaluation.scoring.metrics.lamp_scores`; NaN when missed)."""
    s, n = lamp_scores(capture, est), len(capture.truth["lamps"])
    return [s["lamp_position_error_pct"]] if n == 1 else [s[f"lamp{i}_position_error_pct"] for i in range(n)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=list(CONFIGS))
    ap.add_argument("--noise", nargs="+", choices=list(NOISE), default=list(NOISE))
    ap.add_argument("--resolution", nargs=2, type=int, default=(160, 120), metavar=("W", "H"))
    args = ap.parse_args()
    clock = time.perf_counter()
    print(f"{'config':11} {'noise':5} {'true':>4} {'right':>7}  counts        {'median %':>9} {'worst %':>8} {'s/fit':>6}")
    for name in args.configs:
        clean = CONFIGS[name](*args.resolution)
        true = len(clean.truth["lamps"])
        for level in args.noise:
            seeds = [0] if NOISE[level] is None else range(args.seeds)
            counts: Counter = Counter()
            errors, seconds = [], []
            for seed in seeds:
                cap = clean if NOISE[level] is None else add_camera_noise(clean, noise=NOISE[level], seed=seed)
                t = time.perf_counter()
                est = estimate(cap, method="full", lamps="auto")
                seconds.append(time.perf_counter() - t)
                k = est.stages["full"]["n_lamps"]
                counts[k] += 1
                if k == true:
                    errors += lamp_errors_pct(clean, est)
            right = counts[true] / len(seeds)
            med, worst = (f"{np.median(errors):9.3f}", f"{np.max(errors):8.3f}") if errors else (f"{'-':>9}", f"{'-':>8}")
            shown = " ".join(f"{k}:{v}" for k, v in sorted(counts.items()))
            print(f"{name:11} {level:5} {true:4d} {right:7.0%}  {shown:13} {med} {worst} {np.mean(seconds):6.1f}",
                  flush=True)
    print(f"\n{time.perf_counter() - clock:.0f} s")


if __name__ == "__main__":
    main()
