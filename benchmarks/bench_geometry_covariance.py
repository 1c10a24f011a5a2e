"""A prototype of issue 35's covariance term: ``full``'s 95 % ellipsoid with the fitted surface's uncertainty added.

``full``'s covariance is the image's alone; under range noise the geometry's
error moves the lamp along the ellipsoid's thinnest axis and the coverage
collapses (``bench_range_bound.py``'s coverage column). Here the surface's
uncertainty is propagated by the estimator itself, as a black box: the
surface's parameters ``g`` (a plane ``m·(X − o) = 1``, three; a sphere's
centre and radius, four) are fitted to the noisy range by least squares (the
sphere's geometric distance), their
covariance ``C_g`` is the range's Fisher information inverted (every range
pixel, its noise along the ray or along ``z``, a quantum as ``q/√12``), the
lamp's sensitivity ``G = ∂θ̂/∂g`` is taken by refitting ``full`` on the
surface moved by one standard deviation along each of ``C_g``'s principal
axes (central differences), and the ellipsoid is that of
``C_θ + G C_g Gᵀ``, with ``C_g`` from the Fisher information or from a block
jackknife of the surface fit (:func:`_jackknife`). Printed per row: the lamp RMSE, the coverage of the
image-only and of the combined ellipsoid with exact binomial 95 % intervals.

Analytic board and sphere at 160×120, the sensitivity study's low camera
noise, Torrance–Sparrow named; ``full`` runs on captures whose ``P`` and ``N``
are the least-squares surface's (so every fit sees the same kind of
geometry). Not the design of issue 35 (which puts the surface into the fit),
the measurement that shows which term is missing. Printed, not asserted.

What it printed at 6f27a8d+ (100 seeds; coverage, image only → + geometry with ``C_g`` from the
Fisher information → with ``C_g`` from a block jackknife over 8 × 8 image tiles): board 0.2 mm
0.86 → 0.95 → 0.93, board 1 mm 0.13 [0.07, 0.21] → 0.96 [0.90, 0.99] → 0.94 [0.87, 0.98], sphere
0.2 mm 0.84 → 0.87 → 0.96, sphere 1 mm 0.12 → 0.30 → 0.88 [0.80, 0.94], sphere 1-mm steps along
``z`` 0.55 → 0.62 → 0.87, board 1-mm steps along ``z`` 0.06 → 0.11 → 0.33 [0.24, 0.43]. So the
missing term is the geometry's, with the covariance of the fit that was made (the jackknife: the
Fisher information is that of an efficient fit of the ray noise, which the geometric sphere fit
is not); what neither sees is the quantised plane's bias (the staircase's sawtooth aliasing
with the pixel grid moves the fit the same way in every tile): that one needs the image in the
fit (issue 35).

``full`` now does put the surface into its fit (``surface="auto"``,
``nearlight.estimator.joint_surface``); this black-box propagation stays as an
independent check of that fit's covariance (``tests/estimator/test_joint_surface.py``
compares the two on one capture; here they can be compared over seeds).

Usage::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_geometry_covariance.py --seeds 100 --workers 2
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.stats import binomtest, chi2
from tqdm import tqdm

NOISE = {"full_well": 50000, "read_noise": 3.0, "bits": 14}  # sweeps/sensitivity.yaml's "low"
ROWS = [
    ("board", {"sigma_m": 2e-4}), ("board", {"sigma_m": 1e-3}), ("board", {"quantum_m": 1e-3, "axis": "z"}),
    ("sphere", {"sigma_m": 2e-4}), ("sphere", {"sigma_m": 1e-3}), ("sphere", {"quantum_m": 1e-3, "axis": "z"}),
]
SIZE = (160, 120)


def _surface(shape: str, P: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """Least-squares parameters: a plane's ``m`` (``m·(X − cam) = 1``) or a sphere's ``[cx, cy, cz, R]``."""
    if shape == "board":
        return np.linalg.lstsq(P - cam, np.ones(len(P)), rcond=None)[0]
    from scipy.optimize import least_squares

    A = np.column_stack([2 * P, np.ones(len(P))])
    sol = np.linalg.lstsq(A, np.sum(P * P, axis=1), rcond=None)[0]
    start = np.concatenate([sol[:3], [np.sqrt(sol[3] + sol[:3] @ sol[:3])]])
    # the algebraic fit is biased under noise: refined by the geometric distance (Gauss-Newton)
    return least_squares(lambda s: np.linalg.norm(P - s[:3], axis=1) - s[3], start, method="lm").x


def _on_rays(shape: str, g: np.ndarray, cam: np.ndarray, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance along each unit ray to the surface ``g`` and its normal there (towards the camera)."""
    from nearlight.estimator.whole_surface import on_rays

    return on_rays("plane" if shape == "board" else "sphere", g, cam, rays)


def _one(job):
    from nearlight.estimator.full import full_estimate
    from nearlight.estimator.geometry import capture_rays
    from nearlight.estimator.range_error import RangeModel
    from nearlight.generator.analytic import DEFAULT_LAMP_POSITION, analytic_capture
    from nearlight.generator.noise import add_camera_noise
    from nearlight.generator.range_sensor import perturb_range

    shape, error, seed = job
    clean = analytic_capture(shape=shape, width=SIZE[0], height=SIZE[1])
    cam = np.asarray(clean.camera.position, float)
    cap = perturb_range(add_camera_noise(clean, noise=NOISE, seed=seed), seed=seed, **error)
    mask = clean.surface_mask & np.all(np.isfinite(cap.P), axis=-1)
    rays = capture_rays(clean)[mask]
    g = _surface(shape, np.asarray(cap.P, float)[mask], cam)
    # C_g: the range's Fisher information about g, every pixel's depth along the ray (or z), noise σ_eq
    sigma = RangeModel(sigma_m=error.get("sigma_m", 0.0), quantum_m=error.get("quantum_m", 0.0)).equivalent_sigma_m
    to_depth = rays @ np.asarray(clean.camera.to_world, float)[:3, 2] if error.get("axis") == "z" else 1.0
    steps = 1e-7 * np.maximum(np.abs(g), 1e-3)
    J = np.stack([(_on_rays(shape, g + s * e, cam, rays)[0] - _on_rays(shape, g - s * e, cam, rays)[0]) / (2 * s)
                  for s, e in zip(steps, np.eye(len(g)))], axis=1) * np.reshape(to_depth, (-1, 1))
    J = J[np.all(np.isfinite(J), axis=1)]  # rays that graze the silhouette miss a moved sphere
    C_g = np.linalg.inv(J.T @ J) * sigma**2

    def fit(gk: np.ndarray):
        t, n = _on_rays(shape, gk, cam, rays)
        P = np.full(clean.P.shape, np.nan, np.float32)
        N = np.full(clean.P.shape, np.nan, np.float32)
        P[mask], N[mask] = cam + t[:, None] * rays, n
        return full_estimate(cap.replace(P=P, N=N), lobe="torrance_sparrow")

    est = fit(g)
    d = np.asarray(est.lamp_position, float) - DEFAULT_LAMP_POSITION
    C_img = np.asarray(est.covariance, float)[:3, :3]
    vals, vecs = np.linalg.eigh(C_g)
    sd = np.sqrt(vals)
    # ∂θ̂/∂g from central differences along C_g's principal axes, one s.d. each
    dtheta = np.stack([(fit(g + s_ * u).lamp_position - fit(g - s_ * u).lamp_position) / (2.0 * s_)
                       for s_, u in zip(sd, vecs.T)], axis=1)
    G = dtheta @ vecs.T  # (3, len(g))
    C_jack = _jackknife(shape, np.asarray(cap.P, float)[mask], cam, mask)
    return [*d, *(float(d @ np.linalg.solve(C, d)) for C in (C_img, C_img + G @ C_g @ G.T,
                                                               C_img + G @ C_jack @ G.T))]


#: Blocks of the block jackknife: the image cut into this many × this many tiles.
TILES = 8


def _jackknife(shape: str, P: np.ndarray, cam: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Covariance of the surface's parameters by a block jackknife over image tiles (leave one tile out)."""
    rows, cols = np.nonzero(mask)
    H, W = mask.shape
    tile = (rows * TILES // H) * TILES + cols * TILES // W
    fits = np.array([_surface(shape, P[tile != k], cam) for k in np.unique(tile)])
    k = len(fits)
    dev = fits - fits.mean(axis=0)
    return (k - 1) / k * dev.T @ dev


def _coverage(m2: np.ndarray) -> str:
    inside = int(np.sum(m2 <= chi2.ppf(0.95, 3)))
    lo, hi = binomtest(inside, len(m2)).proportion_ci(0.95)
    return f"{inside / len(m2):.2f} [{lo:.2f}, {hi:.2f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    jobs = [(shape, error, seed) for shape, error in ROWS for seed in range(args.seeds)]
    with ProcessPoolExecutor(args.workers) as pool:
        out = np.array(list(tqdm(pool.map(_one, jobs, chunksize=4), total=len(jobs), desc="captures")))
    print(f"\n{args.seeds} seeds per row, {SIZE[0]}x{SIZE[1]}, low camera noise; coverage of the 95 % ellipsoid "
          "[exact binomial 95 % interval]\n")
    print("| object | range error | RMSE (mm) | image only | + geometry (Fisher) | + geometry (block jackknife) |")
    print("|---|---|---|---|---|---|")
    for k, (shape, error) in enumerate(ROWS):
        part = out[k * args.seeds:(k + 1) * args.seeds]
        rmse = np.sqrt(np.mean(np.sum(part[:, :3] ** 2, axis=1)))
        label = ", ".join(f"{key} {value}" for key, value in error.items())
        print(f"| {shape} | {label} | {rmse * 1e3:.3g} | {_coverage(part[:, 3])} | {_coverage(part[:, 4])} | "
              f"{_coverage(part[:, 5])} |", flush=True)


if __name__ == "__main__":
    main()
