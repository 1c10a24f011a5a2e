"""Dark pixels' specular from their clipped readings: a censored (Tobit) likelihood.

A sensor clips at zero. Where a pixel's signal is within a few read-noise
deviations of zero (:func:`~nearlight.estimator.noise.censored_pixels`), some
of its analyzer readings were clipped, and the separated specular built on
them by least squares is biased: downwards on a lit dark pixel, measured (the
crossed-angle readings are clipped up, which flattens the sinusoid), and its
variance under the camera model is wrong. Left out of the fit, they take
their information with them (on the high-noise GGX sphere of
``benchmarks/bench_lobes.py``, 52 % of the pixels and 13 % of the lamp's
Cramér–Rao bound).

This module measures their specular from the readings themselves, as a
censored maximum-likelihood estimate. Reading model (the generator's,
:func:`nearlight.generator.noise.adc_counts`): a latent value
``x_k ~ N(μ_k, g·μ_k⁺ + r²)`` (shot noise of gain ``g``, read noise ``r``, in
radiance), recorded as ``q · round(clip(x_k, 0, sat) / q)`` (ADC step ``q``):
a recorded 0 means ``x_k < q/2`` and has likelihood ``Φ((q/2 − μ_k)/sd_k)``;
any other reading is taken as Gaussian of variance ``g·μ_k⁺ + r² + q²/12``.
The signal is the analyzer model about its mean,
``μ_k = a + s · ½ cos 2(θ_k − β)``
(:func:`~nearlight.physics.polarization.analyzer_modulation`; ``a`` = ½ S0; ``s`` is exactly what the
``projected`` separation calls the specular when β is its phase,
:func:`~nearlight.estimator.separation.specular_phase`).

Two unknowns from four readings fit badly where most are clipped (the
level ``a`` is a nuisance parameter per pixel: the 2-parameter estimate's
spread is 2.2–2.4 read deviations where the 1-parameter one's is 1.6–1.8,
measured on the generator's own readings). So, per dark pixel:

1. the phase β is that of a wider neighbourhood (:data:`DARK_PHASE_WINDOW`, the
   pixel left out) than the separation's 5 × 5: a dark pixel's estimate goes
   as ``s · cos 2δ`` with δ the phase error, and the 5 × 5 phase of faint
   pixels is noisy enough to shrink it (mean normalised error of the dark lit
   pixels of that sphere, 8 seeds: −0.028 with the 5 × 5 phase, −0.003 with
   15 × 15, −0.001 with the true one);
2. the level ``a`` is the mean level of its :data:`LEVEL_WINDOW` neighbours
   (the pixel left out): least squares where they are not dark, the
   2-parameter censored fit (:func:`level_and_specular`) where they are;
3. ``s`` is the 1-parameter censored fit with that level
   (:func:`specular_given_level`), and its variance the inverse of the
   expected information (calibrated: the errors' spread is 0.95–1.01 of it).

Newton steps on the quasi-likelihood (each reading's variance taken at the
current μ and held in the derivatives), from the least-squares values, each
step at most two read deviations. Without a stated sensor
(``capture.sensor``) the camera is the stack residuals' (``read_var`` holds
``r² + q²/12`` together): the step is then taken as 0, and a reading
within a millionth of a read deviation of 0 as clipped.

The neighbours' level is ``a``, not their diffuse level ``Imin = a − s/2``
(``μ_k = Imin + s cos²(θ_k − β)``), which would tie ``s`` to the pixel's mean
reading as well as to its modulation and pass a noisy level on to ``s``;
with ``a`` the modulation alone decides (``Σ_k c_k = 0`` for evenly spaced
angles) and a level's error enters only through the clipping. What this
brings to ``full``'s lamp: docs/measurements/estimator-choices.md, "Dark pixels".
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from scipy.ndimage import uniform_filter
from scipy.special import log_ndtr, ndtr

from ..physics.polarization import analyzer_modulation, linear_stokes
from .noise import VarianceModel
from .separation import neighbourhood_phase, specular_gain

#: Side (pixels) of the neighbourhood whose phase a dark pixel's specular is measured along.
DARK_PHASE_WINDOW = 15
#: Side (pixels) of the neighbourhood whose mean level is a dark pixel's own (the pixel left out).
LEVEL_WINDOW = 5
#: Most Newton steps; a pixel has converged when its last step is below CONVERGED read deviations.
MAX_STEPS = 20
CONVERGED = 1e-4
#: Largest Newton step, read deviations (a trust region: the censored likelihood is far from quadratic).
MAX_STEP = 2.0

_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)


class ReadingModel(NamedTuple):
    """The reading model's numbers, radiance units.

    Attributes
    ----------
    gain : float
        Radiance of one electron.
    latent_var : float
        Variance of the read noise before the ADC, radiance².
    step : float
        ADC step (0: unknown or none; the clipping threshold is then 0).
    """

    gain: float
    latent_var: float
    step: float


def reading_model(capture: Any, noise: VarianceModel) -> ReadingModel:
    """The reading model of ``capture``: its stated sensor's ADC step, else none (see the module docstring)."""
    sensor = getattr(capture, "sensor", None)
    bits, saturation = getattr(sensor, "bits", None), getattr(sensor, "saturation", None)
    if noise.source == "sensor" and bits and saturation:
        step = float(saturation) / (2.0 ** float(bits) - 1.0)
        return ReadingModel(noise.gain, max(noise.read_var - step**2 / 12.0, 0.0), step)
    return ReadingModel(noise.gain, noise.read_var, 0.0)


def _terms(R: np.ndarray, mu: np.ndarray, clipped: np.ndarray, sensor: ReadingModel,
           expected: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per reading: the log-likelihood's derivative in μ and its information (observed, or expected).

    The clipped readings' terms need the normal tail (Mills ratio ``φ(z)/Φ(z)``,
    ``z = (q/2 − μ)/sd``); with ``expected`` every reading's does (its chance
    of being clipped), the score is then 0.
    """
    latent = sensor.gain * np.clip(mu, 0.0, None) + sensor.latent_var
    recorded = latent + sensor.step**2 / 12.0
    if expected:  # E over the reading: the uncensored share's Gaussian information plus the censored share's
        z = (0.5 * sensor.step - mu) / np.sqrt(latent)
        p = ndtr(z)
        return np.zeros_like(mu), (1.0 - p) / recorded + p * _mills(z) * (z + _mills(z)) / latent
    score, info = (R - mu) / recorded, 1.0 / recorded
    if clipped.any():
        sd = np.sqrt(latent[clipped])
        z = (0.5 * sensor.step - mu[clipped]) / sd
        m = _mills(z)
        score[clipped] = -m / sd
        info[clipped] = m * (z + m) / latent[clipped]
    return score, info


def _clipped(R: np.ndarray, sensor: ReadingModel) -> np.ndarray:
    """Readings the ADC recorded as 0: below half its step (an ADC records nothing between 0 and one step),
    or, the step unknown, within a millionth of a read deviation of 0 (a last-bit change of a 0 is still 0)."""
    return R < max(0.5 * sensor.step, 1e-6 * np.sqrt(sensor.latent_var))


def _mills(z: np.ndarray) -> np.ndarray:
    """``φ(z) / Φ(z)``, stable far into the lower tail."""
    return np.exp(-0.5 * z * z - _LOG_SQRT_2PI - log_ndtr(z))


def specular_given_level(R: np.ndarray, c: np.ndarray, level: np.ndarray,
                         sensor: ReadingModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Censored ML of ``s`` in ``μ_k = level + s · c_k`` from readings clipped at zero.

    Parameters
    ----------
    R : ndarray, shape (K, n)
        Readings (radiance; 0 where clipped), ``n`` pixel-channels.
    c : ndarray, shape (K, n)
        ``½ cos 2(θ_k − β)`` of each reading (:func:`~nearlight.physics.polarization.analyzer_modulation`).
    level : ndarray, shape (n,)
        ``a`` of each pixel-channel, radiance.
    sensor : ReadingModel

    Returns
    -------
    s : ndarray, shape (n,)
        Radiance.
    variance : ndarray, shape (n,)
        Inverse expected information of ``s``, radiance².
    converged : ndarray of bool, shape (n,)
    """
    R = np.asarray(R, dtype=float)
    clipped = _clipped(R, sensor)
    s = np.sum(c * (R - level), axis=0) / np.sum(c * c, axis=0)  # least squares
    limit = MAX_STEP * np.sqrt(sensor.latent_var + sensor.step**2 / 12.0)
    tolerance = CONVERGED * limit / MAX_STEP
    active = np.arange(len(s))  # pixel-channels still moving
    for _ in range(MAX_STEPS):
        cc = c[:, active]
        score, info = _terms(R[:, active], level[active] + s[active] * cc, clipped[:, active], sensor)
        step = np.clip(np.sum(score * cc, axis=0) / np.sum(info * cc * cc, axis=0), -limit, limit)
        s[active] += step
        active = active[~(np.abs(step) < tolerance)]
        if not len(active):
            break
    converged = np.isfinite(s)
    converged[active] = False
    _, info = _terms(R, level + s * c, clipped, sensor, expected=True)
    return s, 1.0 / np.sum(info * c * c, axis=0), converged


def level_and_specular(R: np.ndarray, c: np.ndarray, sensor: ReadingModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Censored ML of ``(a, s)`` in ``μ_k = a + s · c_k`` (shapes and units as :func:`specular_given_level`).

    Returns
    -------
    level, s : ndarray, shape (n,)
    converged : ndarray of bool, shape (n,)
    """
    R = np.asarray(R, dtype=float)
    clipped = _clipped(R, sensor)
    K = len(R)
    s11, s12, s22 = float(K), np.sum(c, axis=0), np.sum(c * c, axis=0)
    b1, b2 = np.sum(R, axis=0), np.sum(c * R, axis=0)
    det = s11 * s22 - s12**2
    a, s = (s22 * b1 - s12 * b2) / det, (s11 * b2 - s12 * b1) / det  # least squares
    limit = MAX_STEP * np.sqrt(sensor.latent_var + sensor.step**2 / 12.0)
    tolerance = CONVERGED * limit / MAX_STEP
    # with fewer than two readings above zero the likelihood has no maximum (it grows as a falls)
    active = np.flatnonzero(np.sum(~clipped, axis=0) >= 2)  # pixel-channels still moving
    for _ in range(MAX_STEPS):
        cc = c[:, active]
        score, info = _terms(R[:, active], a[active] + s[active] * cc, clipped[:, active], sensor)
        g1, g2 = np.sum(score, axis=0), np.sum(score * cc, axis=0)
        h11, h12, h22 = np.sum(info, axis=0), np.sum(info * cc, axis=0), np.sum(info * cc * cc, axis=0)
        det = h11 * h22 - h12**2
        da, ds = (h22 * g1 - h12 * g2) / det, (h11 * g2 - h12 * g1) / det
        big = np.maximum(np.abs(da), np.abs(ds))
        shrink = limit / np.maximum(big, limit)
        a[active] += shrink * da
        s[active] += shrink * ds
        active = active[~(big < tolerance)]
        if not len(active):
            break
    converged = np.isfinite(a) & np.isfinite(s) & (np.sum(~clipped, axis=0) >= 2)
    converged[active] = False
    return a, s, converged


class CensoredSpecular(NamedTuple):
    """Dark pixels' specular from their readings (:func:`censored_specular`), in ``dark``'s raster order.

    Attributes
    ----------
    values, variance : ndarray, shape (n, 3)
        Specular (rig-corrected, as the separation's) and its variance.
    ok : ndarray of bool, shape (n,)
        Every channel converged and had a level from its neighbours; other pixels stay out of the fit.
    phase : ndarray, shape (n,)
        The phase β each was measured along, radians (the analyzer angles' frame).
    """

    values: np.ndarray
    variance: np.ndarray
    ok: np.ndarray
    phase: np.ndarray


def censored_specular(capture: Any, noise: VarianceModel, dark: np.ndarray, surface: np.ndarray) -> CensoredSpecular:
    """The specular of the ``dark`` pixels measured from their clipped readings (see the module docstring).

    Parameters
    ----------
    capture : Capture
        Its analyzer stack, angles, rig and (when stated) sensor.
    noise : VarianceModel
        The camera model (:func:`~nearlight.estimator.noise.camera_noise`).
    dark : ndarray of bool, shape (H, W)
        Pixels to measure (:func:`~nearlight.estimator.noise.censored_pixels`).
    surface : ndarray of bool, shape (H, W)
        Pixels whose level may stand for a neighbour's.

    Returns
    -------
    CensoredSpecular
    """
    rows, cols = np.nonzero(dark)
    n = len(rows)
    if n == 0:
        return CensoredSpecular(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool), np.zeros(0))
    sensor = reading_model(capture, noise)
    angles = np.asarray(capture.analyzer_angles_deg, dtype=float)
    radius = max(DARK_PHASE_WINDOW, 2 * LEVEL_WINDOW) // 2 + 1
    box = (slice(max(rows.min() - radius, 0), rows.max() + radius + 1),
           slice(max(cols.min() - radius, 0), cols.max() + radius + 1))
    stack = np.asarray(capture.stack[(slice(None), *box)], dtype=float)  # (K, h, w, 3)
    r, q = rows - box[0].start, cols - box[1].start
    coef = linear_stokes(stack, angles)  # (3, h, w, 3): S0, S1, S2
    ub, uc = neighbourhood_phase(coef[1], coef[2], DARK_PHASE_WINDOW)  # the phase of (S1, S2) is that of (b, c)
    beta = 0.5 * np.arctan2(uc[r, q], ub[r, q])  # (n,)
    K = len(angles)
    R = stack[:, r, q, :].reshape(K, -1)  # (K, n·3)
    c = np.repeat(analyzer_modulation(angles, beta)[..., None], 3, axis=-1).reshape(K, -1)
    # the level of every pixel of the box: least squares, and the dark ones' own censored fit
    level = 0.5 * coef[0]
    a_dark, _, fine = level_and_specular(R, c, sensor)
    level[r, q] = a_dark.reshape(n, 3)
    good = surface[box].copy()
    good[r, q] = fine.reshape(n, 3).all(axis=1)
    level = np.where(good[..., None], np.nan_to_num(level), 0.0)
    size = LEVEL_WINDOW
    total = uniform_filter(level, (size, size, 1), mode="constant") * size**2 - level
    count = np.rint(uniform_filter(good.astype(float), size, mode="constant") * size**2) - good
    around = total[r, q] / np.maximum(count[r, q], 1.0)[:, None]  # (n, 3)
    s, var, converged = specular_given_level(R, c, around.reshape(-1), sensor)
    ok = converged.reshape(n, 3).all(axis=1) & (count[r, q] > 0)
    gain = specular_gain(capture.rig.analyzer_extinction_ratio, capture.rig.lamp_polarizer_extinction_ratio)
    return CensoredSpecular(s.reshape(n, 3) * gain, var.reshape(n, 3) * gain**2, ok, beta)

