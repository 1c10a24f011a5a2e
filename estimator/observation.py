"""What every method starts from: the specular image, geometry and highlight.

:func:`observe` validates an in-memory :class:`~nearlight.capture.Capture`
(files are validated by :func:`nearlight.capture.read_capture`), separates the
analyzer stack when there is no ``specular`` image, derives normals from ``P``
when ``N`` is absent, fills range holes (a surface point and normal for the
pixels the range finder missed inside the surface, :func:`fill_range_holes`),
and finds the specular mask and the peak pixel. It never reads
``capture.truth``.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
from collections.abc import Callable, Iterator
from typing import TypeVar

import numpy as np

from ..capture import Capture
from ..errors import UserError
from .normals import normals_from_positions
from .separation import separate_capture
from ..capture.silhouette import check_silhouette
from ..physics.camera import camera_rays, project
from ..physics.reflectance import channel_sum, every_channel, normalize

T = TypeVar("T")

#: Default specular mask threshold, fraction of the peak pixel's mean specular (:func:`observe`).
THRESHOLD = 0.05
#: Fewest specular pixels the regressions and fits accept.
MIN_SPECULAR_PIXELS = 10
#: How far (median over surface pixels) the rays from the camera through ``P``
#: may miss their pixels before a capture is refused as inconsistent with its
#: camera: this many pixels, or this fraction of the image width when larger.
#: Range noise moves ``P`` along its ray (0 px); a camera position 1 cm off at
#: 0.6 m moves rays by about 1°, 15 px of a 640-px, 40° image (passes); ``P``
#: shifted by metres, or a surface behind the camera, misses by far more.
RAY_TOLERANCE_PX = 3.0
RAY_TOLERANCE_FRACTION = 0.05


@dataclasses.dataclass(frozen=True)
class Observation:
    """A capture reduced to what the estimators use (float64, world frame, metres).

    Attributes
    ----------
    specular : ndarray, shape (H, W, 3)
        Specular radiance (separated or given); 0 off the surface.
    P, N : ndarray, shape (H, W, 3)
        Positions and unit normals; at ``filled`` pixels those of the fit
        around the range hole; NaN elsewhere off the surface.
    V : ndarray, shape (H, W, 3)
        Unit vectors from the surface to the camera.
    cos_r : ndarray, shape (H, W)
        cos θr = N·V.
    surface : ndarray, shape (H, W), bool
        Pixels with a finite measured position and a normal facing the
        camera: the only pixels any fit uses.
    filled : ndarray, shape (H, W), bool
        Pixels inside range holes (:func:`enclosed_holes`) whose point and
        normal come from :func:`fill_range_holes`, facing the camera, with a
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
    P: np.ndarray
    N: np.ndarray
    V: np.ndarray
    cos_r: np.ndarray
    surface: np.ndarray
    filled: np.ndarray
    mask: np.ndarray
    peak: tuple[int, int]
    camera_position: np.ndarray
    scale: float

    @property
    def located(self) -> np.ndarray:
        """``[H, W]`` bool: ``surface | filled``, pixels with a surface point and normal (measured or filled)."""
        return self.surface | self.filled

    @property
    def peak_point(self) -> np.ndarray:
        """Surface point of the peak pixel, shape (3,)."""
        return self.P[self.peak]


def _check_shapes(capture: Capture) -> None:
    name, hw = capture.name, (capture.height, capture.width)
    if np.shape(capture.P) != (*hw, 3):
        raise UserError(f"{name}: channel P: shape {np.shape(capture.P)}, expected {(*hw, 3)} (height x width x 3)")
    for key in ("N", "specular", "diffuse"):
        img = getattr(capture, key)
        if img is not None and np.shape(img) != (*hw, 3):
            raise UserError(f"{name}: channel {key}: shape {np.shape(img)}, expected {(*hw, 3)}")
    if capture.stack is not None:
        k = 0 if capture.analyzer_angles_deg is None else len(capture.analyzer_angles_deg)
        if np.shape(capture.stack) != (k, *hw, 3):
            raise UserError(
                f"{name}: channels pol<k>: stack shape {np.shape(capture.stack)} does not match "
                f"{k} analyzer angles x {hw[0]} x {hw[1]} x 3"
            )


def _fitted_rays(capture: Capture) -> tuple[np.ndarray, float] | None:
    """The best pinhole camera at ``camera.position`` for the rays through ``P`` (direct linear transform).

    Rays ∝ M·[column, row, 1] fitted to up to 4000 surface pixels' directions
    ``P − camera`` (sign fixed so that they point towards the surface).

    Returns
    -------
    rays : ndarray, shape (H, W, 3)
        Unit ray through every pixel centre, world frame.
    pixel_angle : float
        Angle between the rays of two horizontally adjacent pixels at the image centre, radians.
    None
        When fewer than 8 pixels have a finite ``P``.
    """
    H, W = capture.height, capture.width
    P = np.asarray(capture.P, dtype=float)
    finite = every_channel(np.isfinite(P))
    idx = np.flatnonzero(finite)
    if idx.size < 8:
        return None
    d = P - np.asarray(capture.camera.position, dtype=float)
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    sub = idx[np.linspace(0, idx.size - 1, min(idx.size, 4000)).astype(int)]
    dirs = d.reshape(-1, 3)[sub]
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    pix = np.stack([jj.ravel()[sub], ii.ravel()[sub], np.ones(sub.size)], axis=1)
    pix[:, :2] -= [W / 2, H / 2]
    scale = max(W, H)
    pix[:, :2] /= scale
    # d x (M p) = 0, two independent rows per pixel, M flattened row-major.
    A = np.zeros((2 * sub.size, 9))
    A[0::2, 3:6] = -dirs[:, 2:3] * pix
    A[0::2, 6:9] = dirs[:, 1:2] * pix
    A[1::2, 0:3] = dirs[:, 2:3] * pix
    A[1::2, 6:9] = -dirs[:, 0:1] * pix
    M = np.linalg.svd(A, full_matrices=False)[2][-1].reshape(3, 3)
    allpix = np.stack([(jj - W / 2) / scale, (ii - H / 2) / scale, np.ones((H, W))], axis=-1)
    ray = allpix @ M.T
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    ray *= np.sign(np.sum(ray.reshape(-1, 3)[sub] * dirs))
    i0, j0 = H // 2, W // 2
    step = np.stack([(np.array([j0 + 1.5, j0 + 0.5]) - W / 2) / scale, (np.array([i0 + 0.5] * 2) - H / 2) / scale,
                     np.ones(2)], axis=-1) @ M.T  # fmt: skip
    step /= np.linalg.norm(step, axis=-1, keepdims=True)
    return ray, float(np.arccos(np.clip(step[0] @ step[1], -1.0, 1.0)))


def pixel_rays(capture: Capture) -> np.ndarray | None:
    """Unit rays from the camera through every pixel centre, shape ``(H, W, 3)``, world frame.

    The capture's camera when it has ``to_world`` and ``fov_x_deg``
    (:func:`nearlight.physics.camera.camera_rays`); otherwise the pinhole
    camera fitted to the rays through ``P`` (:func:`_fitted_rays`; None with
    fewer than 8 finite ``P``).
    """
    cam = capture.camera
    if cam.to_world is not None and cam.fov_x_deg is not None:
        return camera_rays(np.asarray(cam.to_world, dtype=float), capture.width, capture.height, cam.fov_x_deg)
    fitted = _fitted_rays(capture)
    return None if fitted is None else fitted[0]


def pixel_ray_error(capture: Capture, step: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How far the ray from the camera through each pixel's ``P`` misses that pixel.

    With ``camera.to_world`` and ``fov_x_deg`` (the generator's convention:
    the camera looks along its local +z, image columns run along local −x,
    rows along local −y) the rays are projected into the image; without them
    the best pinhole camera at ``camera.position`` is fitted to the rays
    (:func:`_fitted_rays`) and the residual is measured with that camera's
    pixel size.

    Parameters
    ----------
    capture : Capture
    step : int
        Check the lattice of every ``step``-th row and column, from row and
        column ``step // 2`` (1: every pixel).

    Returns
    -------
    error_px : ndarray, shape (h, w)
        Distance in pixels between each lattice pixel and where its ray
        lands; NaN off the surface. ``h = len(rows)``, ``w = len(cols)``.
    behind : ndarray, shape (h, w), bool
        Surface pixels whose ``P`` is behind the camera (only known with ``to_world``).
    rows : ndarray, shape (h,), int
        The lattice's image rows.
    cols : ndarray, shape (w,), int
        The lattice's image columns.
    """
    H, W = capture.height, capture.width
    rows, cols = np.arange(step // 2, H, step), np.arange(step // 2, W, step)
    lattice = np.ix_(rows, cols)
    C = np.asarray(capture.camera.position, dtype=float)
    P = np.asarray(capture.P[lattice], dtype=float)
    finite = every_channel(np.isfinite(P))
    d = np.where(finite[..., None], P - C, np.nan)
    error = np.full(finite.shape, np.nan)
    behind = np.zeros(finite.shape, bool)
    cam = capture.camera
    if cam.to_world is not None and cam.fov_x_deg is not None:
        jj, ii = np.meshgrid(cols + 0.5, rows + 0.5)
        col, row, z = project(d, cam.to_world, W, H, cam.fov_x_deg)
        behind = finite & ~(z > 0)
        error = np.where(finite & ~behind, np.hypot(col - jj, row - ii), np.nan)
        return error, behind, rows, cols
    fitted = _fitted_rays(capture)
    if fitted is None:
        return error, behind, rows, cols
    ray, pixel_angle = fitted
    unit = d / np.linalg.norm(d, axis=-1, keepdims=True)
    angle = np.arccos(np.clip(np.sum(ray[lattice] * unit, axis=-1), -1.0, 1.0))
    if pixel_angle > 0:
        error = np.where(finite, angle / pixel_angle, np.nan)
    return error, behind, rows, cols


#: :func:`check_rays` looks at a lattice of about this many pixels or more
#: (every pixel up to 2 × this many; a 640×480 capture: every 3rd row and
#: column). The median miss over the lattice is the image's to within its
#: spread over ~2·10⁴ samples (the analytic board and sphere at 640×480,
#: every 3rd pixel against all: 3.52e-6 against 3.54e-6 px and 7.59e-6
#: against 7.63e-6 px, the tolerance being 3 px), and the 1 % behind the
#: camera within 0.1 %; 4 ms against 28 ms.
RAY_CHECK_PIXELS = 20_000


def check_rays(capture: Capture) -> None:
    """Raise :class:`UserError` when ``P`` is inconsistent with the camera.

    Refused: more than 1 % of the surface behind the camera, or rays from the
    camera through ``P`` that miss their pixels by more than
    :data:`RAY_TOLERANCE_PX` pixels or :data:`RAY_TOLERANCE_FRACTION` of the
    image width (whichever is larger), median over the surface; both
    measured on a lattice of about :data:`RAY_CHECK_PIXELS` pixels.
    """
    step = max(1, int(np.sqrt(capture.height * capture.width / RAY_CHECK_PIXELS)))
    error, behind, rows, cols = pixel_ray_error(capture, step)
    n = int(capture.surface_mask[np.ix_(rows, cols)].sum())
    if n and behind.sum() > 0.01 * n:
        i, j = np.argwhere(behind)[0]
        raise UserError(
            f"{capture.name}: channel P: {100 * behind.sum() / n:.0f}% of the surface is behind the camera "
            f"(first at row {rows[i]}, column {cols[j]}); P does not match camera.position/to_world"
        )
    tol = max(RAY_TOLERANCE_PX, RAY_TOLERANCE_FRACTION * capture.width)
    med = float(np.nanmedian(error)) if np.isfinite(error).any() else 0.0
    if med > tol:
        raise UserError(
            f"{capture.name}: channel P: rays from camera.position through P miss their pixels by {med:.1f} px "
            f"(median; at most {tol:.1f} accepted); P does not match the camera"
        )


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


#: Width (pixels) of the ring of measured positions fitted around a range hole (:func:`fill_range_holes`).
HOLE_RING_PX = 3.0


def enclosed_holes(P: np.ndarray) -> np.ndarray:
    """``[H, W]`` bool: pixels without range (non-finite ``P``) enclosed by pixels with range.

    A range hole is a set of pixels without range not connected (4-connected)
    to the image border through other such pixels: the background and holes
    open to it are not holes (a fit there would extrapolate): the components
    of those pixels (4-connected) that touch no edge of the image, the
    pixels :func:`scipy.ndimage.binary_fill_holes` fills, in ~1/3 of its time.
    """
    from scipy.ndimage import label

    labels, n = label(~every_channel(np.isfinite(P)))
    enclosed = np.ones(n + 1, bool)
    enclosed[0] = False  # pixels with range
    enclosed[labels[[0, -1], :]] = False
    enclosed[labels[:, [0, -1]]] = False
    return enclosed[labels]


def fill_range_holes(P: np.ndarray, holes: np.ndarray, rays: np.ndarray, camera_position: np.ndarray, *,
                     ring: float = HOLE_RING_PX) -> tuple[np.ndarray, np.ndarray]:
    """Surface points and unit normals inside range holes, from a quadric fitted to the range around each.

    For each connected hole (8-connected), the finite ``P`` within ``ring``
    pixels (Euclidean) of it are fitted by least squares with a quadric
    height field ``z = q(u, v)`` (6 coefficients) over their best plane
    (``u, v`` along it, ``z`` along its normal); each hole pixel's camera
    ray meets it at the root of a quadratic that tends to the ray–plane
    intersection as the curvature vanishes, and the normal is the
    quadric's there. Why a quadric rather than a plane: both are exact on a
    plane (a board's hole is filled to float rounding), but on a surface of
    curvature radius R, at a distance d from the fitted pixels, a plane is
    off by O(d²/R) in position and O(d/R) in normal, a quadric only by
    O(d⁴/R³) and O(d³/R³). Measured on the 0.15-m analytic sphere at
    160×120 (holes of radius 2 and 4 px, d = 11 and 16 mm): a plane 0.25
    and 0.55 mm, 1.7° and 3.4°; the quadric 0.16 and 0.84 µm, 0.002° and
    0.006°. The hole is surrounded by the ring, so the quadric interpolates
    and its 6 coefficients are well determined (about 50 ring pixels around
    a 3-px hole).

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
        Positions, metres; non-finite without range.
    holes : ndarray, shape (H, W), bool
        The holes to fill (:func:`enclosed_holes`).
    rays : ndarray, shape (H, W, 3)
        Unit camera rays through the pixel centres (:func:`pixel_rays`).
    camera_position : ndarray, shape (3,)
    ring : float
        Width of the fitted ring, pixels.

    Returns
    -------
    P_fill, N_fill : ndarray, shape (H, W, 3)
        Points and unit normals (towards the camera) at the filled hole
        pixels; NaN elsewhere, and in a hole whose ring does not determine a
        quadric (fewer than 6 pixels, or all on one conic) or whose rays miss
        it.
    """
    from scipy.ndimage import distance_transform_edt, find_objects, label

    P = np.asarray(P, dtype=float)
    C = np.asarray(camera_position, dtype=float)
    finite = every_channel(np.isfinite(P))
    P_fill = np.full(P.shape, np.nan)
    N_fill = np.full(P.shape, np.nan)
    labels, _ = label(holes, structure=np.ones((3, 3)))
    H, W = holes.shape
    pad = int(np.ceil(ring)) + 1
    for k, box in enumerate(find_objects(labels), start=1):
        rows = slice(max(box[0].start - pad, 0), min(box[0].stop + pad, H))
        cols = slice(max(box[1].start - pad, 0), min(box[1].stop + pad, W))
        hole = labels[rows, cols] == k
        near = (distance_transform_edt(~hole) <= ring) & finite[rows, cols]
        pts = P[rows, cols][near]
        if len(pts) < 6:
            continue
        centre = pts.mean(axis=0)
        _, vecs = np.linalg.eigh(np.cov((pts - centre).T))
        a, b, n = vecs[:, 2], vecs[:, 1], vecs[:, 0]
        n = n if n @ (C - centre) > 0 else -n
        frame = np.stack([a, b, n])
        local = (pts - centre) @ frame.T
        s = float(np.sqrt(np.mean(np.sum(local[:, :2] ** 2, axis=1))))
        u, v, z = (local / s).T
        A = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=1)
        coef, _, rank, _ = np.linalg.lstsq(A, z, rcond=None)
        if rank < 6:
            continue
        c0, c1, c2, c3, c4, c5 = coef
        o = frame @ (C - centre) / s
        d = rays[rows, cols][hole] @ frame.T
        ou, ov, oz = o
        du, dv, dz = d.T
        # z(t) − q(u(t), v(t)) = a2 t² + a1 t + a0 along the ray o + t·d
        a2 = -(c3 * du * du + c4 * du * dv + c5 * dv * dv)
        a1 = dz - (c1 * du + c2 * dv + 2 * c3 * ou * du + c4 * (ou * dv + ov * du) + 2 * c5 * ov * dv)
        a0 = oz - (c0 + c1 * ou + c2 * ov + c3 * ou * ou + c4 * ou * ov + c5 * ov * ov)
        disc = a1 * a1 - 4.0 * a2 * a0
        with np.errstate(invalid="ignore", divide="ignore"):
            t = -2.0 * a0 / (a1 + np.copysign(np.sqrt(disc), a1))
        ok = (disc >= 0) & (t > 0) & np.isfinite(t)
        pu, pv = ou + t * du, ov + t * dv
        grad = np.stack([-(c1 + 2 * c3 * pu + c4 * pv), -(c2 + c4 * pu + 2 * c5 * pv), np.ones_like(t)], axis=1)
        idx = tuple(np.argwhere(hole).T + [[rows.start], [cols.start]])
        P_fill[idx] = np.where(ok[:, None], C + (s * t)[:, None] * rays[idx], np.nan)
        N_fill[idx] = np.where(ok[:, None], normalize(grad @ frame), np.nan)
    return P_fill, N_fill


def surface_geometry(capture: Capture) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                 np.ndarray]:
    """``P, N, V, cos_r, surface, filled`` of a capture (see :class:`Observation`).

    Range holes (:func:`enclosed_holes`) are filled first (:func:`fill_range_holes`:
    the filled pixels' ``P`` and ``N`` are the fit's); normals absent from the
    capture are then derived from ``P`` with the holes filled
    (:func:`~nearlight.estimator.normals.normals_from_positions`), so that the
    measured pixels around a hole keep whole windows: a window cut by the
    hole would give the normal at its off-centre centroid, off by a fraction
    of pixel footprint / curvature radius (measured next to holes of radius
    2 and 4 px on the 0.15-m analytic sphere at 160×120: 0.24° and 0.61°,
    against 0.012° with whole windows).
    """
    _check_shapes(capture)
    cam = np.asarray(capture.camera.position, dtype=float)
    P = np.array(capture.P, dtype=float)  # a copy: the observation's own
    measured = every_channel(np.isfinite(P))
    holes = enclosed_holes(P)
    rays = pixel_rays(capture) if holes.any() else None
    filled = np.zeros(holes.shape, bool)
    if rays is not None:
        P_fill, N_fill = fill_range_holes(P, holes, rays, cam)
        filled = every_channel(np.isfinite(P_fill))
        P[filled] = P_fill[filled]
    if capture.N is not None:
        N = normalize(np.asarray(capture.N, dtype=float))
    else:
        N = normals_from_positions(P, cam)
    if filled.any():
        N[filled] = N_fill[filled]
    finite = (measured | filled) & every_channel(np.isfinite(N))
    V = normalize(cam - np.where(finite[..., None], P, 0.0))
    cos_r = np.where(finite, channel_sum(np.where(finite[..., None], N, 0.0) * V), 0.0)
    facing = finite & (cos_r > 0)
    return P, N, V, cos_r, facing & measured, facing & filled


def specular_image(capture: Capture, *, separation: str = "fit") -> np.ndarray:
    """The capture's specular image ``[H, W, 3]``: given, or separated from the stack.

    A stack is separated with the rig's extinction ratios (``capture.rig``,
    :func:`~nearlight.estimator.separation.rig_correction`), so a calibrated
    real analyzer or lamp polarizer gives the ideal rig's specular. A given
    ``specular`` image is used as it is (whoever separated it owned that step).
    """
    _check_shapes(capture)
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
    """Within the block, :func:`observe` of one capture object with the same options is made once, and so is
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


def observe(capture: Capture, *, separation: str = "fit", threshold: float = THRESHOLD) -> Observation:
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
    return shared(_observe, capture, separation=separation, threshold=float(threshold))


def _observe(capture: Capture, *, separation: str, threshold: float) -> Observation:
    """:func:`observe`, made afresh."""
    P, N, V, cos_r, surface, filled = surface_geometry(capture)
    check_rays(capture)
    check_silhouette(capture)  # a mirrored range passes check_rays (capture/silhouette.py)
    spec = specular_image(capture, separation=separation)
    filled &= every_channel(np.isfinite(spec))
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
        P=P,
        N=N,
        V=V,
        cos_r=cos_r,
        surface=surface,
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
