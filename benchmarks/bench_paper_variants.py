"""Lamp position error of the paper's method and its variants on analytic boards and spheres.

The printed paper (``paper-init``, ``paper``) beside the variants
that correct its two weak points, each named as what it is: the ray's origin
(``origin=subpixel``; ``origin=model``, a departure from the paper) and the
AM's t search (``am=bounded``, a departure), and the ORACLE origin
(``origin=mirror-oracle``, the true mirror point: a bound, not an estimator).
Tasks: closed-form Torrance–Sparrow captures (``nearlight.generator.analytic``)
in the layout of ``scenes/ts_board.yaml`` (camera 0.65 m off, 40°, 0.3 m
board) with the lamp at several distances from the board centre along the
scene's lamp direction and several roughnesses, noise-free and with the
sensitivity study's camera noise (full well 20000 e⁻, read noise 5 e⁻, 12
bits, auto exposure; 8 analyzer angles), plus spheres. Error: % of the true
lamp's distance from the highlight point (``nearlight.evaluation.scoring.metrics``); a method
that refuses a task counts as a failure (an infinite error in the median and
p90). Printed, not asserted.

Usage::

    .venv/bin/python benchmarks/bench_paper_variants.py                # 320x240, a few minutes
    .venv/bin/python benchmarks/bench_paper_variants.py --resolution 160 120
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np

from nearlight.errors import UserError
from nearlight.estimator import estimate
from nearlight.evaluation.scoring.metrics import highlight_point, lamp_position_error_pct
from nearlight.generator.analytic import analytic_capture
from nearlight.generator.noise import add_camera_noise

VARIANTS = {
    "paper-init (printed)": ("paper-init", {}),
    "paper (printed AM)": ("paper", {}),
    "paper-init origin=subpixel": ("paper-init", {"origin": "subpixel"}),
    "paper-init origin=model": ("paper-init", {"origin": "model"}),
    "paper origin=model am=bounded": ("paper", {"origin": "model", "am": "bounded"}),
    "ORACLE paper-init origin=mirror-oracle": ("paper-init", {"origin": "mirror-oracle"}),
}
NOISE = {"full_well": 20000, "read_noise": 5, "bits": 12, "saturation": "auto"}
DIRECTION = np.array([0.10, 0.25, 0.45]) / np.linalg.norm([0.10, 0.25, 0.45])


def tasks(w: int, h: int):
    """(label, capture) pairs."""
    angles = tuple(np.arange(8) * 22.5)
    for d, sigma, noisy in itertools.product((0.3, 0.5, 0.7, 0.9), (0.05, 0.1, 0.15), (False, True)):
        cap = analytic_capture(
            width=w, height=h, fov_x_deg=40.0, camera_position=(0.0, -0.35, 0.55), board_size=0.3,
            lamp_position=tuple(d * DIRECTION), analyzer_angles_deg=angles,
            bsdf={"model": "torrance_sparrow", "ks": [0.3, 0.3, 0.3], "sigma": sigma},
        )
        if noisy:
            cap = add_camera_noise(cap, noise=NOISE, seed=0)
        yield ("board", "noisy" if noisy else "clean", d, sigma), cap
    for lamp, sigma in itertools.product(((0.1, 0.1, 0.6), (0.2, -0.2, 0.4), (-0.1, 0.2, 0.8)), (0.05, 0.1)):
        cap = analytic_capture(width=w, height=h, shape="sphere", lamp_position=lamp, analyzer_angles_deg=angles,
                               bsdf={"model": "torrance_sparrow", "ks": [0.3, 0.3, 0.3], "sigma": sigma})
        yield ("sphere", "clean", float(np.linalg.norm(lamp)), sigma), cap


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", nargs=2, type=int, default=(320, 240), metavar=("W", "H"))
    args = ap.parse_args()
    w, h = args.resolution
    errors: dict[str, dict[tuple, float]] = {v: {} for v in VARIANTS}
    seconds = dict.fromkeys(VARIANTS, 0.0)
    for label, cap in tasks(w, h):
        lamp = np.asarray(cap.truth["lamp_position"], dtype=float)
        hp = highlight_point(np.asarray(cap.P, float), np.asarray(cap.N, float), cap.camera.position, lamp)
        for name, (method, options) in VARIANTS.items():
            clock = time.perf_counter()
            try:
                est = estimate(cap, method=method, **options)
                errors[name][label] = lamp_position_error_pct(est.lamp_position, lamp, origin=hp)
            except UserError:
                errors[name][label] = np.inf
            seconds[name] += time.perf_counter() - clock
    groups = {"board clean": lambda k: k[:2] == ("board", "clean"), "board noisy": lambda k: k[:2] == ("board", "noisy"),
              "sphere clean": lambda k: k[0] == "sphere"}
    print(f"lamp position error, % of the lamp's distance from the highlight ({w}x{h}); median / p90 (failures)")
    print(f"{'variant':40}" + "".join(f"{g:>26}" for g in groups) + f"{'seconds':>9}")
    for name in VARIANTS:
        cells = []
        for pick in groups.values():
            e = np.array([v for k, v in errors[name].items() if pick(k)])
            cells.append(f"{np.median(e):8.1f} / {np.percentile(e, 90):6.1f} ({int(np.sum(~np.isfinite(e)))}/{len(e)})")
        print(f"{name:40}" + "".join(f"{c:>26}" for c in cells) + f"{seconds[name]:9.1f}")
    print("\nper task (board: distance m from the board centre, sphere: lamp distance from the origin):")
    for label in errors["paper-init (printed)"]:
        print(f"  {label!s:42}" + " ".join(f"{errors[n][label]:7.1f}" for n in VARIANTS))


if __name__ == "__main__":
    main()
