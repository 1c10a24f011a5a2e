"""What every method starts from: the specular image, geometry and highlight.

:func:`observation_of` validates an in-memory :class:`~nearlight.capture.Capture`
(files are validated by :func:`nearlight.capture.read_capture`), takes its
surface geometry (:func:`~nearlight.estimator.geometry.surface_geometry`:
normals from ``P`` when ``N`` is absent, range holes filled, the range
checked against the camera), separates the analyzer stack when there is no
``specular`` image (:func:`specular_image`), and finds the specular mask and
the peak pixel. It never reads ``capture.truth``.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
from collections.abc import Callable, Iterator
from typing import TypeVar

import numpy as np

from ..capture import Capture
from ..capture.silhouette import check_silhouette
from ..errors import UserError
from ..physics.reflectance import channel_sum, every_channel, normalize
from .geometry import SurfaceGeometry, check_shapes, surface_geometry
from .separation import separate_capture

T = TypeVar("T")

#: Default specular mask threshold, fraction of the peak pixel's mean specular (:func:`observation_of`).
THRESHOLD = 0.05
#: Fewest specular pixels the regressions and fits accept.
MIN_SPECULAR_PIXELS = 10


@dataclasses.dataclass(frozen=True)
class Observation:
    """A capture reduced to what the estimators use (float64, world frame, metres).

    Attributes
    ----------
    specular : ndarray, shape (H, W, 3)
        Specular radiance (separated or given); 0 off the surface.
    geometry : SurfaceGeometry
        The capture's surface (:func:`~nearlight.estimator.geometry.surface_geometry`):
        ``P``, ``N``, ``V``, ``cos_r`` and ``surface`` are its (properties here), and its
        ``summary`` says what they came from (the capture's normals, or the surface
        fitted to the range and the range error it assumed).
    filled : ndarray, shape (H, W), bool
        Pixels inside range holes (:func:`~nearlight.estimator.geometry.enclosed_holes`) whose point and
        normal come from :func:`~nearlight.estimator.geometry.fill_range_holes`, facing the camera, with a
        finite specular: candidates for the peak and the ray's origin only.
    mask : ndarray, shape (H, W), bool
        Specular pixels: surface, every channel > 0, mean ≥ ``threshold`` ×
        peak, and not an isolated hot pixel (see :func:`_spikes`).
    peak : tuple of int
        (row, column) of the brightest mean specular over ``located`` pixels
        (a range hole on the highlight does not move it), isolated hot pixels
        excluded (see :func:`_spikes`, :func:`_peak_pixel`). A discrete
        choice: it stays put under float rounding (pixels within
        :data:`PEAK_TIE` of the maximum are tied and resolved by position),
        but jumps where a pixel's brightness crosses that band.
    camera_position : ndarray, shape (3,)
    scale : float
        Distance from the camera to the peak's surface point, metres: the
        capture's length scale, from which method defaults are derived.
    """

    specular: np.ndarray
    geometry: SurfaceGeometry
    filled: np.ndarray
    mask: np.ndarray
    peak: tuple[int, int]
    camera_position: np.ndarray
    scale: float

    @property
    def P(self) -> np.ndarray:
        """``[H, W, 3]`` surface points, metres; at ``filled`` pixels the fit's around the range hole; NaN elsewhere
        off the surface."""
        return self.geometry.P

    @property
    def N(self) -> np.ndarray:
        """``[H, W, 3]`` unit normals (towards the camera), as ``P``."""
        return self.geometry.N

    @property
    def V(self) -> np.ndarray:
        """``[H, W, 3]`` unit vectors from the surface to the camera."""
        return self.geometry.V

    @property
    def cos_r(self) -> np.ndarray:
        """``[H, W]`` cos θr = N·V."""
        return self.geometry.cos_r

    @property
    def surface(self) -> np.ndarray:
        """``[H, W]`` bool: pixels with a finite measured position and a normal facing the camera, the only pixels
        any fit uses."""
        return self.geometry.surface

    @property
    def located(self) -> np.ndarray:
        """``[H, W]`` bool: ``surface | filled``, pixels with a surface point and normal (measured or filled)."""
        return self.surface | self.filled

    @property
    def peak_point(self) -> np.ndarray:
        """Surface point of the peak pixel, shape (3,)."""
        return self.P[self.peak]



def _check_signal(name: str, channel: str, img: np.ndarray, surface: np.ndarray) -> None:
    """Refuse radiance with no signal at the surface: all <= 0, mostly negative, or constant."""
    if surface.any():
        _check_extremes(name, channel, *_extremes(img, img, surface))


def _check_extremes(name: str, channel: str, hi: float, lo: float) -> None:
    """:func:`_check_signal` from the largest and smallest radiance at the surface."""
    if hi <= 0:
        raise UserError(f"{name}: channel {channel}: no signal: no surface pixel above 0 (all-zero or negative radiance)")
    if -lo > hi:
        raise UserError(
            f"{name}: channel {channel}: mostly negative radiance (min {lo:.4g}, max {hi:.4g}); "
            "radiance cannot be negative beyond noise"
        )



def specular_image(capture: Capture, *, separation: str = "fit") -> np.ndarray:
    """The capture's specular image ``[H, W, 3]``: given, or separated from the stack.

    A stack is separated with the rig's extinction ratios (``capture.rig``,
    :func:`~nearlight.estimator.separation.rig_correction`), so a calibrated
    real analyzer or lamp polarizer gives the ideal rig's specular. A given
    ``specular`` image is used as it is (whoever separated it owned that step).
    """
    check_shapes(capture)
    surface = capture.surface_mask
    if capture.specular is not None:
        spec = np.asarray(capture.specular, dtype=float)
        _check_finite(capture.name, "specular", spec, surface)
        _check_signal(capture.name, "specular", spec, surface)
        return spec
    if capture.stack is None:
        raise UserError(f"{capture.name}: no image: expected pol<k>.R/G/B channels or specular.R/G/B")
    stack = np.asarray(capture.stack)
    # one pass over the stack for every check: its extremes over the angles, per pixel and channel
    high, low = (stack.max(axis=0), stack.min(axis=0)) if stack.size else (None, None)
    if high is not None:
        _check_finite(capture.name, "pol<k>", high + low, surface)
    hi, lo = _extremes(high, low, surface) if high is not None and surface.any() else (None, None)
    if hi is not None and (hi <= 0 or -lo > hi):
        k = int(np.argmin(stack[:, surface].min(axis=(1, 2))))  # the image to name (only when refusing)
        _check_extremes(capture.name, f"pol{k}", hi, lo)
    spec = separate_capture(capture, method=separation)[0]
    _check_finite(capture.name, "pol<k>", spec, surface)
    if hi is not None:
        top = max(hi, -lo)  # the largest |stack| at the surface
        if float(np.max(np.abs(spec), where=surface[..., None], initial=0.0)) <= 1e-6 * top:
            raise UserError(
                f"{capture.name}: channels pol<k>: no polarization signal: the analyzer images do not change "
                "with the angle (specular = Imax - Imin = 0 everywhere)"
            )
    return spec


def _extremes(high: np.ndarray, low: np.ndarray, surface: np.ndarray) -> tuple[float, float]:
    """Largest of ``high`` and smallest of ``low`` (``[H, W, 3]``) over the ``surface`` pixels (at least one).

    A reduction with ``where=`` rather than of ``high[surface]``: the same
    numbers without gathering a copy (640×480: about half the time).
    """
    where = surface[..., None]
    return float(np.max(high, where=where, initial=-np.inf)), float(np.min(low, where=where, initial=np.inf))


def _check_finite(name: str, channel: str, img: np.ndarray, surface: np.ndarray) -> None:
    bad = surface & ~every_channel(np.isfinite(img))
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise UserError(f"{name}: channel {channel}: NaN or Inf at surface pixel (row {i}, column {j})")


def _spikes(lum: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """Isolated hot pixels: more than twice the 3×3 median, with no neighbour that rises with them.

    A pixel is a spike when it exceeds twice the median of its 3×3
    neighbourhood (the local background) and its brightest neighbour rises
    above that background by less than a quarter of the pixel's own rise.
    A hot pixel stands alone; a highlight's peak, however sharp, lifts a
    neighbour on its lobe: a Gaussian lobe centred on a pixel lifts its
    neighbours by exp(−1/2w²) of the peak, w its width in pixels, over a
    quarter for any w > 0.6 px (narrower, a lobe is one pixel and cannot be
    told from a hot pixel). The median rule alone caught the true peak of a
    lobe 1–2 px wide (σ = 0.005 on a 160-px board: neighbours 0.48, 0.44,
    0.31 of the peak, median 0.20). Off-surface pixels count as 0; the
    image's edge is extended by its nearest pixels.

    Only strict local maxima (above all 8 neighbours) can pass both tests
    (were a neighbour as bright, the median would not exceed it and the
    second test would fail), so the median is taken at those alone: the
    same pixels as a median filter over the image (640×480 board: ~3 ms
    against 15–30 ms).
    """
    img = np.where(surface, lum, 0.0)
    H, W = img.shape
    pad = np.pad(img, 1, mode="edge")
    windows = [pad[di : di + H, dj : dj + W] for di in range(3) for dj in range(3)]
    top = np.maximum(windows[0], windows[1])
    for w in windows[2:4] + windows[5:]:  # the 8 neighbours, not the centre
        np.maximum(top, w, out=top)
    rows, cols = np.nonzero(surface & (lum > top))
    around = np.stack([w[rows, cols] for w in windows], axis=-1)
    med = np.maximum(np.partition(around, 4, axis=-1)[:, 4], 0.0)
    peak, rise = lum[rows, cols], top[rows, cols] - med
    spike = (peak > 2.0 * med) & (rise < 0.25 * (peak - med))
    out = np.zeros(lum.shape, bool)
    out[rows[spike], cols[spike]] = True
    return out


#: Pixels within this fraction of the brightest count as sharing the maximum
#: (:func:`_peak_pixel`): 2⁻¹⁹ ≈ 1.9e-6, i.e. 16 float32 ulps, so that two
#: pixels equal but for float rounding (a symmetric scene's mirror-image
#: peaks, rendered on two machines) do not flip the peak with the last bits.
PEAK_TIE = 2.0**-19


def _peak_pixel(lum: np.ndarray, usable: np.ndarray) -> tuple[int, int]:
    """Brightest usable pixel; when several share the maximum to within
    :data:`PEAK_TIE` (a clipped highlight, mirror-image peaks), the one
    nearest their centroid, then the first in row-major order."""
    value = np.where(usable, lum, -np.inf)
    top = value >= value.max() - PEAK_TIE * abs(value.max())
    rows, cols = np.nonzero(top)
    if len(rows) == 1:
        return int(rows[0]), int(cols[0])
    k = int(np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2))
    return int(rows[k]), int(cols[k])


#: What was computed inside :func:`shared_observations`, by (function, the ids of its arguments, its options): the
#: arguments themselves are kept beside the value, so their ids cannot be reused while the entry lives.
_SHARED: contextvars.ContextVar[dict | None] = contextvars.ContextVar("nearlight_observations", default=None)


@contextlib.contextmanager
def shared_observations() -> Iterator[None]:
    """Within the block, :func:`observation_of` of one capture object with the same options is made once, and so is
    each computation made through :func:`shared`.

    :func:`nearlight.estimator.estimate` runs a method and then the sanity
    rules (:mod:`nearlight.estimator.sanity`) inside one block, so the rules
    read the observation, the camera noise and the highlight count the method
    made (at 640×480, ~70 ms not spent twice). Only for the length of one
    call: a capture whose arrays are changed in place between calls is
    observed afresh.
    """
    token = _SHARED.set({})
    try:
        yield
    finally:
        _SHARED.reset(token)


def already_shared(compute: Callable[..., T], *of: object, **options: object) -> T | None:
    """What :func:`shared` computed for these arguments inside the current block; None when it has not (or outside
    one): for reports on what a method used without computing it for a method that did not."""
    store = _SHARED.get()
    entry = None if store is None else store.get((compute, *map(id, of), *sorted(options.items())))
    return None if entry is None else entry[1]


def shared(compute: Callable[..., T], *of: object, **options: object) -> T:
    """``compute(*of, **options)``, once per function, argument objects and options inside
    :func:`shared_observations` (every time outside it). The arguments are keyed by identity: only for
    objects not changed in place within the block (a capture, its observation, its arrays)."""
    store = _SHARED.get()
    if store is None:
        return compute(*of, **options)
    key = (compute, *map(id, of), *sorted(options.items()))
    if key not in store:
        store[key] = (of, compute(*of, **options))
    return store[key][1]


def observation_of(capture: Capture, *, separation: str = "fit", threshold: float = THRESHOLD) -> Observation:
    """Reduce a capture to an :class:`Observation` (once per capture and options inside
    :func:`shared_observations`).

    Parameters
    ----------
    capture : Capture
    separation : {"fit", "projected", "maxmin"}, optional
        How to separate an analyzer stack (ignored when the capture has a
        ``specular`` image).
    threshold : float, optional
        Specular mask threshold, as a fraction of the peak pixel's mean
        specular radiance.

    Raises
    ------
    UserError
        Shapes that disagree, ``P`` inconsistent with the camera or mirrored
        relative to the image (:func:`check_silhouette`), NaNs at surface pixels, no specular pixel above
        the threshold, or a peak on the image border.
    """
    return shared(_observation_of, capture, separation=separation, threshold=float(threshold))


def _observation_of(capture: Capture, *, separation: str, threshold: float) -> Observation:
    """:func:`observation_of`, made afresh."""
    geometry = shared(surface_geometry, capture)
    P, surface = geometry.P, geometry.surface
    check_silhouette(capture)  # a mirrored range passes check_rays (capture/silhouette.py)
    spec = specular_image(capture, separation=separation)
    filled = geometry.filled & every_channel(np.isfinite(spec))
    located = surface | filled
    spec = np.where(located[..., None], spec, 0.0)
    lum = channel_sum(spec) / 3  # spec.mean(axis=-1), bit for bit
    at_surface = lum[surface]
    if at_surface.size and np.ptp(at_surface) <= 1e-6 * np.abs(at_surface).max() and at_surface.max() > 0:
        raise UserError(
            f"{capture.name}: specular: constant over the surface ({at_surface.max():.4g}): no highlight, no signal"
        )
    usable = located & ~_spikes(lum, located)
    peak = _peak_pixel(lum, usable)
    peak_value = lum[peak]
    if not surface.any() or not peak_value > 0:
        raise UserError(f"{capture.name}: specular: no signal: no specular pixel on the surface above 0")
    mask = usable & surface & every_channel(spec > 0) & (lum >= threshold * peak_value)
    if mask.sum() < MIN_SPECULAR_PIXELS:
        raise UserError(
            f"{capture.name}: specular: only {int(mask.sum())} pixels above threshold {threshold} x peak "
            f"(need {MIN_SPECULAR_PIXELS}); lower it with --set threshold=..."
        )
    i, j = peak
    if i in (0, capture.height - 1) or j in (0, capture.width - 1):
        raise UserError(
            f"{capture.name}: specular: peak pixel (row {i}, column {j}) is on the image border; "
            "the highlight is cut off, so its peak is not the mirror point"
        )
    cam = np.asarray(capture.camera.position, dtype=float)
    return Observation(
        specular=spec,
        geometry=geometry,
        filled=filled,
        mask=mask,
        peak=(int(i), int(j)),
        camera_position=cam,
        scale=float(np.linalg.norm(cam - P[i, j])),
    )


#: Half-width (pixels) of the window of :func:`subpixel_peak`.
SUBPIXEL_RADIUS = 2


def subpixel_peak(lum: np.ndarray, usable: np.ndarray, peak: tuple[int, int], *,
                  radius: int = SUBPIXEL_RADIUS) -> np.ndarray:
    """Sub-pixel peak ``(row, column)`` of ``lum`` around the pixel ``peak``.

    A log-Gaussian fit: a 2-D quadratic in ``ln lum`` over the
    ``(2·radius + 1)²`` window (usable, positive pixels), weighted by
    ``lum²`` (the log's noise falls as 1/lum) and its stationary point, exact
    for a Gaussian lobe sampled on the grid and less moved by noise than a
    three-point parabola. Falls back to the pixel centre when the fit has no
    maximum within the window (fewer than 6 pixels, a saddle).

    Returns
    -------
    ndarray, shape (2,)
        Row and column in pixel units, integers at pixel centres.
    """
    i0, j0 = peak
    H, W = lum.shape
    rows = slice(max(i0 - radius, 0), min(i0 + radius + 1, H))
    cols = slice(max(j0 - radius, 0), min(j0 + radius + 1, W))
    win, ok = lum[rows, cols], usable[rows, cols] & (lum[rows, cols] > 0)
    if ok.sum() < 6 or not lum[peak] > 0:
        return np.array(peak, dtype=float)
    y, x = np.nonzero(ok)
    y = y + rows.start - i0
    x = x + cols.start - j0
    v = win[ok] / lum[peak]
    A = np.stack([np.ones_like(v), y, x, y * y, y * x, x * x], axis=1) * v[:, None]
    coef = np.linalg.lstsq(A, np.log(v) * v, rcond=None)[0]
    hess = np.array([[2 * coef[3], coef[4]], [coef[4], 2 * coef[5]]])
    if not (np.all(np.isfinite(hess)) and hess[0, 0] < 0 and np.linalg.det(hess) > 0):
        return np.array(peak, dtype=float)
    off = np.linalg.solve(hess, -coef[1:3])
    if np.max(np.abs(off)) > radius:
        return np.array(peak, dtype=float)
    return np.array(peak, dtype=float) + off


def surface_at(obs: Observation, rc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface point and unit normal at continuous pixel coordinates ``rc = (row, column)``.

    Bilinear interpolation of ``P`` and ``N`` between the four surrounding
    pixel centres (``N`` renormalised), measured or filled (``obs.located``);
    where one of them is neither, the nearest pixel's. Exact at pixel centres.

    Returns
    -------
    P, N : ndarray, shape (3,)
    """
    r, c = float(rc[0]), float(rc[1])
    H, W = obs.surface.shape
    i0, j0 = int(np.floor(r)), int(np.floor(c))
    fr, fc = r - i0, c - j0
    if fr == 0.0 and fc == 0.0 and 0 <= i0 < H and 0 <= j0 < W:
        return obs.P[i0, j0].copy(), obs.N[i0, j0].copy()
    corners = [(i0, j0), (i0, j0 + 1), (i0 + 1, j0), (i0 + 1, j0 + 1)]
    located = obs.located
    if not all(0 <= i < H and 0 <= j < W and located[i, j] for i, j in corners):
        i, j = int(np.clip(round(r), 0, H - 1)), int(np.clip(round(c), 0, W - 1))
        return obs.P[i, j].copy(), obs.N[i, j].copy()
    w = np.array([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc])
    P = sum(wk * obs.P[i, j] for wk, (i, j) in zip(w, corners))
    N = sum(wk * obs.N[i, j] for wk, (i, j) in zip(w, corners))
    return P, normalize(N)
