"""Method ``mirror-spheres``: the lamp from its images on two or more chrome balls of known radius (issue 40).

Each mirror ball of ``rig.targets`` shows the lamp as a small bright spot. Its position in the image fixes one
ray from the ball towards the lamp; two or more balls fix the lamp.

* the balls' centres: the rig's calibrated ``centre``, or (``centres="silhouette"``) each ball's silhouette
  (:func:`silhouette_centre`: the cone of camera rays tangent to the ball);
* the lamp's image on each ball: the intensity-weighted centroid of the ball's pixels brighter than ``threshold``
  × its brightest (:func:`lamp_image`): a camera integrates the spot over each pixel's area, so a spot smaller
  than a pixel still moves the centroid;
* the start (Powell, Sarkar & Goldgof, TPAMI 2001): the centroid's camera ray meets the ball at ``X``, normal
  ``n = (X − C)/R``, and reflects to ``r = d − 2 (d·n) n``; the lamp is the point closest to the reflected rays in
  least squares (:func:`closest_point`);
* the refinement (Ackermann, Fuhrmann & Goesele, VMV 2013): the lamp whose mirror images
  (:func:`mirror_points`) project nearest the centroids, least squares in pixels (3 unknowns, 2 residuals a ball);
* the covariance: every error that moves the lamp, propagated linearly (:func:`sensitivities`): the centroids'
  pixel quantisation (:data:`QUANTISATION_PX2`) and noise (the camera noise model of
  :mod:`~nearlight.estimator.noise` through the weighted centroid when the capture states its sensor, else the
  variance the reprojection residual shows beyond the stated errors), and the centres' error: the rig's stated
  ``centre_error_m``, or the silhouette fit's own. A centre error is one draw per capture, shared by every
  estimate made from it, and reaches the lamp magnified about 2 × distance / radius (40 for a 25-mm ball 0.5 m
  from the lamp): no fit averages it away, so a covariance without it claims far more than the capture supports.

The method estimates the lamp only: Ks and σ are NaN, and ``diagnostics["undetermined"]`` names them.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from ..capture import Camera, Capture
from ..capture.targets import RigTarget
from ..errors import UserError
from ..physics.camera import pixel_ray, project
from ..physics.reflectance import mirror_direction, normalize
from .fitting import central_jacobian
from .noise import VarianceModel, camera_noise, variance
from .options import Choice, Fraction
from .result import Estimate

#: Halvings of the bracket of the normal's angle in :func:`mirror_points` (at most π: then below 2e-7 rad), and the
#: steps of false position that follow: the bisector is smooth, so each step squares the relative error (measured:
#: the points within 7e-17 m of the generator's ``brentq`` root, which is 1e-15 rad).
BISECTION_STEPS = 24
FALSE_POSITION_STEPS = 3
#: ``least_squares``'s tolerances of the refinement: a step of 1e-12 of the lamp's coordinates (5e-13 m at 0.5 m), far
#: below any centroid's error; tighter ones run to ``max_nfev`` on noisy centroids (1e-15: 3 times the evaluations).
FIT_TOLERANCE = 1e-12
#: Step of the central differences of :func:`sensitivities`, metres: the predicted pixels are smooth over
#: millimetres, so the differences' rounding and truncation errors are ~1e-8 and ~1e-9 relative.
STEP_M = 1e-6
#: Step of the central differences of the start's sensitivity to the centroids, pixels.
STEP_PX = 1e-4
#: Variance per axis of the centroid of a lamp's image smaller than a pixel, px²: a camera integrates the image
#: over each pixel, so its centroid lies anywhere within the pixel(s) it falls on. For a uniform image of width
#: ``s`` < 1 px at a uniformly random sub-pixel position the error's mean square is ``(1 − s)²/12`` (within one
#: pixel ``(1 − s)³/12``, straddling two ``s (1 − s)²/12``); the rig does not state ``s`` (the lamp's size), so
#: ``s → 0``: 1/12. Measured on ``scenes/targets.yaml`` (two balls at 160×120, 320×240, 640×480): 0.16 px rms
#: against this 0.29 px.
QUANTISATION_PX2 = 1.0 / 12.0
#: Factor on the covariance of a silhouette's centre (:func:`silhouette_centre`): its limb points' errors are
#: correlated (along the limb neighbouring crossings step through their pixels in order), which the fit's own
#: covariance takes as independent. Over 300 random placements of a 25-mm ball at 0.6 m, at 160×120 and 320×240,
#: the squared Mahalanobis distance of the centre's error averaged 4.8 and 4.0 (3 expected); scaled by 1.5 its
#: 95 % ellipsoid covered 94 % and 97 %.
SILHOUETTE_INFLATION = 1.5
#: Where the balls' centres come from.
CENTRES = ("rig", "silhouette")


class View(NamedTuple):
    """A capture's pinhole camera with its image size: rays through image positions, image positions of points.

    Attributes
    ----------
    camera : Camera
        Its ``position``, ``to_world`` and ``fov_x_deg`` (all needed).
    width, height : int
        Image size, pixels.
    """

    camera: Camera
    width: int
    height: int

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unit world rays through image positions ``pixels`` (..., 2) = (column, row), pixels; shape (..., 3)."""
        pixels = np.asarray(pixels, float)
        return pixel_ray(self.camera.to_world, pixels[..., 0], pixels[..., 1], self.width, self.height,
                         self.camera.fov_x_deg)  # fmt: skip

    def pixels(self, points: np.ndarray) -> np.ndarray:
        """Image positions (column, row) of world points (..., 3), metres; shape (..., 2), pixels."""
        col, row, _ = project(np.asarray(points, float) - self.camera.position, self.camera.to_world, self.width,
                              self.height, self.camera.fov_x_deg)  # fmt: skip
        return np.stack([col, row], axis=-1)


def view_of(capture: Capture) -> View:
    """The capture's :class:`View`; a one-line :class:`UserError` when its camera has no ``to_world`` or FOV."""
    cam = capture.camera
    if cam.to_world is None or cam.fov_x_deg is None:
        raise UserError(f"{capture.name}: mirror-spheres: needs camera.to_world and camera.fov_x_deg")
    return View(Camera(np.asarray(cam.position, float), np.asarray(cam.to_world, float), float(cam.fov_x_deg)),
                capture.width, capture.height)  # fmt: skip


def mirror_points(camera_position: np.ndarray, centres: np.ndarray, radii: np.ndarray,
                  lamp: np.ndarray) -> np.ndarray:  # fmt: skip
    """Where each mirror ball reflects the lamp's centre to the camera (the specular point of a convex mirror).

    :func:`nearlight.generator.targets_closed_form.lamp_image_centre`'s construction, vectorised over the balls
    and in numpy alone (the estimator may not import the generator): the point ``O + R n(φ)``,
    ``n(φ) = cos φ u + sin φ w`` in the plane of camera, centre and lamp, ``φ`` the root of the bisector condition
    on the arc both see (:func:`_bisector`), bracketed by :data:`BISECTION_STEPS` halvings and polished by
    :data:`FALSE_POSITION_STEPS` steps of false position.

    Parameters
    ----------
    camera_position : ndarray, shape (3,)
    centres : ndarray, shape (B, 3)
        Ball centres, metres.
    radii : ndarray, shape (B,)
        Ball radii, metres.
    lamp : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (B, 3)
        The points, metres; NaN for a ball no point of which both the camera and the lamp see (no image).
    """
    C, L = np.asarray(camera_position, float), np.asarray(lamp, float)
    O, R = np.asarray(centres, float).reshape(-1, 3), np.asarray(radii, float).reshape(-1)
    camera = np.linalg.norm(C - O, axis=-1)
    u = (C - O) / camera[:, None]
    to_lamp = L - O
    along = np.sum(to_lamp * u, axis=-1)
    across = to_lamp - along[:, None] * u
    span = np.linalg.norm(across, axis=-1)
    beta = np.arctan2(span, along)
    w = across / np.where(span > 0, span, 1.0)[:, None]
    with np.errstate(invalid="ignore"):  # a lamp or camera inside a ball: no image (NaN)
        a = np.maximum(0.0, beta - np.arccos(R / np.linalg.norm(to_lamp, axis=-1)))
        b = np.minimum(beta, np.arccos(R / camera))
    seen = a < b

    def f(phi: np.ndarray) -> np.ndarray:
        return _bisector(phi, camera, along, span, R)

    for _ in range(BISECTION_STEPS):  # the bisector is positive at the arc's start, negative at its end
        mid = 0.5 * (a + b)
        positive = f(mid) > 0
        a, b = np.where(positive, mid, a), np.where(positive, b, mid)
    for _ in range(FALSE_POSITION_STEPS):
        fa, fb = f(a), f(b)
        with np.errstate(invalid="ignore", divide="ignore"):
            mid = np.where(fa > fb, a + fa * (b - a) / (fa - fb), a)
        positive = f(mid) > 0
        a, b = np.where(positive, mid, a), np.where(positive, b, mid)
    phi = np.where(np.abs(f(a)) < np.abs(f(b)), a, b)
    points = O + R[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * w)
    facing = beta < 1e-12  # the lamp on the camera's side of its line through the centre
    points = np.where(facing[:, None], O + R[:, None] * u, points)
    return np.where((seen | facing)[:, None], points, np.nan)


def _bisector(phi: np.ndarray, camera: np.ndarray, along: np.ndarray, across: np.ndarray,
              radius: np.ndarray) -> np.ndarray:  # fmt: skip
    """The component along the ball's tangent of the sum of the unit vectors from ``X = R n(φ)`` to the camera
    and to the lamp, in the plane's coordinates (camera at ``(|C − O|, 0)``, lamp at ``(along, across)``):
    zero where ``n`` halves the angle between them (the reflection law)."""
    cos, sin = np.cos(phi), np.sin(phi)
    to_camera = np.sqrt(camera**2 + radius**2 - 2.0 * camera * radius * cos)
    to_lamp = np.sqrt(along**2 + across**2 + radius**2 - 2.0 * radius * (along * cos + across * sin))
    return -camera * sin / to_camera + (across * cos - along * sin) / to_lamp


def predicted_pixels(view: View, centres: np.ndarray, radii: np.ndarray, lamp: np.ndarray) -> np.ndarray:
    """The lamp's image on each ball, (column, row) pixels, shape (B, 2): :func:`mirror_points`, projected."""
    return view.pixels(mirror_points(view.camera.position, centres, radii, lamp))


def reflected_rays(view: View, centres: np.ndarray, radii: np.ndarray,
                   pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The camera rays through ``pixels`` mirrored by the balls: where each meets its ball, and where it goes.

    A ray that misses its ball (a centre or centroid a little off) is mirrored at the ball's point nearest it:
    the limit of a grazing hit.

    Parameters
    ----------
    view : View
    centres : ndarray, shape (B, 3)
    radii : ndarray, shape (B,)
    pixels : ndarray, shape (B, 2)
        The lamp's image on each ball, (column, row) pixels.

    Returns
    -------
    points : ndarray, shape (B, 3)
        ``X``, metres.
    directions : ndarray, shape (B, 3)
        Unit reflected directions ``r = d − 2 (d·n) n``.
    """
    C, R = view.camera.position, np.asarray(radii, float)[:, None]
    d = view.rays(pixels)
    nearest = np.sum((centres - C) * d, axis=-1, keepdims=True)  # along the ray, to its point nearest the centre
    half = np.sqrt(np.maximum(R**2 - np.sum(np.square(C + nearest * d - centres), axis=-1, keepdims=True), 0.0))
    n = normalize(C + (nearest - half) * d - centres)
    return centres + R * n, mirror_direction(n, -d)


def closest_point(points: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The point nearest to the lines ``points[k] + t directions[k]`` in least squares, shape (3,).

    Solves ``Σ_k (I − r_k r_kᵀ) L = Σ_k (I − r_k r_kᵀ) X_k`` (unit ``r_k``); singular for parallel lines.
    """
    projectors = np.eye(3) - directions[:, :, None] * directions[:, None, :]
    return np.linalg.solve(projectors.sum(axis=0), np.einsum("kij,kj->i", projectors, points))


def powell_lamp(view: View, centres: np.ndarray, radii: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """The start: the point nearest the reflected rays (Powell et al. 2001), shape (3,), metres."""
    return closest_point(*reflected_rays(view, centres, radii, pixels))


def refined_lamp(view: View, centres: np.ndarray, radii: np.ndarray, pixels: np.ndarray,
                 start: np.ndarray) -> dict:  # fmt: skip
    """The lamp whose images project nearest ``pixels`` (Ackermann et al. 2013): least squares in pixels.

    Returns
    -------
    dict
        ``lamp`` (3,), ``nfev``, ``status`` (scipy's), ``cost`` (½ Σ residual², px²).
    """
    fit = least_squares(lambda L: (predicted_pixels(view, centres, radii, L) - pixels).ravel(), start,
                        x_scale=1.0, xtol=FIT_TOLERANCE, ftol=FIT_TOLERANCE, gtol=FIT_TOLERANCE)  # fmt: skip
    return {"lamp": fit.x, "nfev": int(fit.nfev), "status": int(fit.status), "cost": float(fit.cost)}


def locate_lamp(view: View, centres: np.ndarray, radii: np.ndarray, pixels: np.ndarray, *,
                refine: bool = True) -> dict:  # fmt: skip
    """The lamp from its images on the balls: Powell's start, then (``refine``) the reprojection fit.

    Parameters
    ----------
    view : View
    centres : ndarray, shape (B, 3)
        Ball centres, metres (B ≥ 2).
    radii : ndarray, shape (B,)
        Ball radii, metres.
    pixels : ndarray, shape (B, 2)
        The lamp's image on each ball, (column, row) pixels (centres at ``k + 0.5``).
    refine : bool

    Returns
    -------
    dict
        ``start`` (3,), ``lamp`` (3,) (the start when not ``refine``), ``points`` and ``directions`` (B, 3) of the
        reflected rays, ``residual`` (B, 2) reprojection residual at ``lamp`` (px), and with ``refine`` ``fit``
        (:func:`refined_lamp`'s ``nfev``, ``status``, ``cost``).
    """
    centres, radii, pixels = (np.asarray(a, float) for a in (centres, radii, pixels))
    X, r = reflected_rays(view, centres, radii, pixels)
    start = closest_point(X, r)
    out = {"start": start, "lamp": start, "points": X, "directions": r}
    if refine:
        fit = refined_lamp(view, centres, radii, pixels, start)
        out.update(lamp=fit.pop("lamp"), fit=fit)
    out["residual"] = predicted_pixels(view, centres, radii, out["lamp"]) - pixels
    return out


class Sensitivities(NamedTuple):
    """The linear response of the estimate and of its residual to the errors of its inputs.

    Attributes
    ----------
    lamp_pixels, lamp_centres : ndarray, shape (3, 2B), (3, 3B)
        ``∂L̂/∂m`` (m per px) and ``∂L̂/∂C`` (m per m) of the estimate to the centroids ``m`` and the centres ``C``
        (ball-major, (column, row) and (x, y, z)).
    residual_pixels, residual_centres : ndarray, shape (2B, 2B), (2B, 3B)
        The same of the reprojection residual ``p(L̂, C) − m``.
    """

    lamp_pixels: np.ndarray
    lamp_centres: np.ndarray
    residual_pixels: np.ndarray
    residual_centres: np.ndarray


def sensitivities(view: View, centres: np.ndarray, radii: np.ndarray, pixels: np.ndarray, lamp: np.ndarray, *,
                  refined: bool) -> Sensitivities:  # fmt: skip
    """:class:`Sensitivities` of the estimate ``lamp`` made from ``pixels`` and ``centres``.

    With ``J = ∂p/∂L`` and ``J_C = ∂p/∂C`` of the predicted pixels ``p`` (:func:`predicted_pixels`, central
    differences of :data:`STEP_M`): the refined lamp minimises ``|p(L, C) − m|²``, so to first order
    ``dL̂ = J⁺ (dm − J_C dC)`` (``J⁺`` the pseudo-inverse); the start (:func:`powell_lamp`) is differentiated
    numerically (steps :data:`STEP_PX`, :data:`STEP_M`). The residual follows: ``dr = J dL̂ + J_C dC − dm``.
    """
    B = len(centres)
    J_L = central_jacobian(lambda L: predicted_pixels(view, centres, radii, L), lamp, STEP_M)
    J_C = central_jacobian(lambda c: predicted_pixels(view, c.reshape(B, 3), radii, lamp), centres.ravel(), STEP_M)
    if refined:
        G_m = np.linalg.pinv(J_L)
        G_C = -G_m @ J_C
    else:
        G_m = central_jacobian(lambda m: powell_lamp(view, centres, radii, m.reshape(B, 2)), pixels.ravel(), STEP_PX)
        G_C = central_jacobian(lambda c: powell_lamp(view, c.reshape(B, 3), radii, pixels), centres.ravel(), STEP_M)
    return Sensitivities(G_m, G_C, J_L @ G_m - np.eye(2 * B), J_L @ G_C + J_C)


def block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """The block-diagonal matrix of ``blocks`` (B, k, k), shape (B·k, B·k)."""
    B, k, _ = blocks.shape
    out = np.zeros((B * k, B * k))
    for i, block in enumerate(blocks):
        out[i * k : (i + 1) * k, i * k : (i + 1) * k] = block
    return out


def lamp_covariance(sens: Sensitivities, pixel_covariances: np.ndarray, centre_covariances: np.ndarray) -> np.ndarray:
    """The lamp's 1-σ covariance, shape (3, 3), m²: ``G_m S_m G_mᵀ + G_C S_C G_Cᵀ``, the balls independent.

    Parameters
    ----------
    sens : Sensitivities
    pixel_covariances : ndarray, shape (B, 2, 2)
        Each centroid's covariance, px².
    centre_covariances : ndarray, shape (B, 3, 3)
        Each centre's error covariance, m² (0 for a centre taken as exact).
    """
    G_m, G_C = sens.lamp_pixels, sens.lamp_centres
    return G_m @ block_diagonal(pixel_covariances) @ G_m.T + G_C @ block_diagonal(centre_covariances) @ G_C.T


def residual_pixel_variance(sens: Sensitivities, residual: np.ndarray, pixel_covariances: np.ndarray,
                            centre_covariances: np.ndarray) -> float:  # fmt: skip
    """The centroids' variance per axis (px², alike for every ball) that the reprojection residual shows beyond
    the errors already stated.

    To first order ``r = A_m δm + A_C δC`` (:class:`Sensitivities`), so ``E|r|² = tr(A_m (S_m + s² I) A_mᵀ) +
    tr(A_C S_C A_Cᵀ)``; solved for ``s²`` (at least 0). For the refined lamp ``tr(A_mᵀA_m) = 2B − 3``: with two
    balls one degree of freedom, a rough measure (relative standard deviation √2).
    """
    A_m, A_C = sens.residual_pixels, sens.residual_centres
    stated = np.trace(A_m @ block_diagonal(pixel_covariances) @ A_m.T)
    stated += np.trace(A_C @ block_diagonal(centre_covariances) @ A_C.T)
    return max(float(np.sum(np.square(residual)) - stated), 0.0) / float(np.trace(A_m.T @ A_m))


def silhouette_centre(view: View, inside: np.ndarray, depth: np.ndarray,
                      radius: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A ball's centre from its silhouette (the cone of camera rays tangent to it), and its covariance.

    The rays ``d`` tangent to a sphere of centre direction ``c`` and angular radius θ satisfy ``c·d = cos θ``:
    ``d·w = 1`` with ``w = c / cos θ``, solved in least squares over rays through the limb; then
    ``sin θ = R/|C − O|`` puts the centre at ``O + R w / √(|w|² − 1)`` (``O`` the camera). The limb is sampled at
    the midpoints between each pixel centre inside the silhouette and its 4-neighbour outside, where that
    neighbour sees nothing or something farther (not an occluder, not the image's edge).

    Each midpoint is off the true limb by up to ½ pixel along its pair's axis, evenly either way: unbiased to
    first order; the second-order bias of the apparent radius ``ρ`` (px) is ``1/(24 ρ)`` px (``E[e²] = 1/12``
    over ``2ρ``, halved by the angle average; measured 0.002–0.004 px on discs of 9–40 px), a relative
    ``1/(24 ρ²)`` of the distance. What remains is the midpoints' scatter (0.23 px rms) averaged over the limb,
    which leaves the mean radius off by a few hundredths of a pixel, a relative ``δρ/ρ`` of the distance
    (1–2 mm at 0.6 m for a 25-mm ball of radius 17 px at 320×240): that is the returned covariance,
    ``s² (DᵀD)⁻¹`` of the fit (``s²`` its residual variance, the points taken as independent) through
    ``∂C/∂w = R (I/q − w wᵀ/q³)``, ``q = √(|w|² − 1)``, times :data:`SILHOUETTE_INFLATION`.

    Parameters
    ----------
    view : View
    inside : ndarray of bool, shape (H, W)
        The ball's pixels (their centres' rays meet it).
    depth : ndarray, shape (H, W)
        Distance along each pixel's ray to what it sees, metres; not finite where it sees nothing.
    radius : float
        The ball's radius, metres.

    Returns
    -------
    centre : ndarray, shape (3,)
        Metres; NaN when fewer than 4 limb points are seen.
    covariance : ndarray, shape (3, 3)
        Its 1-σ covariance, m².
    """
    midpoints = []
    for axis in (0, 1):  # pairs of vertical, then horizontal neighbours
        first = tuple(slice(None, -1) if a == axis else slice(None) for a in (0, 1))
        second = tuple(slice(1, None) if a == axis else slice(None) for a in (0, 1))
        in_a, in_b, d_a, d_b = inside[first], inside[second], depth[first], depth[second]
        rows, cols = np.nonzero(_limb(in_a, in_b, d_a, d_b) | _limb(in_b, in_a, d_b, d_a))
        offset = np.array([0.5, 1.0]) if axis == 0 else np.array([1.0, 0.5])  # (column, row) of the midpoint
        midpoints.append(np.stack([cols, rows], axis=-1) + offset)
    points = np.concatenate(midpoints)
    if len(points) < 4:
        return np.full(3, np.nan), np.full((3, 3), np.nan)
    D = view.rays(points)
    w, *_ = np.linalg.lstsq(D, np.ones(len(points)), rcond=None)
    s2 = float(np.sum(np.square(D @ w - 1.0))) / (len(points) - 3)
    q = np.sqrt(w @ w - 1.0)
    dC_dw = radius * (np.eye(3) / q - np.outer(w, w) / q**3)
    covariance = SILHOUETTE_INFLATION * dC_dw @ (s2 * np.linalg.inv(D.T @ D)) @ dC_dw.T
    return view.camera.position + radius * w / q, covariance


def _limb(inside: np.ndarray, outside: np.ndarray, depth_in: np.ndarray, depth_out: np.ndarray) -> np.ndarray:
    """Pairs of pixels whose first is the ball's and whose second, not the ball's, sees nothing or something
    farther: the ball's limb passes between them."""
    with np.errstate(invalid="ignore"):
        return inside & ~outside & (~np.isfinite(depth_out) | (depth_out > depth_in))


def lamp_image(brightness: np.ndarray, ball: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """The pixels of the lamp's image on a ball and their weights: those brighter than ``threshold`` × the ball's
    brightest pixel (none when that is not above 0).

    Returns
    -------
    pixels : ndarray, shape (n, 2)
        Their centres (column, row), pixels.
    weights : ndarray, shape (n,)
        Their brightness.
    """
    top = float(brightness[ball].max(initial=0.0))
    lit = ball & (brightness > threshold * top) if top > 0 else np.zeros_like(ball)
    rows, cols = np.nonzero(lit)
    return np.stack([cols + 0.5, rows + 0.5], axis=-1), brightness[rows, cols]


def centroid_covariance(pixels: np.ndarray, weights: np.ndarray, weight_variances: np.ndarray) -> np.ndarray:
    """Covariance of the weighted centroid ``m = Σ w p / Σ w`` of independent weights, (2, 2) px²:
    ``Σ var(w_i) (p_i − m)(p_i − m)ᵀ / (Σ w)²`` (``∂m/∂w_i = (p_i − m)/Σ w``; the pixel set held fixed)."""
    offsets = pixels - weights @ pixels / weights.sum()
    return np.einsum("i,ij,ik->jk", weight_variances, offsets, offsets) / weights.sum() ** 2


def mirror_spheres(capture: Capture) -> list[RigTarget]:
    """The capture's mirror balls (``rig.targets`` of type ``mirror_sphere``), at least two, each in view."""
    balls = [t for t in capture.rig.targets if t.type == "mirror_sphere"]
    if len(balls) < 2:
        raise UserError(f"{capture.name}: mirror-spheres: needs at least 2 mirror spheres in rig.targets, the "
                        f"capture has {len(balls)}")  # fmt: skip
    missing = [t.name for t in balls if capture.object_id is None or t.name not in capture.objects]
    if missing:
        raise UserError(f"{capture.name}: mirror-spheres: {missing[0]}: no pixels of it (object_id and objects say "
                        "which pixel sees which target)")  # fmt: skip
    if capture.stack is None:
        raise UserError(f"{capture.name}: mirror-spheres: needs the analyzer stack (channels pol<k>)")
    return balls


def ball_centre(capture: Capture, view: View, target: RigTarget, on: np.ndarray,
                depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`silhouette_centre` of a ball's pixels ``on`` (H, W), or a one-line :class:`UserError`."""
    centre, cov = silhouette_centre(view, on, depth, target.radius)
    if not np.all(np.isfinite(centre)):
        raise UserError(f"{capture.name}: mirror-spheres: {target.name}: its silhouette shows too little limb to fit "
                        "(fewer than 4 pixel pairs)")  # fmt: skip
    return centre, cov


def lamp_centroid(capture: Capture, target: RigTarget, on: np.ndarray, stack: np.ndarray,
                  noise: VarianceModel | None, threshold: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The centroid (column, row) of the lamp's image on a ball (:func:`lamp_image` of the stack's mean over angles
    and channels) and its (2, 2) covariance, px²: :data:`QUANTISATION_PX2` per axis, plus the camera's ``noise``
    through the weights (each the mean of K × 3 independent readings) when stated; a one-line
    :class:`UserError` when the ball shows no image."""
    pixels, weights = lamp_image(stack.mean(axis=(0, 3)), on, threshold)
    if len(weights) == 0:
        raise UserError(f"{capture.name}: mirror-spheres: {target.name}: no image of the lamp on the ball (is the "
                        "lamp a shape rays can hit? lamp.intersectable)")  # fmt: skip
    cov = QUANTISATION_PX2 * np.eye(2)
    if noise is not None:
        rows, cols = (pixels[:, 1] - 0.5).astype(int), (pixels[:, 0] - 0.5).astype(int)
        readings = variance(stack[:, rows, cols, :], noise)  # (K, n, 3)
        cov = cov + centroid_covariance(pixels, weights, readings.sum(axis=(0, 2)) / readings[:, 0].size**2)
    return weights @ pixels / weights.sum(), cov


def mirror_spheres_estimate(
    capture: Capture,
    *,
    centres: Choice(CENTRES) = "rig",
    refine: bool = True,
    threshold: Fraction = 0.2,
) -> Estimate:
    """Method ``mirror-spheres``: the lamp from its images on the capture's mirror balls (module docstring).

    Parameters
    ----------
    capture : Capture
        With at least two ``mirror_sphere`` targets in ``rig.targets``, their pixels in ``object_id``, the
        analyzer stack, and ``camera.to_world`` and ``fov_x_deg``.
    centres : {"rig", "silhouette"}
        The balls' centres: the rig's calibrated ones, or each ball's silhouette (:func:`silhouette_centre`); the
        covariance carries the rig's stated ``centre_error_m`` or the silhouette fit's own covariance.
    refine : bool
        Refine Powell's start by the reprojection fit.
    threshold : float
        The lamp's image: a ball's pixels brighter than this fraction of its brightest (mean of the analyzer
        stack over angles and channels).

    Returns
    -------
    Estimate
        ``lamp_position`` and its 1-σ ``covariance`` (σ's row and column NaN); Ks and σ NaN. ``stages``: ``balls``
        (per ball: the ``centre`` used and ``centre_cov_m2``, ``centroid_px`` and ``centroid_cov_px2``, the
        reflected ray's ``point`` and ``direction``), ``init`` and ``fit`` (lamp, reprojection RMS in px).
        ``diagnostics["centroid_noise"]``: where the centroids' noise came from (``sensor``, or ``residual``) and
        the variance per axis the residual added (px²).

    Raises
    ------
    UserError
        Fewer than 2 mirror balls, a ball out of view, or one showing no image of the lamp.
    """
    clock = time.perf_counter()
    view, balls = view_of(capture), mirror_spheres(capture)
    radii = np.array([t.radius for t in balls])
    stack = np.asarray(capture.stack, float)
    noise = camera_noise(capture) if capture.sensor is not None else None
    on = [capture.object_id == capture.objects.index(t.name) + 1 for t in balls]
    if centres == "rig":
        C = np.array([t.centre for t in balls], float)
        C_cov = np.array([t.centre_error_m**2 * np.eye(3) for t in balls])
    else:
        depth = np.linalg.norm(np.asarray(capture.P, float) - view.camera.position, axis=-1)
        C, C_cov = map(np.array, zip(*(ball_centre(capture, view, t, o, depth) for t, o in zip(balls, on))))
    m, m_cov = map(np.array, zip(*(lamp_centroid(capture, t, o, stack, noise, threshold) for t, o in zip(balls, on))))
    timings = {"observe": time.perf_counter() - clock}

    clock = time.perf_counter()
    found = locate_lamp(view, C, radii, m, refine=refine)
    timings["fit"] = time.perf_counter() - clock

    clock = time.perf_counter()
    sens = sensitivities(view, C, radii, m, found["lamp"], refined=refine)
    excess = 0.0 if noise is not None else residual_pixel_variance(sens, found["residual"], m_cov, C_cov)
    m_cov = m_cov + excess * np.eye(2)
    covariance = np.full((4, 4), np.nan)
    covariance[:3, :3] = lamp_covariance(sens, m_cov, C_cov)
    timings["covariance"] = time.perf_counter() - clock

    def rms(lamp: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.square(predicted_pixels(view, C, radii, lamp) - m))))

    return Estimate(
        method="mirror-spheres",
        lamp_position=found["lamp"],
        ks=np.full(3, np.nan),
        sigma=np.nan,
        covariance=covariance,
        stages={
            "balls": {t.name: {"centre": C[k], "centre_cov_m2": C_cov[k], "centroid_px": m[k],
                               "centroid_cov_px2": m_cov[k], "point": found["points"][k],
                               "direction": found["directions"][k]} for k, t in enumerate(balls)},  # fmt: skip
            "init": {"lamp": found["start"], "reprojection_rms_px": rms(found["start"])},
            "fit": {"lamp": found["lamp"], "reprojection_rms_px": rms(found["lamp"]), **found.get("fit", {})},
        },
        diagnostics={"undetermined": ["ks", "sigma"], "centres": centres,
                     "centroid_noise": {"source": "residual" if noise is None else noise.source,
                                        "excess_px2": excess}},  # fmt: skip
        timings=timings,
    )


mirror_spheres_estimate.uses_targets = True
