"""What the geometry stage makes of a range sensor's error: ``full``'s lamp error and seconds.

For the analytic board and sphere (``nearlight.generator.analytic``, no
Mitsuba) at ``--resolution`` (default 320×240), ``N`` dropped and the range
given a sensor's error (``nearlight.generator.range_sensor.perturb_range``:
Gaussian noise along the ray; quantisation along ``z``, a depth map's, or
along the ray, a stripe scanner's; the grid's offset drawn per seed), it
runs ``full`` on each of ``--seeds`` seeds (its geometry the surface that
``estimator.geometry.surface_geometry`` fits, ``rig.range`` as
``perturb_range`` states it) and prints the lamp error's median and range
over the seeds (% of the highlight–lamp distance) beside ``full`` on the
capture with its exact ``P`` and ``N``, the range model and surface the
stage took, and the normals' median error. Then the seconds of ``full``
(Torrance–Sparrow lobe named) on one 640×480 capture per row, with the
capture's normals and with the fitted surface (best of 2, the same
process), as a ratio, and the fit's own seconds.

Printed, not asserted (the machine is shared); what it printed:
``docs/physics.md``, "Range sensor error and the fitted surface".

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_surfaces.py --seeds 6
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nearlight.estimator.full import full_estimate
from nearlight.estimator.geometry import surface_geometry
from nearlight.evaluation.scoring.metrics import highlight_point, lamp_position_error_pct
from nearlight.generator.analytic import DEFAULT_LAMP_POSITION, analytic_capture
from nearlight.generator.range_sensor import perturb_range

ROWS = [
    ("exact", {}),
    ("gauss 0.05 mm", {"sigma_m": 5e-5}),
    ("gauss 0.2 mm", {"sigma_m": 2e-4}),
    ("gauss 1 mm", {"sigma_m": 1e-3}),
    ("z-quantum 0.2 mm", {"quantum_m": 2e-4, "axis": "z"}),
    ("z-quantum 1 mm", {"quantum_m": 1e-3, "axis": "z"}),
    ("ray-quantum 1 mm", {"quantum_m": 1e-3, "axis": "ray"}),
]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--resolution", type=int, nargs=2, default=(320, 240), metavar=("W", "H"))
    ap.add_argument("--no-timing", action="store_true", help="skip the 640x480 timing")
    args = ap.parse_args()
    W, H = args.resolution
    print(f"full's lamp error (% of the highlight-lamp distance) over {args.seeds} seeds at {W}x{H}: "
          "median [min-max]\n")
    print("| shape | range error | full, the capture's normals | full, the fitted surface | model read off P "
          "| normal error (deg) |")
    print("|---|---|---|---|---|---|")
    for shape in ("board", "sphere"):
        clean = analytic_capture(shape=shape, width=W, height=H)
        origin = highlight_point(clean.P, clean.N, clean.camera.position, DEFAULT_LAMP_POSITION)
        given = lamp_position_error_pct(full_estimate(clean).lamp_position, DEFAULT_LAMP_POSITION, origin=origin)
        for label, error in ROWS:
            errs, nerr = [], []
            for seed in range(args.seeds if error else 1):
                cap = perturb_range(clean, seed=seed, **error) if error else clean.replace(N=None)
                geo = surface_geometry(cap)
                ok = np.isfinite(geo.N[..., 0]) & clean.surface_mask
                nerr.append(np.median(_angle_deg(geo.N[ok], clean.N[ok])))
                errs.append(lamp_position_error_pct(full_estimate(cap).lamp_position, DEFAULT_LAMP_POSITION,
                                                    origin=origin))
            m = geo.summary["range"]
            model = (f"q {m['quantum_m'] * 1e3:.3g} mm along {m['axis']}" if m["quantum_m"]
                     else f"σ {m['sigma_m'] * 1e3:.3g} mm along {m['axis']}")
            print(f"| {shape} | {label} | {given:.3g} | {np.median(errs):.3g} [{min(errs):.3g}-{max(errs):.3g}] "
                  f"| {model} ({geo.summary['surface']}) | {np.median(nerr):.3g} |", flush=True)
    if args.no_timing:
        return
    print("\nseconds per 640x480 capture (best of 2, one process): full with the capture's normals, full with the "
          "fitted surface, ratio; the fit alone\n")
    for shape in ("board", "sphere"):
        clean = analytic_capture(shape=shape, width=640, height=480)
        for label, error in (ROWS[0], ROWS[2], ROWS[5]):
            cap = perturb_range(clean, seed=0, **error) if error else clean.replace(N=None)
            t = []
            for fn in (lambda: full_estimate(clean, lobe="torrance_sparrow"),
                       lambda: full_estimate(cap, lobe="torrance_sparrow"), lambda: surface_geometry(cap)):
                best = np.inf
                for _ in range(2):
                    t0 = time.perf_counter()
                    fn()
                    best = min(best, time.perf_counter() - t0)
                t.append(best)
            print(f"  {shape:6s} {label:18s} {t[0]:6.3f} s  {t[1]:6.3f} s  x{t[1] / t[0]:.2f}  (fit {t[2]:.3f} s)",
                  flush=True)


if __name__ == "__main__":
    main()
