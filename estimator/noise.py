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
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from ..physics.polarization import analyzer_matrix

#: Relative floor of the specular's standard deviation, as a fraction of its peak.
FLOOR = 1e-4


class CameraNoise(NamedTuple):
    """``var(L) = gain · μ + read_var`` (radiance units), and where the numbers came from.

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


def camera_noise(capture: Any, *, surface: np.ndarray | None = None) -> CameraNoise | None:
    """The capture's Poisson–Gaussian camera model: stated, else measured from the stack, else None.

    Parameters
    ----------
    capture : Capture
    surface : ndarray of bool, shape (H, W), optional
        Pixels whose residuals measure it (default: the capture's surface).
    """
    sensor = getattr(capture, "sensor", None)
    if sensor is not None:
        sat, well = _sensor_field(sensor, "saturation"), _sensor_field(sensor, "full_well")
        if sat and well:
            gain = sat / well
            read = _sensor_field(sensor, "read_noise") or 0.0
            bits = _sensor_field(sensor, "bits")
            step = sat / (2.0**bits - 1.0) if bits else 0.0
            return CameraNoise(gain, (read * gain) ** 2 + step**2 / 12.0, "sensor")
    if capture.stack is None or len(capture.analyzer_angles_deg) < 4:
        return None
    A = analyzer_matrix(capture.analyzer_angles_deg)
    if np.linalg.matrix_rank(A) < 3:
        return None
    mask = capture.surface_mask if surface is None else surface
    I = np.asarray(capture.stack, dtype=float)[:, mask]  # (K, n, 3)
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
    return CameraNoise(max(float(gain), 0.0), max(float(read_var), 0.0), "stack residuals")


def specular_variance(capture: Any, specular: np.ndarray, noise: CameraNoise) -> np.ndarray:
    """Variance of each pixel and channel of the separated (or given) specular image, radiance².

    Parameters
    ----------
    capture : Capture
        Its stack (when the specular was separated from one), angles and rig.
    specular : ndarray, shape (H, W, 3)
        The specular image the fit uses.
    noise : CameraNoise

    Returns
    -------
    ndarray, shape (H, W, 3)
        At least ``(FLOOR · peak)²``.
    """
    peak = float(np.nanmax(np.abs(specular))) if np.isfinite(specular).any() else 1.0
    floor = (FLOOR * peak) ** 2
    if capture.specular is not None or capture.stack is None:
        var = noise.gain * np.clip(specular, 0.0, None) + noise.read_var
        return np.maximum(var, floor)
    A = analyzer_matrix(capture.analyzer_angles_deg)
    Pinv = np.linalg.pinv(A)  # (3, K): rows S0, S1, S2
    stack = np.asarray(capture.stack, dtype=float)
    coef = np.tensordot(Pinv, stack, axes=1)  # (3, H, W, 3)
    mu = np.tensordot(A, coef, axes=1)  # (K, H, W, 3)
    b, c = coef[1].sum(axis=-1), coef[2].sum(axis=-1)
    norm = np.hypot(b, c)
    safe = norm > 0
    ub = np.where(safe, b / np.where(safe, norm, 1.0), 1.0)
    uc = np.where(safe, c / np.where(safe, norm, 1.0), 0.0)
    w = Pinv[1][:, None, None] * ub + Pinv[2][:, None, None] * uc  # (K, H, W): specular = S1 cos 2β + S2 sin 2β
    var = np.einsum("khw,khwc->hwc", w**2, noise.gain * np.clip(mu, 0.0, None) + noise.read_var)
    rig = capture.rig
    ka = 0.0 if rig.analyzer_extinction_ratio is None else 1.0 / float(rig.analyzer_extinction_ratio)
    kl = 0.0 if rig.lamp_polarizer_extinction_ratio is None else 1.0 / float(rig.lamp_polarizer_extinction_ratio)
    scale = (1.0 + kl) / ((1.0 - ka) * (1.0 - kl))
    return np.maximum(var * scale**2, floor)
