"""Per-pixel noise of the specular image: a Poisson–Gaussian camera, propagated through the separation.

A camera pixel that records radiance ``L`` (expected value ``μ``) has variance

    var(L) = g · μ + r²

with ``g`` the radiance of one electron (shot noise, Poisson in electrons) and
``r²`` the variance that does not grow with the signal (read noise and the
ADC's quantisation step²/12), both in radiance units. Where they come from,
in this order (:func:`camera_noise`):

1. the capture states them (``capture.sensor``: ``saturation``, the radiance
   at full well; ``full_well`` electrons; ``read_noise`` electrons; ``bits``):
   ``g = saturation / full_well``, ``r² = (read_noise · g)² + step²/12`` with
   ``step = saturation / (2^bits − 1)``;
2. otherwise the analyzer stack's own residuals: per pixel and channel the
   stack is fitted by ``a + b cos 2θ + c sin 2θ`` (the Stokes fit of the
   separation); with ``K ≥ 4`` angles the residuals ``e_k`` have
   ``E[Σ_k e_k²] = Σ_k (1 − h_k) var(I_k) = g Σ_k (1 − h_k) μ_k + r² (K − 3)``
   (``h_k`` the fit's leverages; exact because ``I − H`` is a projection),
   so least squares of ``Σ_k e_k²`` on ``Σ_k (1 − h_k) μ_k`` and ``K − 3``
   over the surface pixels gives ``g`` and ``r²``;
3. otherwise (a given specular image without a stated sensor, or 3 angles):
   no model, and the fit weighs every pixel alike.

The separated specular is linear in the stack along the phase of the pixel's
polarization (``specular = Σ_k w_k I_k``, ``w_k = P_1k cos 2β + P_2k sin 2β``
with ``P`` the pseudo-inverse of the Stokes fit's analyzer matrix, rows S0, S1, S2), so its variance is
``Σ_k w_k² var(I_k)`` (for ``K`` evenly spaced angles, ``(8/K)(g·a + r²)``
with ``a`` the mean intensity); a rig correction scales it by its factor
squared. A floor keeps noise-free captures (whose residuals are float
rounding) from weighing a few pixels by 1e10: the variance is at least
``(floor · peak specular)²``, the same 1e-4 of the peak that keeps the robust
loss quadratic there.

Dark pixels are not the model's: a sensor clips at zero, so where a pixel's
readings lie within a few read-noise deviations of zero some were censored,
the separated specular there is biased and its variance under the model is
wrong (:func:`censored_pixels` finds them; the weighted fit measures their
specular from the readings by a censored likelihood instead,
:mod:`~nearlight.estimator.censored`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from scipy import ndimage

from ..physics.polarization import analyzer_matrix, aolp, linear_stokes
from ..physics.reflectance import any_channel
from .observation import shared
from .separation import specular_gain

#: Relative floor of the specular's standard deviation, as a fraction of its peak.
FLOOR = 1e-4


class VarianceModel(NamedTuple):
    """The camera's Poisson–Gaussian noise as a variance, ``var(L) = gain · μ + read_var`` (radiance units).

    Measured or stated per capture (:func:`camera_noise`); a scene's noise
    settings are :class:`nearlight.generator.scene.CameraNoise`.

    Attributes
    ----------
    gain : float
        Radiance of one electron.
    read_var : float
        Signal-independent variance, radiance².
    source : str
        ``"sensor"`` (the capture states it) or ``"stack residuals"``.
    """

    gain: float
    read_var: float
    source: str


def _sensor_field(sensor: Any, key: str) -> float | None:
    value = sensor.get(key) if isinstance(sensor, dict) else getattr(sensor, key, None)
    return None if value is None else float(value)


def sensor_noise(*, saturation: float, full_well: float, read_noise: float = 0.0, bits: float | None = None) -> VarianceModel:
    """The Poisson–Gaussian model of a stated sensor.

    ``gain = saturation / full_well`` (radiance per electron); ``read_var =
    (read_noise · gain)² + q²/12``, the ADC step ``q = saturation / (2^bits − 1)``
    taken as uniform rounding (none without ``bits``).

    Parameters
    ----------
    saturation : float
        Radiance that fills the full well.
    full_well, read_noise : float
        Electrons; electrons rms.
    bits : int, optional
        ADC resolution.
    """
    gain = saturation / full_well
    step = saturation / (2.0**bits - 1.0) if bits else 0.0
    return VarianceModel(gain, (read_noise * gain) ** 2 + step**2 / 12.0, "sensor")


def variance(L: np.ndarray, noise: VarianceModel) -> np.ndarray:
    """``gain · L + read_var`` of recorded radiance ``L`` (negative read as 0), radiance², shape of ``L``."""
    return noise.gain * np.clip(L, 0.0, None) + noise.read_var


def stokes_weights(angles_deg: Any, beta: np.ndarray) -> np.ndarray:
    """Weights ``w_k`` of the specular ``Σ_k w_k I_k`` along phase β, shape ``(K, *beta.shape)``.

    ``w_k = P_1k cos 2β + P_2k sin 2β`` with ``P`` the pseudo-inverse of the
    analyzer matrix (rows S0, S1, S2): the specular ``S1 cos 2β + S2 sin 2β``
    of the Stokes fit read along β. ``Σ_k w_k²`` is ``8 / K`` for ``K``
    evenly spaced angles.

    Parameters
    ----------
    angles_deg : array_like, shape (K,)
    beta : ndarray, shape (...)
        Phase (AoLP) of each pixel, radians.
    """
    P = np.linalg.pinv(analyzer_matrix(angles_deg))
    beta = np.asarray(beta, dtype=float)
    c, s = np.cos(2.0 * beta), np.sin(2.0 * beta)
    shape = (-1,) + (1,) * beta.ndim
    return P[1].reshape(shape) * c + P[2].reshape(shape) * s


#: Most pixels whose stack residuals measure the camera (a regular sample of the surface): two
#: parameters need far fewer, and the whole of a 640×480 stack took ~0.6 s.
NOISE_PIXELS = 20000


def camera_noise(capture: Any, *, surface: np.ndarray | None = None) -> VarianceModel | None:
    """The capture's Poisson–Gaussian camera model: stated, else measured from the stack, else None.

    Parameters
    ----------
    capture : Capture
    surface : ndarray of bool, shape (H, W), optional
        Pixels whose residuals measure it (default: the capture's surface);
        at most :data:`NOISE_PIXELS` of them, every k-th in raster order.

    Made once per capture and ``surface`` inside
    :func:`~nearlight.estimator.observation.shared_observations` (the method's fit and the sanity rules).
    """
    return shared(_camera_noise, capture, surface)


def _camera_noise(capture: Any, surface: np.ndarray | None) -> VarianceModel | None:
    """:func:`camera_noise`, made afresh."""
    sensor = getattr(capture, "sensor", None)
    if sensor is not None:
        sat, well = _sensor_field(sensor, "saturation"), _sensor_field(sensor, "full_well")
        if sat and well:
            return sensor_noise(saturation=sat, full_well=well, read_noise=_sensor_field(sensor, "read_noise") or 0.0,
                                bits=_sensor_field(sensor, "bits"))
    if capture.stack is None or len(capture.analyzer_angles_deg) < 4:
        return None
    A = analyzer_matrix(capture.analyzer_angles_deg)
    if np.linalg.matrix_rank(A) < 3:
        return None
    mask = capture.surface_mask if surface is None else surface
    rows, cols = np.nonzero(mask)
    step = max(1, len(rows) // NOISE_PIXELS)
    I = np.asarray(capture.stack[:, rows[::step], cols[::step]], dtype=float)  # (K, n, 3)
    hat = A @ np.linalg.pinv(A)
    mu = np.tensordot(hat, I, axes=1)
    resid = np.eye(len(A)) - hat
    # per pixel and channel: E[Σ_k e_k²] = Σ_k (1 − h_k) var(I_k) (I − H is a projection), exact
    # whatever the variance of each angle; per angle it would mix the other angles' variances in
    y = np.sum(np.square(I - mu), axis=0).ravel()
    x = np.tensordot(np.diag(resid), mu, axes=1).ravel()
    dof = float(np.trace(resid))
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 10:
        return None
    X = np.stack([x[ok], np.full(int(ok.sum()), dof)], axis=1)
    (gain, read_var), *_ = np.linalg.lstsq(X, y[ok], rcond=None)
    return VarianceModel(max(float(gain), 0.0), max(float(read_var), 0.0), "stack residuals")


def std_floor(specular: np.ndarray) -> float:
    """The float-rounding floor of the standard deviations of a specular image (H, W, 3) or (n, 3), radiance:
    :data:`FLOOR` × its largest finite ``|value|`` (× 1 when none is finite)."""
    peak = float(np.nanmax(np.abs(specular))) if np.isfinite(specular).any() else 1.0
    return FLOOR * peak


def specular_variance(capture: Any, specular: np.ndarray, noise: VarianceModel, *,
                      pixels: np.ndarray | None = None) -> np.ndarray:
    """Variance of each pixel and channel of the separated (or given) specular image, radiance².

    Parameters
    ----------
    capture : Capture
        Its stack (when the specular was separated from one), angles and rig.
    specular : ndarray, shape (H, W, 3)
        The specular image the fit uses.
    noise : VarianceModel
    pixels : ndarray of bool, shape (H, W), optional
        Only these pixels (default: all).

    Returns
    -------
    ndarray, shape (H, W, 3), or (n, 3) for the ``n`` pixels asked
        At least :func:`std_floor` squared: ``(FLOOR · peak)²``, ``peak`` the largest ``|specular|``.
    """
    floor = std_floor(specular) ** 2
    where = (slice(None), slice(None)) if pixels is None else np.nonzero(pixels)
    if capture.specular is not None or capture.stack is None:
        return np.maximum(variance(specular[where], noise), floor)
    stack = np.asarray(capture.stack[(slice(None), *where)], dtype=float)  # (K, ..., 3)
    coef = linear_stokes(stack, capture.analyzer_angles_deg)  # (3, ..., 3)
    mu = np.tensordot(analyzer_matrix(capture.analyzer_angles_deg), coef, axes=1)  # (K, ..., 3)
    beta = aolp(coef[1].sum(axis=-1), coef[2].sum(axis=-1))  # one phase per pixel, as the separation's
    w = stokes_weights(capture.analyzer_angles_deg, beta)  # (K, ...)
    var = np.sum(w[..., None] ** 2 * variance(mu, noise), axis=0)
    rig = capture.rig
    gain = specular_gain(rig.analyzer_extinction_ratio, rig.lamp_polarizer_extinction_ratio)
    return np.maximum(var * gain**2, floor)


#: A pixel is left out of the weighted fit when its mean reading over the analyzer angles, smoothed
#: (Gaussian, CENSOR_SMOOTH_PX pixels), is below CENSOR_SIGMAS read-noise deviations in any channel.
CENSOR_SIGMAS = 3.0
CENSOR_SMOOTH_PX = 2.0


def censored_pixels(capture: Any, noise: VarianceModel, surface: np.ndarray, *,
                     judged: np.ndarray | None = None) -> np.ndarray:
    """Surface pixels whose readings the sensor may have clipped at zero: not the separation's to measure.

    A reading is ``max(0, signal + noise)``: where the signal is within a
    few read-noise deviations ``√read_var`` of zero, some readings were
    censored, their mean is biased upwards and the separation built on them
    is biased (downwards where the specular is lit: the crossed-angle
    readings are clipped up, which flattens the sinusoid), while the
    variance model calls those pixels the quietest and would weigh them
    most. Such pixels are those whose mean reading over the analyzer angles
    is below :data:`CENSOR_SIGMAS` ``√read_var`` in any channel; the mean is
    smoothed over ~:data:`CENSOR_SMOOTH_PX` pixels (normalised over the
    surface), so which pixels are judged dark hardly depends on their own
    noise (choosing a pixel because its own draw was low would bias the
    rest). The mean reading, not the
    smallest: a fully polarized specular with no diffuse (a black surface)
    has a reading near zero at the crossed angle across its whole
    highlight, which holds the lamp. (Fitted as separated, they bias the
    lamp: docs/measurements/estimator-choices.md, "Dark pixels".)

    Parameters
    ----------
    capture : Capture
        Its analyzer stack; a capture without one (a given specular image)
        has no readings to judge: nothing is left out.
    noise : VarianceModel
    surface : ndarray of bool, shape (H, W)
    judged : ndarray of bool, shape (H, W), optional
        Only these pixels are judged (default: every surface pixel; the
        fit's ≤ 20 000 pixels, ``full``'s use). The smoothing then runs on
        their bounding box grown by the filter's radius: each judged pixel's
        smoothed mean is a sum over that radius alone, so the numbers are the
        same as over the whole image, bit for bit (a 640×480 board's
        highlight: ~5 ms against ~50 ms).

    Returns
    -------
    ndarray of bool, shape (H, W)
        True on the (judged) surface pixels that are dark.
    """
    if capture.stack is None or capture.specular is not None or not noise.read_var > 0:
        return np.zeros(surface.shape, bool)
    judged = surface if judged is None else surface & judged
    if not judged.any():
        return np.zeros(surface.shape, bool)
    rows, cols = np.nonzero(judged)
    radius = int(_TRUNCATE * CENSOR_SMOOTH_PX + 0.5)  # scipy.ndimage.gaussian_filter's
    box = (slice(max(rows.min() - radius, 0), rows.max() + radius + 1),
           slice(max(cols.min() - radius, 0), cols.max() + radius + 1))
    inside = surface[box]
    reading = np.mean(np.asarray(capture.stack)[(slice(None), *box)], axis=0, dtype=float)  # float64 sums
    mean = np.where(inside[..., None], np.nan_to_num(reading), 0.0)
    sigma = (CENSOR_SMOOTH_PX, CENSOR_SMOOTH_PX, 0)
    weight = ndimage.gaussian_filter(inside.astype(float), CENSOR_SMOOTH_PX, truncate=_TRUNCATE)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = ndimage.gaussian_filter(mean, sigma, truncate=_TRUNCATE) / weight
    low = ~(smooth >= CENSOR_SIGMAS * np.sqrt(noise.read_var))
    out = np.zeros(surface.shape, bool)
    out[box] = judged[box] & any_channel(low)
    return out


#: The Gaussian's reach in standard deviations (scipy.ndimage's default, stated: the crop above depends on it).
_TRUNCATE = 4.0
