"""Surface normals from the range image by local fits, over a window the range noise chooses.

A surface fitted to the ``w × w`` positions around a pixel gives its normal.
Two errors compete:

* **noise**: range noise of standard deviation ``σ_r`` (a range finder's
  noise, or depth quantisation in steps ``q``: ``σ_r ≈ q/√12``) tilts the
  fit by about ``σ_r / √(Σ x²)``, ``Σ x² = w h² m(m+1)(2m+1)/3`` over the
  window (``h`` the pixel footprint, ``m = (w − 1)/2``): at 640×480 on a board
  0.5 m away (``h`` ≈ 0.6 mm) a 1-mm depth step tilts a 3 × 3 plane's normal
  by about 12°, a 31 × 31 fit's by 0.1°;
* **curvature**: a plane fitted to a curved patch tilts wherever the patch
  is not symmetric about the pixel (perspective, the object's edge, a hole),
  by about ``w h / R``: measured on the 0.15-m analytic sphere at 320×240,
  the median normal error of plane fits grows from 0.011° (3 × 3) to 0.70°
  (25 × 25).

So :func:`normals_from_positions` measures ``σ_r`` from the range's fourth
differences (:func:`range_noise`, blind to curvature), then takes the
smallest odd window whose predicted noise tilt is below :data:`TILT` (at
most :data:`MAX_WINDOW`). A noise-free range image keeps the 3 × 3 plane
fits (exact on planes). A larger window fits a quadric height field instead
of a plane (:func:`_quadric_normals`: the curvature is fitted, not averaged
into the slope; the same sphere's median error at 25 × 25: 0.25°), and the
3 × 3 normal stays wherever the large window is not whole. A cubic would
cut that bias further (0.015°) but amplifies the noise about 2.5 times,
which on noisy range images cost more than it saved. What the windows
bring to ``full``'s lamp against 3 × 3 plane fits:
docs/measurements/estimator-choices.md, "Normals from range".
The sums run as box filters (:func:`scipy.ndimage.uniform_filter`), so a
window costs the same at any size.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter

#: Largest normal tilt (radians) the window choice accepts from range noise.
TILT = 1e-3
#: Largest window, pixels (odd).
MAX_WINDOW = 31
#: Degree of the polynomial height field fitted in windows larger than 3 × 3.
DEGREE = 2


def _plane_fits(P: np.ndarray, valid: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel: unit normal (smallest-eigenvalue eigenvector), that eigenvalue (m²) and the window's count."""
    ref = np.nanmean(np.where(valid[..., None], P, np.nan).reshape(-1, 3), axis=0) if valid.any() else np.zeros(3)
    Q = np.where(valid[..., None], P - ref, 0.0)
    v = valid.astype(float)

    def box(a: np.ndarray) -> np.ndarray:
        return uniform_filter(a, size=window, mode="constant") * window**2

    count = np.rint(box(v))
    n = np.maximum(count, 1.0)
    mean = np.stack([box(Q[..., i]) for i in range(3)], axis=-1) / n[..., None]
    cov = np.empty((*P.shape[:2], 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[..., i, j] = cov[..., j, i] = box(Q[..., i] * Q[..., j]) / n - mean[..., i] * mean[..., j]
    ok = valid & (count >= 3)
    cov[~ok] = np.eye(3)
    vals, vecs = np.linalg.eigh(cov)
    return vecs[..., :, 0], np.where(ok, vals[..., 0], np.nan), count


def _quadric_normals(P: np.ndarray, valid: np.ndarray, window: int, camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel: the normal of a quadric height field fitted over the window, and the window's count.

    Heights ``z`` along the mean viewing axis over the plane across it, ``z =
    c0 + c1 x + c2 y + c3 x² + c4 xy + c5 y²`` by least squares (the sums as
    box filters), and the normal of its gradient at the pixel's own ``(x, y)``:
    the curvature is fitted, not averaged into the slope, so the normal stays
    unbiased to second order in windows that perspective or the object's
    edge make lopsided.
    """
    ref = np.mean(P[valid], axis=0)
    axis = (ref - camera) / np.linalg.norm(ref - camera)
    Q = np.where(valid[..., None], P - ref, 0.0)
    # any orthonormal frame (e1, e2, axis), axis the mean viewing direction: the surface is a height field along it
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    scale = max(float(np.sqrt(np.mean(np.sum(Q[valid] ** 2, axis=-1)))), 1e-12)
    x, y, z = (Q @ e1) / scale, (Q @ e2) / scale, (Q @ axis) / scale
    v = valid.astype(float)
    powers = [(i, d - i) for d in range(DEGREE + 1) for i in range(d, -1, -1)]  # x^i y^j, i + j ≤ DEGREE
    k = len(powers)

    def box(a: np.ndarray) -> np.ndarray:
        return uniform_filter(a * v, size=window, mode="constant") * window**2

    sums: dict[tuple[int, int], np.ndarray] = {}
    A = np.empty((*P.shape[:2], k, k))
    for r, (i1, j1) in enumerate(powers):
        for c_, (i2, j2) in enumerate(powers[r:], start=r):
            key = (i1 + i2, j1 + j2)
            if key not in sums:
                sums[key] = box(x ** key[0] * y ** key[1])
            A[..., r, c_] = A[..., c_, r] = sums[key]
    b = np.stack([box(x**i * y**j * z) for i, j in powers], axis=-1)
    count = np.rint(A[..., 0, 0])
    ok = valid & (count >= 2 * k)
    A[~ok] = np.eye(k)
    b[~ok] = 0.0
    with np.errstate(all="ignore"):
        c = np.linalg.solve(A, b[..., None])[..., 0]
    gx = sum(c[..., n] * i * x ** (i - 1) * y**j for n, (i, j) in enumerate(powers) if i > 0)
    gy = sum(c[..., n] * j * x**i * y ** (j - 1) for n, (i, j) in enumerate(powers) if j > 0)
    N = -gx[..., None] * e1 - gy[..., None] * e2 + axis
    N /= np.linalg.norm(N, axis=-1, keepdims=True)
    N[~ok] = np.nan
    return N, count


def _footprint(P: np.ndarray, valid: np.ndarray) -> float:
    """Median distance between horizontally adjacent surface points, metres."""
    both = valid[:, 1:] & valid[:, :-1]
    if not both.any():
        return np.nan
    return float(np.median(np.linalg.norm(P[:, 1:] - P[:, :-1], axis=-1)[both]))


def range_noise(P: np.ndarray, camera_position: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Standard deviation of the range noise, metres, from fourth differences of the range along rows and columns.

    A smooth surface's range has fourth differences of order ``h⁴ / R³``
    (nanometres for a 15-cm sphere at millimetre pixels) where independent
    noise of standard deviation ``σ_r`` has ``√70 σ_r`` (70 = Σ of the squared
    binomial weights 1, 4, 6, 4, 1); so ``σ_r = 1.4826 · median|Δ⁴ d| / √70``
    over every run of five surface pixels along rows, and along columns, the
    larger of the two: robust to the silhouettes' and holes' few large
    values, and blind to curvature (which plane-fit residuals would take for
    noise). Depth quantised in steps ``q`` on a slanted surface reads as
    ``≈ q/√12`` along the axis the steps cross (along the other, for a camera
    without roll, the depth is constant and its differences zero).

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
    camera_position : ndarray, shape (3,)
    valid : ndarray of bool, shape (H, W), optional

    Returns
    -------
    float
        NaN when no row or column holds five surface pixels in a run.
    """
    P = np.asarray(P, dtype=float)
    valid = np.all(np.isfinite(P), axis=-1) if valid is None else valid
    d = np.linalg.norm(np.where(valid[..., None], P, 0.0) - np.asarray(camera_position, dtype=float), axis=-1)
    w = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
    sigmas = []
    for axis in (0, 1):
        dd, vv = np.moveaxis(d, axis, -1), np.moveaxis(valid, axis, -1)
        n = dd.shape[-1] - 4
        if n <= 0:
            continue
        fourth = sum(w[k] * dd[..., k:k + n] for k in range(5))
        run = np.logical_and.reduce([vv[..., k:k + n] for k in range(5)])
        if run.any():
            sigmas.append(float(1.4826 * np.median(np.abs(fourth[run])) / np.sqrt(70.0)))
    # the larger of the two axes: depth quantised along a camera without roll is constant along rows
    # (zero fourth differences there), so a median over both would read the steps as no noise
    return max(sigmas) if sigmas else np.nan


def choose_window(P: np.ndarray, camera_position: np.ndarray, valid: np.ndarray | None = None) -> tuple[int, float, float]:
    """The window :func:`normals_from_positions` uses: ``(window, σ_r, footprint)``.

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
        World positions, metres; NaN where there is no surface.
    camera_position : ndarray, shape (3,)
    valid : ndarray of bool, shape (H, W), optional
        Pixels with a position (default: finite ``P``).

    Returns
    -------
    window : int
        Odd, 3 to :data:`MAX_WINDOW`.
    sigma_r : float
        Range noise (:func:`range_noise`), metres.
    footprint : float
        Median pixel footprint, metres.
    """
    P = np.asarray(P, dtype=float)
    valid = np.all(np.isfinite(P), axis=-1) if valid is None else valid
    sigma_r, h = range_noise(P, camera_position, valid), _footprint(P, valid)
    if not (np.isfinite(sigma_r) and np.isfinite(h) and h > 0):
        return 3, sigma_r, h
    window = 3
    while window < MAX_WINDOW:
        m = (window - 1) // 2
        if sigma_r / (h * np.sqrt(window * m * (m + 1) * (2 * m + 1) / 3.0)) <= TILT:
            break
        window += 2
    return window, sigma_r, h


def normals_from_positions(P: np.ndarray, camera_position: np.ndarray, *, window: int | None = None) -> np.ndarray:
    """Unit normals from world positions by least-squares planes (see the module docstring).

    Each pixel's normal is the eigenvector of the smallest eigenvalue of the
    covariance of the finite positions in its ``window × window``
    neighbourhood, oriented towards the camera.

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
        World positions, metres; NaN where there is no surface.
    camera_position : ndarray, shape (3,)
    window : int, optional
        Odd neighbourhood size, pixels; default: chosen by the range noise
        (:func:`choose_window`), with 3 × 3 wherever that window is not whole.

    Returns
    -------
    ndarray, shape (H, W, 3)
        Unit normals; NaN where there is no surface or fewer than 3 neighbours.
    """
    P = np.asarray(P, dtype=float)
    valid = np.all(np.isfinite(P), axis=-1)
    N, lam, _ = _plane_fits(P, valid, 3)
    ok = np.isfinite(lam)
    w = choose_window(P, camera_position, valid)[0] if window is None else int(window)
    if w != 3:
        N_w, count = _quadric_normals(P, valid, w, np.asarray(camera_position, dtype=float))
        big = np.all(np.isfinite(N_w), axis=-1) & ((count == w * w) if window is None else True)
        N = np.where(big[..., None], N_w, N)
        ok = big | (ok if window is None else False)
    to_cam = np.asarray(camera_position, dtype=float) - np.where(valid[..., None], P, 0.0)
    N = np.where((np.sum(N * to_cam, axis=-1) < 0)[..., None], -N, N)
    N[~ok] = np.nan
    return N
