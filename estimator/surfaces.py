"""Surface points and normals fitted to the range data: one surface where one fits, else windows the noise chooses.

Staged for issue 34: tested (``tests/estimator/test_surfaces.py``) and
measured (``benchmarks/bench_surfaces.py``), not yet what
:class:`~nearlight.estimator.observation.Observation` uses (that change
regenerates every committed report, so it lands with the capture's
``rig.range`` and the bound's report columns).

Why inverse depth over pixels
-----------------------------
A pinhole camera's unnormalised rays are affine in the pixel coordinates,
``R(c, r) = M·[c, r, 1]`` (:func:`pinhole_matrix`; columns ``c``, rows ``r``,
pixel centres at ``k + 0.5``), and a plane ``m·X = κ`` seen through them has an
inverse depth ``f = 1/((X − o)·n)`` (``n`` the optical axis, ``o`` the camera)
that is *affine* in ``(c, r)``. So a fit of ``f`` over pixel offsets has
regressors without error (a range sensor's error moves ``P`` along the ray,
never across it), is exact on planes at any window size, and gives the
tangent plane from ``f``'s value and gradient at the pixel:
``m ∝ M⁻ᵀ [f_c, f_r, f − c f_c − r f_r]`` (:func:`_normal`).

The window
----------
Over a whole ``(2w+1)²`` square window centred on the pixel, the odd and even
monomials decouple, so the least-squares gradient of a quadratic is
``Σ Δc·f / Σ Δc²`` (the plane's), unbiased by the curvature; its standard
deviation is ``σ_f / √(Σ Δc²)`` with ``σ_f`` the inverse depth's noise
(:class:`RangeModel`); the value at the centre is the quadratic's ``c₀``.
The sums over any window cost four look-ups in summed-area tables, so every
window of the ladder :data:`HALF_WIDTHS` is computed for every pixel. Each
pixel takes the widest window by the **intersection of confidence
intervals** (ICI; Katkovnik, Egiazarian & Astola, *Local Approximation
Techniques in Signal and Image Processing*, SPIE 2006, ch. 6): widening
while every narrower window's interval ``t ± Γ·s`` (``t`` the log-gradient,
``Γ`` = :data:`GAMMA`) still meets the others, i.e. until the curvature's
bias shows against the noise. A noise-free range keeps small windows (exact
on planes, unbiased to second order on curves); a noisy one widens as far
as the surface stays a quadratic.

A whole plane, a whole quadric
------------------------------
When one plane fits every surface pixel within the noise (:func:`_one_plane`),
every normal is that plane's: a board is one plane over all its pixels,
also at its edges, where no centred window is whole. Otherwise, when one
quadric does (:func:`_one_quadric`, Taubin's fit: a sphere, a cylinder, a
cone), every point and normal is the quadric's where each pixel's ray meets
it. Only when neither fits within the noise (a bent plate, a torus, a real
object) are the normals local, per pixel, as below. This is model
selection by the data, not knowledge of the scene: a sphere's 10 quadric
coefficients fixed by 10⁴–10⁵ range pixels give its normals to hundredths
of a degree at 0.2 mm of noise, which no local window can (its bound,
:mod:`nearlight.evaluation.scoring.crlb_range`, takes the same family).

Quantisation
------------
Depth quantised in steps ``q`` (a depth map in millimetres, a light stripe's
0.2 mm) is a staircase, not noise: along the axis the steps are taken (``z``
for a depth map, the ray for a stripe scanner) the depth sits on a lattice
(:func:`measured_range` finds it). Inside a terrace the range is flat and a
small window reads a false slope of zero, with no scatter to warn the ICI;
so a quantised range takes no window narrower than one that spans
:data:`STEPS_PER_WINDOW` steps of the local slope, and its noise is the
staircase's ``q/√12`` (the grid's offset unknown, the error over a window
that spans several steps behaves as that uniform noise).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Literal

import numpy as np
from scipy.ndimage import distance_transform_cdt

#: Half-widths (pixels) of the square windows tried, ``(2w+1)²`` pixels each.
HALF_WIDTHS = (1, 2, 3, 4, 6, 8, 11, 16, 22, 32, 45, 64, 90, 128, 180, 256)
#: ICI threshold: intervals ``t ± Γ·s`` (s the standard deviation of the window's log-gradient).
GAMMA = 2.0
#: A quantised range's smallest window spans this many depth steps of the local slope.
STEPS_PER_WINDOW = 4.0
#: Relative precision of float32 ``P`` (half an ulp over √3): the noise floor of an exact range.
FLOAT32_FLOOR = 2.0**-24 / np.sqrt(3.0)
#: Below this cosine between normal and view, a normal is refitted in its own tangent frame (:func:`_tangent_fit`).
GRAZING = 0.5
#: Largest half-width of the tangent-frame refit (its cost grows with the window's area).
TANGENT_MAX = 6
#: A range is quantised when its pixels share few depth levels: on average at least this many per level.
PIXELS_PER_LEVEL = 4
#: A lattice of depths is taken for quantisation when the measured scatter is at most this × its ``q/√12``.
LATTICE_EXPLAINS = 2.0
#: Range noise measured at a stride of 2 pixels is taken over stride 1's when it is this many times larger: the
#: errors are correlated between neighbours (:func:`measured_range`).
CORRELATED = 1.15
#: Below this noise (metres) a range is exact as far as any sensor goes (a micrometre: 0.5 % of a light stripe's
#: 0.2-mm step), and stride 2 reads only the surface's curvature.
EXACT_RANGE = 1e-6
#: Largest ratio of the smallest gap between depth levels to the step :func:`_lattice` looks for.
MAX_DIVISOR = 16
#: Spatial blocks (per side) of the jackknife that gives a whole plane's covariance (:func:`_one_plane`).
JACKKNIFE_BLOCKS = 4
#: The whole-quadric jackknife evaluates its replicates on every this-many-th row and column.
JACKKNIFE_STEP = 3
#: A plane fits the whole surface when its residual RMS is within this factor of the noise.
PLANE_FIT = 1.5


@dataclasses.dataclass(frozen=True)
class RangeModel:
    """What the range sensor's error is (``rig.range``, or measured from ``P``).

    Attributes
    ----------
    sigma_m : float
        Standard deviation of Gaussian noise, metres (0: none).
    quantum_m : float
        Step of the depth's quantisation, metres (0: not quantised).
    axis : {"ray", "z"}
        Along what the noise and the steps are: the distance along each ray
        (a light-stripe or time-of-flight sensor) or the depth along the
        optical axis (what a depth map stores).
    source : str
        ``"rig"`` (stated by the capture), ``"measured"`` (from ``P``).
    """

    sigma_m: float = 0.0
    quantum_m: float = 0.0
    axis: Literal["ray", "z"] = "ray"
    source: str = "measured"

    @property
    def equivalent_sigma_m(self) -> float:
        """Standard deviation of the noise and the staircase together, ``√(σ² + q²/12)``, metres."""
        return float(np.hypot(self.sigma_m, self.quantum_m / np.sqrt(12.0)))


def pinhole_matrix(rays: np.ndarray) -> np.ndarray:
    """``M`` with ``M·[c, r, 1] ∝`` the ray through pixel ``(row r, column c)`` (centres at ``k + 0.5``).

    Fitted to the unit rays of four pixels well apart (a pinhole's rays are
    exactly of that form: :func:`nearlight.physics.camera.camera_rays`, or
    :func:`nearlight.estimator.geometry.capture_rays`'s fitted pinhole), by
    the direct linear transform over a 5 × 5 lattice of pixels.

    Parameters
    ----------
    rays : ndarray, shape (H, W, 3)

    Returns
    -------
    ndarray, shape (3, 3)
        Scaled so that ``M[:, 2]·n = 1`` with ``n`` the optical axis (:func:`optical_axis`).
    """
    H, W = rays.shape[:2]
    rows = np.linspace(0, H - 1, 5).round().astype(int)
    cols = np.linspace(0, W - 1, 5).round().astype(int)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    d = rays[rr.ravel(), cc.ravel()]
    s = float(max(H, W))
    p = np.stack([(cc.ravel() + 0.5) / s, (rr.ravel() + 0.5) / s, np.ones(rr.size)], axis=1)
    A = np.zeros((2 * len(d), 9))
    A[0::2, 3:6] = -d[:, 2:3] * p
    A[0::2, 6:9] = d[:, 1:2] * p
    A[1::2, 0:3] = d[:, 2:3] * p
    A[1::2, 6:9] = -d[:, 0:1] * p
    M = np.linalg.svd(A, full_matrices=False)[2][-1].reshape(3, 3) @ np.diag([1 / s, 1 / s, 1.0])
    if float((M @ [cols[0] + 0.5, rows[0] + 0.5, 1.0]) @ d[0]) < 0:
        M = -M
    n = np.cross(M[:, 0], M[:, 1])
    n /= np.linalg.norm(n)
    n *= np.sign(n @ M[:, 2])
    return M / float(n @ M[:, 2])


def optical_axis(M: np.ndarray) -> np.ndarray:
    """Unit optical axis of the pinhole ``M`` (normal to the image plane, pointing forward), shape (3,)."""
    n = np.cross(M[:, 0], M[:, 1])
    n /= np.linalg.norm(n)
    return n * np.sign(n @ M[:, 2])


def _lattice(depth: np.ndarray) -> float:
    """Step ``q`` when the depths (metres, 1-D) sit on a lattice ``k·q + offset``, else 0.

    A lattice has few distinct levels for its pixels (on average at least
    :data:`PIXELS_PER_LEVEL` on each) and every gap between consecutive levels
    a whole multiple of one step (the smallest gap, or that divided by up to
    :data:`MAX_DIVISOR`); a smooth range's values are all distinct. Values within float32 precision of each other count as one.
    """
    if depth.size < 50:
        return 0.0
    vals = np.sort(depth)
    tol = 1e-7 + 4e-7 * float(np.abs(vals).max())
    levels = vals[np.concatenate([[True], np.diff(vals) > tol])]
    if levels.size < 3 or levels.size * PIXELS_PER_LEVEL > vals.size:
        return 0.0
    gaps = np.diff(levels)
    # the step is the gaps' greatest common divisor: on a surface steeper than a step per pixel no two
    # neighbours share a level, and the smallest gap seen is a multiple of the step
    for m in range(1, MAX_DIVISOR + 1):
        q = float(np.min(gaps)) / m
        if q <= 8 * tol:
            break
        k = gaps / q
        if np.all(np.abs(k - np.rint(k)) * q <= 4 * tol):
            return q
    return 0.0


def measured_range(P: np.ndarray, camera_position: np.ndarray, valid: np.ndarray, axis: np.ndarray) -> RangeModel:
    """The range sensor's error read off ``P``: a lattice along ``z`` or along the ray, else Gaussian noise.

    Quantisation is found as depths on a lattice (:func:`_lattice`);
    otherwise the noise is measured from fourth differences
    of the distance along the ray
    (:func:`nearlight.estimator.normals.range_noise`).

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
    camera_position : ndarray, shape (3,)
    valid : ndarray of bool, shape (H, W)
    axis : ndarray, shape (3,)
        The optical axis.
    """
    from .normals import range_noise

    # fourth differences of neighbours miss errors correlated over a few pixels (a staircase blurred by a
    # sub-pixel misregistration's interpolation: the bench profile's torus reads 0.030 mm at stride 1, 0.038 mm at
    # stride 2), which the windows' slopes see at their full size; at stride 2 a curved surface's own fourth
    # differences grow 16-fold (the 160x120 sphere with 0.2 mm: 0.203 and 0.216 mm), so stride 2 is taken only
    # when it reads more than CORRELATED times stride 1, on a range that is not exact
    sigmas = [range_noise(P[::k, ::k], camera_position, valid[::k, ::k]) for k in (1, 2)]
    sigmas = [float(x) if np.isfinite(x) else 0.0 for x in sigmas]
    sigma = sigmas[1] if sigmas[0] > EXACT_RANGE and sigmas[1] > CORRELATED * sigmas[0] else sigmas[0]
    rel = np.where(valid[..., None], P - camera_position, 0.0)
    for name, depth in (("z", rel @ axis), ("ray", np.linalg.norm(rel, axis=-1))):
        q = _lattice(depth[valid])
        # a lattice is the error model only when it explains the scatter: a 0.2-mm staircase interpolated by a
        # (0.3, 0.2)-px shift sits exactly on a 4-µm lattice (its weights are multiples of 0.02), while its
        # scatter is that of the 0.2-mm steps
        if q > 0 and sigma <= LATTICE_EXPLAINS * q / np.sqrt(12.0):
            return RangeModel(quantum_m=q, axis=name)
    return RangeModel(sigma_m=sigma, axis="ray")


def _sat(a: np.ndarray) -> np.ndarray:
    """Summed-area table with a zero first row and column, shape ``(H + 1, W + 1)``."""
    out = np.zeros((a.shape[0] + 1, a.shape[1] + 1))
    np.cumsum(np.cumsum(a, axis=0), axis=1, out=out[1:, 1:])
    return out


def _box(S: np.ndarray, w: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Sums over the ``(2w+1)²`` windows centred on pixels ``(rows, cols)`` (windows inside the image), shape ``rows.shape``."""
    r0, r1, c0, c1 = rows - w, rows + w + 1, cols - w, cols + w + 1
    return S[r1, c1] - S[r0, c1] - S[r1, c0] + S[r0, c0]


def _normal(M: np.ndarray, f0: np.ndarray, gc: np.ndarray, gr: np.ndarray, cc: np.ndarray, rr: np.ndarray) -> np.ndarray:
    """Unit normals ``M⁻ᵀ [f_c, f_r, f − c f_c − r f_r]`` (not yet oriented), shape ``f0.shape + (3,)``."""
    v = np.stack([gc, gr, f0 - cc * gc - rr * gr], axis=-1)
    m = v @ np.linalg.inv(M)  # (M⁻ᵀ v)ᵀ = vᵀ M⁻¹
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


@dataclasses.dataclass(frozen=True)
class FittedSurface:
    """Normals fitted to a range image (:func:`fit_surface`).

    Attributes
    ----------
    P : ndarray, shape (H, W, 3)
        The fitted surface's points on each pixel's ray, metres (the range
        with its noise fitted away); NaN where no fit.
    N : ndarray, shape (H, W, 3)
        Unit normals towards the camera; NaN where no fit.
    sd_rad : ndarray, shape (H, W)
        Standard deviation of each normal's direction from the range noise,
        radians (the two tilts' in quadrature); NaN where no fit.
    half_width : ndarray of int, shape (H, W)
        Half-width of the window each normal came from (0: no window; −1:
        the whole plane; −2: the whole quadric; −3: the whole sphere).
    model : RangeModel
        The range error the fit assumed.
    kind : {"plane", "sphere", "quadric", "local"}
        One plane fitted the whole surface, one sphere, one quadric, or none
        (windows per pixel).
    """

    P: np.ndarray
    N: np.ndarray
    sd_rad: np.ndarray
    half_width: np.ndarray
    model: RangeModel
    kind: str

    @property
    def plane(self) -> bool:
        """Whether one plane fitted the whole surface."""
        return self.kind == "plane"


def _plane_in_space(P: np.ndarray, valid: np.ndarray, cam: np.ndarray, N: np.ndarray, rays: np.ndarray,
                    model: RangeModel, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """The whole plane's points and normals, fitted to the points in space (no camera model).

    :func:`_one_plane` decides that one plane fits (its inverse depth affine
    over the pixels); the plane itself is fitted to ``P``: the weighted
    principal axes of the points, each weighted by the range noise across
    the plane (:func:`_normal_noise`, with the pixel-grid fit's normals
    ``N``), and each point moved along its own direction from the camera
    onto it. A camera whose calibration is off moves its rays, not the
    points the range measured.
    """
    X = P[valid]
    u = (X - cam) / np.linalg.norm(X - cam, axis=1, keepdims=True)
    w = 1.0 / _normal_noise(N[valid], u, rays, model, floor) ** 2
    centroid = (w[:, None] * X).sum(0) / w.sum()
    Q = X - centroid
    n = np.linalg.eigh((w[:, None] * Q).T @ Q)[1][:, 0]
    along = u @ n
    Pf = np.full(P.shape, np.nan)
    Nf = np.full(P.shape, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        Pf[valid] = X - ((Q @ n) / along)[:, None] * u
    Nf[valid] = n
    return Pf, Nf


def _one_plane(f: np.ndarray, sf: np.ndarray, valid: np.ndarray, cc: np.ndarray, rr: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """``(coefficients [a, b, c] of f ≈ a + b·c + c·r, their covariance)`` when one plane fits every valid pixel
    within :data:`PLANE_FIT` × the noise, else None.

    The covariance is the larger of the independent-noise one and a
    delete-one-block jackknife over :data:`JACKKNIFE_BLOCKS`² spatial blocks:
    a staircase's errors are correlated over a terrace, which the first
    alone would take for independent noise (on a 1-mm z-quantised board,
    errors of 5 to 17 standard deviations).
    """
    if valid.sum() < 20:
        return None
    x, y, w = cc[valid], rr[valid], 1.0 / sf[valid]
    x0, y0 = x.mean(), y.mean()
    A = np.stack([np.ones_like(x), x - x0, y - y0], axis=1) * w[:, None]
    b = f[valid] * w
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    rms = float(np.sqrt(np.mean((A @ coef - b) ** 2)))
    if not rms <= PLANE_FIT:
        return None
    cov = np.linalg.inv(A.T @ A) * max(rms, 1.0) ** 2
    H, W = valid.shape
    block = (np.minimum(y * JACKKNIFE_BLOCKS // H, JACKKNIFE_BLOCKS - 1) * JACKKNIFE_BLOCKS
             + np.minimum(x * JACKKNIFE_BLOCKS // W, JACKKNIFE_BLOCKS - 1)).astype(int)
    present = np.unique(block)
    if present.size >= 4:
        # each block's normal equations by one sort and a segmented sum (not a boolean mask per block)
        order = np.argsort(block, kind="stable")
        starts = np.searchsorted(block[order], present)
        As, bs = A[order], b[order]
        AtAk = np.add.reduceat(As[:, :, None] * As[:, None, :], starts, axis=0)
        Atbk = np.add.reduceat(As * bs[:, None], starts, axis=0)
        leave = np.linalg.solve(AtAk.sum(0) - AtAk, (Atbk.sum(0) - Atbk)[..., None])[..., 0]
        g = present.size
        jack = (g - 1) / g * (leave - leave.mean(axis=0)).T @ (leave - leave.mean(axis=0))
        cov = np.where(np.diag(jack)[:, None] * np.diag(jack)[None, :] > np.diag(cov)[:, None] * np.diag(cov)[None, :],
                       jack, cov)
    shift = np.array([[1.0, -x0, -y0], [0, 1, 0], [0, 0, 1]])
    return shift @ coef, shift @ cov @ shift.T


def fit_surface(P: np.ndarray, camera_position: np.ndarray, rays: np.ndarray, *, model: RangeModel | None = None,
                valid: np.ndarray | None = None) -> FittedSurface:
    """Normals of the surface fitted to the range image ``P`` (see the module docstring).

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
        World positions, metres; NaN where no surface.
    camera_position : ndarray, shape (3,)
    rays : ndarray, shape (H, W, 3)
        Unit rays through the pixel centres (a pinhole's).
    model : RangeModel, optional
        The range's error; default: :func:`measured_range`.
    valid : ndarray of bool, shape (H, W), optional
        Pixels with a position (default: finite ``P``).

    Returns
    -------
    FittedSurface
    """
    P = np.asarray(P, dtype=float)
    cam = np.asarray(camera_position, dtype=float)
    valid = np.all(np.isfinite(P), axis=-1) if valid is None else valid
    H, W = valid.shape
    M = pinhole_matrix(rays)
    axis = optical_axis(M)
    rel = np.where(valid[..., None], P - cam, 0.0)
    z = rel @ axis
    valid = valid & (z > 0)
    if model is None:
        model = measured_range(P, cam, valid, axis)
    zs = np.where(valid, z, 1.0)
    dist = np.linalg.norm(rel, axis=-1)
    # the depth's noise along z: along the ray it is foreshortened by z/d
    to_z = 1.0 if model.axis == "z" else np.where(valid, zs / np.maximum(dist, 1e-300), 1.0)
    floor = FLOAT32_FLOOR * float(np.max(np.abs(P[valid]))) if valid.any() else 0.0
    sz = np.hypot(model.equivalent_sigma_m * to_z, floor)
    f = np.where(valid, 1.0 / zs, 0.0)
    sf = sz / zs**2  # the inverse depth's standard deviation
    rr, cc = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")

    # per pixel: f's value and gradient (per pixel) at the centre, the gradient's s.d. per component, the window
    fit = np.full((H, W, 4), np.nan)
    half = np.zeros((H, W), int)
    plane = _one_plane(f, sf, valid, cc, rr)
    if plane is None:
        # the simplest family that fits within the noise: a sphere's 4 parameters before a quadric's 9
        for kind, code, fitter in (("sphere", -3, _one_sphere), ("quadric", -2, _one_quadric)):
            whole = fitter(P, valid, rays, cam, model, floor)
            if whole is not None:
                Pq, Nq, sdq = whole
                return FittedSurface(P=Pq, N=Nq, sd_rad=sdq, half_width=np.where(valid, code, 0), model=model,
                                     kind=kind)
    if plane is not None:
        (a, b, c), cov = plane
        fit[valid] = np.stack([a + b * cc[valid] + c * rr[valid], np.full(valid.sum(), b), np.full(valid.sum(), c),
                               np.full(valid.sum(), np.sqrt(0.5 * (cov[1, 1] + cov[2, 2])))], axis=-1)
        half[valid] = -1
    else:
        Xw, Nw = _windows(f, sf, valid, model, zs, P, fit, half)
    done = np.isfinite(fit[..., 0])
    N = np.full((H, W, 3), np.nan)
    sd = np.full((H, W), np.nan)
    f0, gc, gr, sg = fit[done].T
    x, y = cc[done], rr[done]
    n0 = _normal(M, f0, gc, gr, x, y)
    N[done] = n0
    # each tilt's standard deviation: the angle a one-s.d. change of each gradient component turns the normal by;
    # for one plane on a lattice of pixels, each pixel taking its nearest's (it varies over the image, not per pixel)
    at = done.copy()
    if plane is not None:
        at[:] = False
        at[::JACKKNIFE_STEP, ::JACKKNIFE_STEP] = True
        at &= done
    pick = at[done]
    turn = [np.arccos(np.clip(np.sum(n0[pick] * _normal(M, f0[pick], gc[pick] + dc * sg[pick], gr[pick] + dr * sg[pick],
                                                        x[pick], y[pick]), axis=-1), -1.0, 1.0))
            for dc, dr in ((1.0, 0.0), (0.0, 1.0))]
    sd[at] = np.hypot(*turn)
    if plane is not None and at.any():
        near = distance_transform_cdt(~at, metric="chessboard", return_indices=True)[1]
        sd = np.where(done, sd[near[0], near[1]], np.nan)
    if plane is None:
        Pf, N = Xw, np.where(done[..., None], Nw, np.nan)
    else:
        Pf, N = _plane_in_space(P, valid, cam, N, rays, model, floor)
    flip = np.sum(np.nan_to_num(N) * -rel, axis=-1) < 0
    N[flip] = -N[flip]
    if plane is None:
        view = -rel / np.maximum(dist, 1e-300)[..., None]
        # where the inverse depth bends towards a silhouette's singularity: grazing, and near the silhouette
        # for the window the pixel took
        edge = distance_transform_cdt(valid, metric="chessboard")
        grazing = done & (np.sum(np.nan_to_num(N) * view, axis=-1) < GRAZING) & (edge <= 2 * np.abs(half) + 4)
        if grazing.any():
            N[grazing] = _tangent_fit(P, valid, N, grazing, np.clip(half[grazing], 2, TANGENT_MAX))
            Pf[grazing] = P[grazing]  # the inverse depth's value is what bends there: keep the measured point
    return FittedSurface(P=Pf, N=N, sd_rad=sd, half_width=half, model=model,
                         kind="local" if plane is None else "plane")


#: The monomials ``Δc^a Δr^b`` of each degree, split by parity in ``Δc`` and ``Δr``: over a window symmetric about
#: its centre the blocks are orthogonal, so each is fitted alone.
BLOCKS = {
    2: (((0, 0), (2, 0), (0, 2)), ((1, 0),), ((0, 1),), ((1, 1),)),
    3: (((0, 0), (2, 0), (0, 2)), ((1, 0), (3, 0), (1, 2)), ((0, 1), (0, 3), (2, 1)), ((1, 1),)),
}


def _family() -> list[tuple[int, int, list[tuple[tuple[tuple[int, int], ...], np.ndarray]], float]]:
    """The windows and degrees the ICI runs through: ``(half-width, degree, [(block, G⁻¹)], k)``, ``k`` the centre
    gradient's standard deviation per unit noise, sorted by ``k`` falling (the least biased, noisiest first).

    ``G`` is a block's Gram matrix over the whole ``(2w+1)²`` window, the same for every window of that size.
    """
    out = []
    for w in HALF_WIDTHS:
        d = np.arange(-w, w + 1, dtype=float)
        c, r = (x.ravel() for x in np.meshgrid(d, d))
        for degree, blocks in BLOCKS.items():
            if 2 * w + 1 <= degree:
                continue
            inv = []
            for block in blocks:
                basis = np.stack([c**a * r**b for a, b in block])
                inv.append((block, np.linalg.inv(basis @ basis.T)))
            out.append((w, degree, inv, float(np.sqrt(inv[1][1][0, 0]))))
    return sorted(out, key=lambda x: -x[3])


FAMILY = _family()


class _Lazy(dict):
    """A dict that computes a missing key's value once, by ``make(key)``."""

    def __init__(self, make: Callable[[tuple[int, int]], np.ndarray]) -> None:
        super().__init__()
        self.make = make

    def __missing__(self, key: tuple[int, int]) -> np.ndarray:
        self[key] = value = self.make(key)
        return value


class _Field:
    """One image ``g`` (``[H, W]``, 0 off the surface) with summed-area tables of ``g·c^p·r^q`` (``p + q ≤ 3``, made
    when first asked for), and the window polynomials fitted to it (:meth:`poly`)."""

    def __init__(self, g: np.ndarray, cc: np.ndarray, rr: np.ndarray) -> None:
        self.raw = _Lazy(lambda pq: _sat(g * cc ** pq[0] * rr ** pq[1]))
        self.cc, self.rr = cc, rr

    def poly(self, w: int, blocks: list, r0: np.ndarray, c0: np.ndarray, dc: np.ndarray, dr: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Value, gradient ``(2, n)`` (per pixel along columns, rows) and the gradient's variance per unit noise
        ``(2, n)`` of each window's polynomial (centred at ``(r0, c0)``, ``blocks`` as :data:`FAMILY`'s) at the
        offsets ``(dc, dr)``."""
        from math import comb

        j0, i0 = self.cc[r0, c0], self.rr[r0, c0]
        box = _Lazy(lambda pq: _box(self.raw[pq], w, r0, c0))

        def moment(a_: int, b_: int) -> np.ndarray:
            """Σ Δc^a Δr^b g over each window, from the raw sums about the image centre."""
            return sum(comb(a_, p) * comb(b_, q) * (-j0) ** (a_ - p) * (-i0) ** (b_ - q) * box[p, q]
                       for p in range(a_ + 1) for q in range(b_ + 1))

        value = np.zeros(r0.size)
        grad = np.zeros((2, r0.size))
        var = np.zeros((2, r0.size))
        for block, inv in blocks:
            coef = inv @ np.stack([moment(a, b) for a, b in block])  # (len(block), n)
            value += sum(coef[m] * dc**a * dr**b for m, (a, b) in enumerate(block))
            for axis in (0, 1):  # d/dΔc, d/dΔr of each monomial at δ
                u = np.stack([(a * dc ** max(a - 1, 0) * dr**b) if axis == 0 else (b * dc**a * dr ** max(b - 1, 0))
                              for a, b in block])
                grad[axis] += np.sum(coef * u, axis=0)
                var[axis] += np.einsum("mn,mk,kn->n", u, inv, u)
        return value, grad, var


def _windows(f: np.ndarray, sf: np.ndarray, valid: np.ndarray, model: RangeModel, zs: np.ndarray, P: np.ndarray,
             fit: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill ``fit`` (value, gradient per pixel along columns and rows, the gradient's s.d.) and ``half`` by the ICI
    over :data:`FAMILY`; return the fitted points and normals ``(H, W, 3)`` of the windows chosen.

    Each pixel uses the whole window of each size nearest to it that contains
    it (its own, centred, when whole; else one shifted inwards from an edge,
    a hole or a silhouette, by at most ``w``), and evaluates that window's
    polynomial at its own offset ``δ`` from the window's centre, with the
    standard deviation of the gradient there. The ICI runs on the inverse
    depth (whose noise the range model gives); the points and normals come
    from the same windows fitted to the three coordinates of ``P`` (normal =
    ``∂X/∂c × ∂X/∂r``), so that they depend on no camera model: a camera
    whose calibration is off (the bench profile's 0.2°) moves the rays, not
    the points the range measured.
    """
    H, W = valid.shape
    ref = float(np.mean(f[valid]))
    rr, cc = np.meshgrid(np.arange(H) - H / 2, np.arange(W) - W / 2, indexing="ij")  # centred, for precision
    inverse = _Field(np.where(valid, f - ref, 0.0), cc, rr)
    count = _sat(valid.astype(float))
    lo = np.full((H, W, 2), -np.inf)
    hi = np.full((H, W, 2), np.inf)
    alive = valid.copy()
    choice = np.full((H, W), -1)
    centre = np.zeros((2, H, W), int)
    nearest: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for index, (w, degree, blocks, _) in enumerate(FAMILY):
        if 2 * w + 1 > min(H, W):
            continue
        if w not in nearest:
            k_ = 2 * w + 1
            whole = np.zeros((H, W), bool)
            whole[w:H - w, w:W - w] = np.rint(count[k_:, k_:] - count[:-k_, k_:] - count[k_:, :-k_]
                                               + count[:-k_, :-k_]) == k_ * k_
            if not whole.any():
                nearest[w] = (np.zeros((H, W), int) + w + 1, np.zeros((2, H, W), int))
            else:
                nearest[w] = distance_transform_cdt(~whole, metric="chessboard", return_indices=True)
        dist, (ci, cj) = nearest[w]
        rows, cols = np.nonzero(alive & (dist <= w))
        if not rows.size:
            continue
        r0, c0_ = ci[rows, cols], cj[rows, cols]  # the window's centre
        dc, dr = (cols - c0_).astype(float), (rows - r0).astype(float)
        value, (gc, gr), var = inverse.poly(w, blocks, r0, c0_, dc, dr)
        value += ref
        sfp = sf[rows, cols]
        t = np.stack([gc, gr], axis=-1) / value[:, None]
        s = sfp[:, None] * np.sqrt(var.T) / np.abs(value)[:, None]
        if model.quantum_m > 0:
            # a window over fewer than STEPS_PER_WINDOW steps of the local slope reads the terrace, not the slope
            young = np.hypot(gc, gr) * (2 * w + 1) * zs[rows, cols] ** 2 / model.quantum_m < STEPS_PER_WINDOW
        else:
            young = np.zeros(rows.size, bool)
        lo_k, hi_k = np.maximum(lo[rows, cols], t - GAMMA * s), np.minimum(hi[rows, cols], t + GAMMA * s)
        meets = np.all(lo_k <= hi_k, axis=-1) | young
        keep = meets & ~young
        lo[rows[keep], cols[keep]], hi[rows[keep], cols[keep]] = lo_k[keep], hi_k[keep]
        fit[rows[meets], cols[meets]] = np.stack([value, gc, gr, sfp * np.sqrt(var.mean(axis=0))], axis=-1)[meets]
        half[rows[meets], cols[meets]] = w
        choice[rows[meets], cols[meets]] = index
        centre[:, rows[meets], cols[meets]] = np.stack([r0, c0_])[:, meets]
        alive[rows[~meets], cols[~meets]] = False
    # the points and normals: the chosen windows fitted to x, y and z
    X0 = P[valid].mean(axis=0)
    coords = [_Field(np.where(valid, P[..., k] - X0[k], 0.0), cc, rr) for k in range(3)]
    Xf = np.full((H, W, 3), np.nan)
    Nf = np.full((H, W, 3), np.nan)
    for index in np.unique(choice[choice >= 0]):
        w, _, blocks, _ = FAMILY[index]
        rows, cols = np.nonzero(choice == index)
        r0, c0_ = centre[0, rows, cols], centre[1, rows, cols]
        dc, dr = (cols - c0_).astype(float), (rows - r0).astype(float)
        fits = [field.poly(w, blocks, r0, c0_, dc, dr)[:2] for field in coords]
        Xf[rows, cols] = np.stack([v for v, _ in fits], axis=-1) + X0
        dXdc = np.stack([g[0] for _, g in fits], axis=-1)
        dXdr = np.stack([g[1] for _, g in fits], axis=-1)
        n = np.cross(dXdc, dXdr)
        Nf[rows, cols] = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return Xf, Nf


def _tangent_fit(P: np.ndarray, valid: np.ndarray, N: np.ndarray, where: np.ndarray, half: np.ndarray,
                 iterations: int = 2) -> np.ndarray:
    """Normals at the pixels ``where`` from a quadric height field over each one's tangent plane, shape ``(n, 3)``.

    Near a silhouette the inverse depth over the pixel grid is no polynomial
    (it has a square-root singularity at the limb), so a grazing pixel's
    window is refitted in 3-D: heights along its current normal over the
    plane across it, ``h = c₀ + c₁u + c₂v + c₃u² + c₄uv + c₅v²`` over the
    ``(2w+1)²`` pixels around it (``w`` = ``half``), and the normal of that
    quadric at the pixel; twice, the second time in the first fit's frame.
    Range noise along a grazing ray lies nearly in that plane, so it moves
    the points along the surface more than off it.
    """
    H, W = valid.shape
    rows, cols = np.nonzero(where)
    out = N[rows, cols].copy()
    for wv in np.unique(half):
        sel = np.flatnonzero(half == wv)
        d = np.arange(-wv, wv + 1)
        di, dj = (x.ravel() for x in np.meshgrid(d, d, indexing="ij"))
        ri = np.clip(rows[sel, None] + di, 0, H - 1)
        cj = np.clip(cols[sel, None] + dj, 0, W - 1)
        ok = valid[ri, cj] & (np.abs(rows[sel, None] + di - ri) + np.abs(cols[sel, None] + dj - cj) == 0)
        Q = np.where(ok[..., None], P[ri, cj] - P[rows[sel], cols[sel]][:, None, :], 0.0)
        n = out[sel]
        for _ in range(iterations):
            e1 = np.cross(n, np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
            e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
            e2 = np.cross(n, e1)
            u, v, h = (np.einsum("pkx,px->pk", Q, e) for e in (e1, e2, n))
            scale = np.sqrt(np.sum(ok * (u * u + v * v), axis=1, keepdims=True) / np.maximum(ok.sum(1, keepdims=True), 1))
            u, v = u / scale, v / scale
            A = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1) * ok[..., None]
            G = np.einsum("pki,pkj->pij", A, A)
            good = ok.sum(1) >= 8
            G[~good] = np.eye(6)
            coef = np.linalg.solve(G, np.einsum("pki,pk->pi", A, h * ok)[..., None])[..., 0]
            # the quadric's normal at the pixel itself (u = v = 0): the gradient is (c1, c2) per unit of u/scale
            m = n - (coef[:, 1:2] * e1 + coef[:, 2:3] * e2) / scale
            m /= np.linalg.norm(m, axis=-1, keepdims=True)
            n = np.where(good[:, None], m, n)
        out[sel] = n
    return out


def _quadric_design(u: np.ndarray) -> np.ndarray:
    """Rows ``[x², y², z², xy, xz, yz, x, y, z, 1]`` of the points ``u`` (n, 3), shape (n, 10)."""
    x, y, z = u.T
    return np.stack([x * x, y * y, z * z, x * y, x * z, y * z, x, y, z, np.ones_like(x)], axis=1)


def _gradient_selectors() -> np.ndarray:
    """``S`` (3, 10, 10) with each gradient row ``∂D/∂x_i = D·S[i]``: every entry of the gradient of a monomial of
    degree ≤ 2 is a monomial of degree ≤ 1, itself a column of ``D`` (so ``Σ GᵢᵀGᵢ = Sᵢᵀ (DᵀD) Sᵢ``)."""
    S = np.zeros((3, 10, 10))
    x, y, z, one = 6, 7, 8, 9  # the columns of x, y, z and 1 in D
    for i, col in enumerate((x, y, z)):
        S[i, col, i] = 2.0  # ∂(x_i²) = 2 x_i
        S[i, one, 6 + i] = 1.0  # ∂(x_i) = 1
    # the cross terms xy, xz, yz (columns 3, 4, 5)
    S[0, y, 3], S[1, x, 3] = 1.0, 1.0
    S[0, z, 4], S[2, x, 4] = 1.0, 1.0
    S[1, z, 5], S[2, y, 5] = 1.0, 1.0
    return S


GRADIENT = _gradient_selectors()


def _taubin(Mm: np.ndarray, Nm: np.ndarray) -> np.ndarray | None:
    """Taubin's quadric: the generalised eigenvector of ``(Σ DᵀD, Σ GᵀG)`` of the smallest finite eigenvalue."""
    import scipy.linalg

    with np.errstate(all="ignore"):
        vals, vecs = scipy.linalg.eig(Mm, Nm)
    vals = np.real(vals)
    ok = np.isfinite(vals) & (vals > -1e-9 * max(float(np.trace(Mm)), 1e-300))
    if not ok.any():
        return None
    a = np.real(vecs[:, np.flatnonzero(ok)[np.argmin(vals[ok])]])
    return a / np.linalg.norm(a)


def _quadric_surface(a: np.ndarray, o: np.ndarray, rays: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each ray ``o + τ r`` (scaled coordinates) meets the quadric ``a`` nearest ``τ = tau``, and the unit
    gradient there: ``(τ, normal)``, NaN where it misses."""
    A = np.array([[a[0], a[3] / 2, a[4] / 2], [a[3] / 2, a[1], a[5] / 2], [a[4] / 2, a[5] / 2, a[2]]])
    b, c = a[6:9], a[9]
    qa = np.einsum("ni,ij,nj->n", rays, A, rays)
    qb = 2 * rays @ (A @ o) + rays @ b
    qc = o @ A @ o + b @ o + c
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = np.sqrt(np.where(qb * qb - 4 * qa * qc >= 0, qb * qb - 4 * qa * qc, np.nan))
        q = -0.5 * (qb + np.copysign(disc, qb))
        roots = np.stack([q / qa, qc / q])  # both roots, stable
    pick = np.argmin(np.abs(np.nan_to_num(roots, nan=np.inf) - tau), axis=0)
    t = roots[pick, np.arange(len(tau))]
    u = o + t[:, None] * rays
    g = 2 * u @ A + b
    return t, g / np.linalg.norm(g, axis=1, keepdims=True)


def _one_quadric(P: np.ndarray, valid: np.ndarray, rays: np.ndarray, cam: np.ndarray, model: RangeModel,
                 floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Points, normals and the normals' s.d. of one quadric surface (sphere, cylinder, cone, ellipsoid) through
    every valid pixel, when it fits within :data:`PLANE_FIT` × the range noise along the normal (a robust scale of
    the residuals); else None.

    Taubin's fit (G. Taubin, TPAMI 13(11), 1991: the algebraic residual
    over its gradient, to first order the geometric distance), its
    residuals the Sampson distances ``f/|∇f|``, their noise the range
    error's component along the normal (along the ray: ``σ·|n·r|``; along
    ``z``: ``σ·|n·r| / (r·axis)``). The normals' s.d. is a delete-one-block
    jackknife over :data:`JACKKNIFE_BLOCKS`² spatial blocks (the sums of the
    eigenproblem are additive, so each replicate costs one 10 × 10 solve).
    A plane must be tested before (:func:`_one_plane`): it is a degenerate
    quadric, every plane pair through it fitting as well.
    """
    H, W = valid.shape
    if valid.sum() < 50:
        return None
    X = P[valid]
    ref = X.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((X - ref) ** 2, axis=1))))
    u = (X - ref) / scale
    D = _quadric_design(u)
    rows, cols = np.nonzero(valid)
    block = (np.minimum(rows * JACKKNIFE_BLOCKS // H, JACKKNIFE_BLOCKS - 1) * JACKKNIFE_BLOCKS
             + np.minimum(cols * JACKKNIFE_BLOCKS // W, JACKKNIFE_BLOCKS - 1))
    present = np.unique(block)
    Mb = np.stack([D[block == k].T @ D[block == k] for k in present])
    Nb = np.einsum("iab,kac,icd->kbd", GRADIENT, Mb, GRADIENT)
    a = _taubin(Mb.sum(0), Nb.sum(0))
    if a is None:
        return None
    o = (cam - ref) / scale
    r = (X - cam) / np.linalg.norm(X - cam, axis=1, keepdims=True)  # each point's own direction, not the camera's ray
    tau_meas = np.linalg.norm(X - cam, axis=1) / scale
    f = D @ a
    grad = np.stack([D @ (GRADIENT[i] @ a) for i in range(3)], axis=1)
    n = grad / np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-300)
    dist = f / np.maximum(np.linalg.norm(grad, axis=1), 1e-300) * scale  # Sampson distance, metres
    sigma_n = _normal_noise(n, r, rays, model, floor)
    # a robust scale (1.4826·median|d/σ|: 1 for Gaussian residuals) rather than the RMS: near a silhouette σ·|n·r|
    # is tiny, and there the first-order Sampson distance is least exact
    if not 1.4826 * np.median(np.abs(dist / sigma_n)) <= PLANE_FIT:
        return None
    t, N = _quadric_surface(a, o, r, tau_meas)
    # a ray that grazes the silhouette may miss the fitted quadric by a hair: its measured point, and the quadric's
    # gradient there
    miss = ~np.isfinite(t)
    t[miss], N[miss] = tau_meas[miss], n[miss]
    # the jackknife's replicates on every JACKKNIFE_STEP-th row and column; each pixel takes its nearest such
    # pixel's s.d. (the s.d. of a whole-surface fit varies over many pixels, not from one to the next)
    lattice = np.zeros(valid.shape, bool)
    lattice[::JACKKNIFE_STEP, ::JACKKNIFE_STEP] = True
    lattice &= valid
    if not lattice.any():
        lattice = valid
    on = lattice[valid]
    turns = []
    for k in range(len(present)):
        ak = _taubin(Mb.sum(0) - Mb[k], Nb.sum(0) - Nb[k])
        if ak is None:
            return None
        tk, Nk = _quadric_surface(ak, o, r[on], tau_meas[on])
        Nk[~np.isfinite(tk)] = N[on][~np.isfinite(tk)]
        turns.append(Nk * np.sign(np.sum(Nk * N[on], axis=1, keepdims=True)))
    turns = np.stack(turns)
    g = len(present)
    spread = turns - turns.mean(axis=0)
    sd_lattice = np.full(valid.shape, np.nan)
    sd_lattice[lattice] = np.sqrt((g - 1) / g * np.sum(spread**2, axis=(0, 2)))
    near = distance_transform_cdt(~lattice, metric="chessboard", return_indices=True)[1]
    sd = sd_lattice[near[0], near[1]][valid]
    N = np.where((np.sum(N * r, axis=1) > 0)[:, None], -N, N)
    Pq = np.full(P.shape, np.nan)
    Nq = np.full(P.shape, np.nan)
    sdq = np.full(valid.shape, np.nan)
    Pq[valid], Nq[valid], sdq[valid] = cam + (t * scale)[:, None] * r, N, sd
    return Pq, Nq, sdq


def _normal_noise(n: np.ndarray, r: np.ndarray, rays: np.ndarray, model: RangeModel, floor: float) -> np.ndarray:
    """Standard deviation of the range error along each normal ``n`` (m, 3), metres, for points on rays ``r``.

    The error moves a point along its ray: by ``σ`` (along the ray) or by
    ``σ / (r·axis)`` (along ``z``), of which ``|n·r|`` is across the surface;
    with the float32 floor in quadrature.
    """
    along = np.abs(np.sum(n * r, axis=1))
    if model.axis == "z":
        along = along / np.maximum(r @ optical_axis(pinhole_matrix(rays)), 1e-12)
    return np.hypot(model.equivalent_sigma_m * along, floor)


#: Gauss–Newton iterations of the sphere's geometric fit (from the algebraic one: converged in 2-3).
SPHERE_ITERATIONS = 5


def _sphere_on_rays(c: np.ndarray, R: float, cam: np.ndarray, r: np.ndarray, near: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Distance along each unit ray ``r`` from ``cam`` to the sphere (the root nearest ``near``) and the unit
    normal there (outward); NaN where a ray misses."""
    b = r @ (cam - c)
    disc = b * b - (np.sum((cam - c) ** 2) - R * R)
    root = np.sqrt(np.where(disc >= 0, disc, np.nan))
    t = np.where(np.abs(-b - root - near) <= np.abs(-b + root - near), -b - root, -b + root)
    return t, (cam + t[:, None] * r - c) / R


def _one_sphere(P: np.ndarray, valid: np.ndarray, rays: np.ndarray, cam: np.ndarray, model: RangeModel,
                floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Points, normals and the normals' s.d. of one sphere through every valid pixel, when it fits within
    :data:`PLANE_FIT` × the range noise along the normal (a robust scale of the residuals); else None.

    The algebraic fit ``|X|² = 2c·X + k`` (linear), then Gauss–Newton on
    the geometric residuals ``|X − c| − R`` weighted by the range noise
    along the normal (:func:`_normal_noise`). The normals' s.d.: the fit's
    covariance ``(JᵀWJ)⁻¹`` (scaled by the residuals' variance when above 1),
    each of its four principal axes turning every normal by an angle, summed
    in quadrature.
    """
    if valid.sum() < 50:
        return None
    X = P[valid]
    r = (X - cam) / np.linalg.norm(X - cam, axis=1, keepdims=True)  # each point's own direction, not the camera's ray
    ref = X.mean(axis=0)
    Q = X - ref
    sol = np.linalg.lstsq(np.column_stack([2 * Q, np.ones(len(Q))]), np.sum(Q * Q, axis=1), rcond=None)[0]
    c = sol[:3]
    R = float(np.sqrt(max(sol[3] + c @ c, 0.0)))
    if not R > 0:
        return None
    for _ in range(SPHERE_ITERATIONS):
        d = Q - c
        dist = np.linalg.norm(d, axis=1)
        n = d / dist[:, None]
        w = 1.0 / _normal_noise(n, r, rays, model, floor)
        J = np.column_stack([-n, -np.ones(len(n))]) * w[:, None]
        res = (dist - R) * w
        step = np.linalg.lstsq(J, -res, rcond=None)[0]
        c, R = c + step[:3], R + float(step[3])
    d = Q - c
    dist = np.linalg.norm(d, axis=1)
    n = d / dist[:, None]
    w = 1.0 / _normal_noise(n, r, rays, model, floor)
    res = (dist - R) * w
    scale = 1.4826 * float(np.median(np.abs(res)))
    if not scale <= PLANE_FIT:
        return None
    J = np.column_stack([-n, -np.ones(len(n))]) * w[:, None]
    cov = np.linalg.inv(J.T @ J) * max(scale, 1.0) ** 2
    centre = c + ref
    near = np.linalg.norm(X - cam, axis=1)
    t, N = _sphere_on_rays(centre, R, cam, r, near)
    miss = ~np.isfinite(t)  # a ray grazing the silhouette: its measured point
    t[miss], N[miss] = near[miss], n[miss]
    vals, vecs = np.linalg.eigh(cov)
    turn2 = np.zeros(len(t))
    for k in range(4):
        dv = vecs[:, k] * np.sqrt(max(vals[k], 0.0))
        tk, Nk = _sphere_on_rays(centre + dv[:3], R + dv[3], cam, r, near)
        Nk[~np.isfinite(tk)] = N[~np.isfinite(tk)]
        turn2 += np.arctan2(np.linalg.norm(np.cross(Nk, N), axis=1), np.sum(Nk * N, axis=1)) ** 2
    N = np.where((np.sum(N * r, axis=1) > 0)[:, None], -N, N)
    Ps = np.full(P.shape, np.nan)
    Ns = np.full(P.shape, np.nan)
    sds = np.full(valid.shape, np.nan)
    Ps[valid], Ns[valid], sds[valid] = cam + t[:, None] * r, N, np.sqrt(turn2)
    return Ps, Ns, sds
