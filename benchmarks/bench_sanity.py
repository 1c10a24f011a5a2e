"""How far the sanity rules' thresholds sit from good estimates, and what they refuse.

On analytic captures (``nearlight.generator.analytic``, no Mitsuba; 160×120,
4 analyzer angles) of the sensitivity study's design: board and sphere (r =
0.1 m), the lamp 0.25–0.7 m from the object along the study's ray, σ 0.05,
0.1, 0.2, Torrance–Sparrow and Ward (same peak and width), camera noise none,
``low`` (50 000 e full well, 3 e read, 14 bits) and ``high`` (5 000 e, 10 e,
10 bits), one seed; methods ``paper-init``, ``paper``, ``full``,
``distant``, each run with ``sanity=False`` so every statistic is seen.

Prints, per method, the estimates within 5 % of the lamp and each rule's
statistic at its worst over them (explained fraction, in-front fraction,
lamp reach over the camera distance, the ``located`` ratio) beside the
rule's threshold, then the refused estimates per rule with their error
range (``ks-scale`` refuses Ks alone and keeps the lamp). The rules are sound
when no estimate within 5 % loses its lamp.

Run: ``.venv/bin/python benchmarks/bench_sanity.py [--seeds N]`` (about 2 min
a seed on 2 cores).
"""

from __future__ import annotations

import argparse
import itertools
import warnings
from collections import defaultdict

import numpy as np

from nearlight.errors import UserError
from nearlight.estimator import estimate, sanity
from nearlight.generator.analytic import analytic_capture
from nearlight.generator.nuisances import through_rig
from nearlight.physics.reflectance import ward_from_torrance_sparrow

NOISE = {"none": None, "low": {"full_well": 50000, "read_noise": 3.0, "bits": 14},
         "high": {"full_well": 5000, "read_noise": 10.0, "bits": 10}}
RAY = np.array([0.05, 0.15, 0.35]) / np.linalg.norm([0.05, 0.15, 0.35])  # the sensitivity study's lamp ray
METHODS = ("paper-init", "paper", "full", "distant")
KS = np.array([0.8, 0.6, 0.5])


def captures(seeds: int):
    """(label, capture, true lamp) over the design."""
    for shape, d, rough, model, noise, seed in itertools.product(
            ["board", "sphere"], [0.25, 0.35, 0.5, 0.7], [0.05, 0.1, 0.2], ["torrance_sparrow", "ward"], NOISE,
            range(seeds)):
        centre = np.zeros(3) if shape == "board" else np.array([0.0, 0.0, 0.1])
        lamp = centre + d * RAY
        bsdf = {"model": "torrance_sparrow", "ks": KS.tolist(), "sigma": rough}
        if model == "ward":
            alpha, rho = ward_from_torrance_sparrow(rough, KS)
            bsdf = {"model": "ward", "rho_s": rho.tolist(), "alpha": alpha}
        kw = {"sphere_centre": tuple(centre), "sphere_radius": 0.1} if shape == "sphere" else {}
        clean = analytic_capture(shape=shape, lamp_position=tuple(lamp), bsdf=bsdf, **kw)
        cap = clean if NOISE[noise] is None else through_rig(clean, noise=NOISE[noise], seed=seed)
        yield f"{shape} d={d} σ={rough} {model} {noise} seed {seed}", cap, lamp


def statistics(cap, est, obs) -> dict[str, float]:
    """Each rule's statistic for one estimate."""
    anchor = obs.P[obs.peak]
    region, explained = sanity.own_highlight(cap, est, obs)
    w = obs.specular[region].mean(axis=-1)
    lit = np.einsum("ij,ij->i", obs.N[region], est.lamp_position - obs.P[region]) > 0
    located = np.nan
    if est.covariance is not None:
        sd = np.sqrt(max(np.linalg.eigvalsh(est.covariance[:3, :3])[-1], 0.0))
        located = sd / np.linalg.norm(est.lamp_position - anchor)
    return {"explained": explained, "in_front": float(w[lit].sum() / w.sum()),
            "reach": float(np.linalg.norm(est.lamp_position - anchor) / obs.scale), "located": located}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    good = defaultdict(list)
    refused = defaultdict(list)
    for label, cap, lamp in captures(args.seeds):
        obs = sanity.observation(cap, {})
        for method in METHODS:
            try:
                est = estimate(cap, method=method, sanity=False)
            except UserError:
                continue  # the method refused by itself (e.g. paper's t_max)
            err = 100 * np.linalg.norm(est.lamp_position - lamp) / np.linalg.norm(lamp - obs.P[obs.peak])
            failed = sanity.check(cap, est, obs, {})
            if failed is not None:
                refused[method, failed.rule].append((err, label))
            if err < 5:
                good[method].append(statistics(cap, est, obs))
    print("estimates within 5 % of the lamp: each rule's statistic at its worst (threshold)")
    print(f"{'method':11s} {'n':>4s} {'explained':>10s} {'in-front':>9s} {'reach':>7s} {'located':>8s}")
    print(f"{'(rule)':11s} {'':>4s} {'>= ' + str(sanity.EXPLAINED_MIN):>10s} {'>= ' + str(sanity.IN_FRONT_MIN):>9s} "
          f"{'<= ' + str(sanity.REACH):>7s} {'<= ' + str(sanity.LOCATED_MAX):>8s}")
    for method in METHODS:
        rows = good[method]
        if not rows:
            print(f"{method:11s} {0:4d}")
            continue
        col = {k: np.array([r[k] for r in rows]) for k in rows[0]}
        print(f"{method:11s} {len(rows):4d} {col['explained'].min():10.3f} {col['in_front'].min():9.2f} "
              f"{col['reach'].max():7.2f} {np.nanmax(col['located']) if np.isfinite(col['located']).any() else np.nan:8.3g}")
    print("\nrefused (rule; ks-scale: Ks alone, the lamp kept): count, lamp error range (%), the best-placed one")
    for (method, rule), items in sorted(refused.items()):
        errs = sorted(items)
        print(f"{method:11s} {rule:16s} {len(items):4d}  {errs[0][0]:7.2f} – {errs[-1][0]:7.2f}   {errs[0][1]}")
    worst = min((e for (_, rule), items in refused.items() if rule != "ks-scale" for e, _ in items), default=np.inf)
    print(f"\nbest refused estimate: {worst:.2f} % of the distance; "
          f"{'no estimate within 5 % refused' if worst >= 5 else 'AN ESTIMATE WITHIN 5 % WAS REFUSED'}")


if __name__ == "__main__":
    main()
