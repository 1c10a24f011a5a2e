"""A capture's surface geometry: points, normals and view directions, range holes filled, the range checked.

:func:`surface_geometry` gives every pixel's surface point ``P``, unit normal
``N`` (the capture's, else the surface fitted to ``P``, its points too:
:func:`~nearlight.estimator.surfaces.fit_surface`, the range's error
stated by ``rig.range`` or measured: :func:`range_model`), the unit vector
``V`` to the camera and ``cos θr``; pixels the range finder missed inside the
surface (:func:`enclosed_holes`) get a point and normal from a quadric fitted
to the range around them (:func:`fill_range_holes`), along the capture's
camera rays (:func:`capture_rays`). :func:`check_rays` refuses a range image
that does not match the capture's camera. Metres, world frame, float64.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.ndimage import distance_transform_edt, find_objects, label

from ..capture import Capture
from ..errors import UserError
from ..physics.camera import camera_rays, project
from ..physics.reflectance import channel_sum, every_channel, normalize
from .pinhole import optical_axis, pinhole_matrix
from .range_error import RangeModel, measured_range
from .surfaces import SurfaceParameters, fit_surface

#: How far (median over surface pixels) the rays from the camera through ``P``
#: may miss their pixels before a capture is refused as inconsistent with its
#: camera: this many pixels, or this fraction of the image width when larger.
#: Range noise moves ``P`` along its ray (0 px); a camera position 1 cm off at
#: 0.6 m moves rays by about 1°, 15 px of a 640-px, 40° image (passes); ``P``
#: shifted by metres, or a surface behind the camera, misses by far more.
RAY_TOLERANCE_PX = 3.0
RAY_TOLERANCE_FRACTION = 0.05


def check_shapes(capture: Capture) -> None:
    """Raise :class:`UserError` when a channel's shape disagrees with the capture's height and width."""
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


def capture_rays(capture: Capture) -> np.ndarray | None:
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
        Unit camera rays through the pixel centres (:func:`capture_rays`).
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


@dataclasses.dataclass(frozen=True)
class SurfaceGeometry:
    """A capture's surface as every method sees it (:func:`surface_geometry`); metres, world frame, float64.

    Attributes
    ----------
    P, N : ndarray, shape (H, W, 3)
        Surface points and unit normals (towards the camera): the capture's
        ``N`` with its ``P`` when it has normals, else the surface fitted to
        the range (:func:`~nearlight.estimator.surfaces.fit_surface`: its
        points, the range's noise fitted away, and its normals); at
        ``filled`` pixels those of the fit; NaN elsewhere off the surface.
    V : ndarray, shape (H, W, 3)
        Unit vectors from the surface to the camera.
    cos_r : ndarray, shape (H, W)
        ``N·V``; 0 off the surface.
    surface : ndarray, shape (H, W), bool
        Pixels with a measured position and a normal facing the camera.
    filled : ndarray, shape (H, W), bool
        Pixels inside range holes with a fitted point and normal facing the camera.
    summary : dict
        What the geometry came from, for the estimate's ``diagnostics["geometry"]``:
        ``normals`` (``"capture"`` or ``"fitted"``) and, when fitted, ``surface``
        (the fit's kind: ``plane``, ``sphere``, ``quadric`` or ``local``), ``range``
        (the range error assumed: ``sigma_m``, ``quantum_m``, ``axis``, ``source``
        ``rig`` or ``measured``) and ``normal_sd_deg`` (the median over the
        surface of each normal's standard deviation from the range's error).
    """

    P: np.ndarray
    N: np.ndarray
    V: np.ndarray
    cos_r: np.ndarray
    surface: np.ndarray
    filled: np.ndarray
    summary: dict
    parameters: SurfaceParameters | None = None
    range: RangeModel | None = None


def range_model(capture: Capture, P: np.ndarray, valid: np.ndarray, rays: np.ndarray) -> RangeModel:
    """The range's error: the capture's ``rig.range`` when it states one, else measured from ``P``
    (:func:`~nearlight.estimator.range_error.measured_range`, on the measured pixels ``valid``)."""
    stated = capture.rig.range
    if stated is not None:
        return RangeModel(sigma_m=stated.sigma_m, quantum_m=stated.quantum_m, axis=stated.axis, source="rig")
    cam = np.asarray(capture.camera.position, dtype=float)
    return measured_range(P, cam, valid, optical_axis(pinhole_matrix(rays)))


def surface_geometry(capture: Capture) -> SurfaceGeometry:
    """The surface of a capture as every method sees it (see :class:`SurfaceGeometry`).

    Checks the channels' shapes and the range against the camera
    (:func:`check_shapes`, :func:`check_rays`), fills range holes
    (:func:`enclosed_holes`, :func:`fill_range_holes`), and, when the capture
    has no normals, fits the surface to the range with the holes filled
    (:func:`~nearlight.estimator.surfaces.fit_surface`), its error model
    :func:`range_model`'s, read on the measured pixels only (a filled
    point is on no sensor's lattice): so the measured pixels around a hole keep
    whole windows, and a filled pixel on a plane or sphere gets the whole
    fit's point and normal, not its ring's. Once per capture inside
    :func:`~nearlight.estimator.observation.shared_observations`.
    """
    check_shapes(capture)
    check_rays(capture)
    cam = np.asarray(capture.camera.position, dtype=float)
    P = np.array(capture.P, dtype=float)  # a copy: the observation's own
    measured = every_channel(np.isfinite(P))
    holes = enclosed_holes(P)
    fit_normals = capture.N is None
    rays = capture_rays(capture) if (holes.any() or fit_normals) else None
    filled = np.zeros(holes.shape, bool)
    N_fill = None
    if rays is not None and holes.any():
        P_fill, N_fill = fill_range_holes(P, holes, rays, cam)
        filled = every_channel(np.isfinite(P_fill))
        P[filled] = P_fill[filled]
    summary: dict = {"normals": "capture"}
    parameters, model = None, None
    if not fit_normals:
        N = normalize(np.asarray(capture.N, dtype=float))
        if filled.any():
            N[filled] = N_fill[filled]
    elif rays is None:
        N = np.full(P.shape, np.nan)  # fewer than 8 finite points: no camera to fit a surface through
        summary = {"normals": "fitted", "surface": "none"}
    else:
        model = range_model(capture, P, measured, rays)
        fit = fit_surface(P, cam, rays, model=model, valid=measured | filled)
        N = fit.N
        fitted = every_channel(np.isfinite(fit.P)) & every_channel(np.isfinite(N))
        P = np.where(fitted[..., None], fit.P, P)
        if filled.any():
            lost = filled & ~fitted
            P[lost], N[lost] = P_fill[lost], N_fill[lost]
        parameters = fit.parameters
        sd = fit.sd_rad[measured & fitted]
        summary = {"normals": "fitted", "surface": fit.kind, "range": dataclasses.asdict(model),
                   "normal_sd_deg": float(np.degrees(np.nanmedian(sd))) if np.isfinite(sd).any() else None}
    finite = (measured | filled) & every_channel(np.isfinite(N)) & every_channel(np.isfinite(P))
    V = normalize(cam - np.where(finite[..., None], P, 0.0))
    cos_r = np.where(finite, channel_sum(np.where(finite[..., None], N, 0.0) * V), 0.0)
    facing = finite & (cos_r > 0)
    return SurfaceGeometry(P=P, N=N, V=V, cos_r=cos_r, surface=facing & measured, filled=facing & filled,
                           summary=summary, parameters=parameters, range=model)
