"""Cramér–Rao lower bounds: the best any unbiased estimator can do under Gaussian noise.

For observations ``y = f(θ) + ε`` with independent Gaussian ``ε_i`` of
variance ``v_i``, the Fisher information is ``F = Jᵀ diag(1/v) J`` with ``J``
the Jacobian of ``f`` at the true ``θ``, and every unbiased estimator has
covariance ``≥ F⁻¹``. :func:`crlb` computes that bound for any model by central
differences; :func:`specular_crlb` applies it to a capture's specular lobe.

The specular model (what the bound is about): parameters
``θ = (lamp x, y, z [m], colour r, g, b, roughness)``, observations the specular
radiance ``Is`` of every surface pixel and channel, from
:func:`nearlight.physics.reflectance.specular_radiance` with the capture's own
lobe family (Torrance–Sparrow, Ward, GGX or Beckmann) and unit intensity (Ks absorbs the lamp's intensity, as estimators report it).
Is is not observed directly but through the analyzer stack
``y_k = c0 + c1 cos 2θ_k + c2 sin 2θ_k`` with the diffuse offset and the phase
β free per pixel (nuisance parameters the estimators must also fit), so a stack
of K images of per-image variance ``v`` determines Is with variance
``4 v uᵀ C u`` (``C`` the (c1, c2) block of ``(AᵀA)⁻¹``, ``u = (cos 2β, sin 2β)``):
``8 v / K`` for K equally spaced angles. The diffuse image is not used (its
albedo is unknown), normals and positions are taken as exact, and range noise
is not modelled: the bound covers camera noise only.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ...estimator.fitting import central_jacobian
from ...estimator.noise import sensor_noise, stokes_weights, variance
from ...physics.camera import auto_saturation
from ...physics.polarization import aolp, linear_stokes, through_polarizer
from ...physics.reflectance import LOBES, specular_radiance
from .metrics import capture_name, one_lamp_position


def crlb(model: Callable[[np.ndarray], np.ndarray], theta: Any, *, noise_var: Any, steps: Any) -> np.ndarray:
    """Cramér–Rao bound on the covariance of ``theta`` for Gaussian noise.

    Parameters
    ----------
    model, theta, steps
        ``model(theta) -> ndarray`` (any shape, M observations), ``theta`` shape (P,) and
        per-parameter difference steps, as
        :func:`nearlight.estimator.fitting.central_jacobian`.
    noise_var : float or ndarray, shape (M,) or model's output shape
        Variance of each observation's noise, in the model's output units squared.

    Returns
    -------
    ndarray, shape (P, P)
        ``F⁻¹``; all-NaN when the Fisher matrix is singular (a parameter the
        data does not determine).
    """
    J = central_jacobian(model, theta, steps)
    v = np.broadcast_to(np.ravel(np.asarray(noise_var, dtype=float)), (J.shape[0],))
    if np.any(v <= 0):
        raise ValueError("noise_var: every observation needs a positive noise variance")
    fisher = J.T @ (J / v[:, None])
    if not np.all(np.isfinite(fisher)) or np.linalg.cond(fisher) > 1e14:
        return np.full_like(fisher, np.nan)
    return np.linalg.inv(fisher)


def specular_variance_factor(angles_deg: Any, beta: np.ndarray) -> np.ndarray:
    """Variance of Is from an analyzer stack, per unit per-image variance.

    Parameters
    ----------
    angles_deg : array_like, shape (K,)
        Analyzer angles, degrees (K ≥ 3 distinct modulo 180°).
    beta : ndarray, shape (...)
        Phase β of each pixel, radians.

    Returns
    -------
    ndarray, shape (...)
        ``Σ_k w_k²`` of :func:`nearlight.estimator.noise.stokes_weights` (``4 uᵀ C u``
        above): multiply by the per-image noise variance ``v``. Equals ``8 / K``
        for K equally spaced angles.
    """
    return np.sum(np.square(stokes_weights(angles_deg, beta)), axis=0)


def stack_phase(stack: np.ndarray, angles_deg: Any) -> np.ndarray:
    """Phase β (radians) of ``a + b cos 2θ + c sin 2θ`` fitted to a stack (the AoLP), shape ``(H, W, 3)``.

    Parameters
    ----------
    stack : ndarray, shape (K, H, W, 3)
    angles_deg : array_like, shape (K,)
    """
    _, S1, S2 = linear_stokes(stack, angles_deg)
    return aolp(S1, S2)


def camera_noise_variance(stack: np.ndarray, *, noise: Any) -> np.ndarray:
    """Variance of the generator's camera noise at each pixel of a clean stack, radiance².

    The Gaussian approximation of :func:`nearlight.generator.add_camera_noise`:
    with ``g = saturation / full_well`` (radiance per electron), shot noise
    ``g·L``, read noise ``(g·read_noise)²`` and the ADC step ``q = saturation /
    (2^bits − 1)`` as uniform rounding ``q²/12``. Clipping at the full well is
    ignored (the ``auto`` exposure keeps clean pixels at ≤ 90 % of it).

    Parameters
    ----------
    stack : ndarray, shape (K, H, W, 3)
        Clean analyzer stack, radiance.
    noise : mapping or NoiseSpec
        The camera noise settings (``full_well``, ``read_noise``, ``bits``, ``saturation``).

    Returns
    -------
    ndarray, shape (K, H, W, 3)
    """
    from ...generator.scene import NoiseSpec

    if not isinstance(noise, NoiseSpec):
        noise = NoiseSpec.model_validate(dict(noise))
    L = np.nan_to_num(np.asarray(stack, dtype=float))
    saturation = auto_saturation(stack) if noise.saturation == "auto" else float(noise.saturation)
    model = sensor_noise(saturation=saturation, full_well=noise.full_well, read_noise=noise.read_noise, bits=noise.bits)
    return variance(L, model)


def specular_crlb(capture: Any, *, noise_var: np.ndarray, pixels: np.ndarray | None = None) -> dict[str, float]:
    """CRLB of the lamp position and roughness for a capture with an analyzer stack, any lobe family.

    Parameters
    ----------
    capture : Capture
        Noise-free capture with ``stack``, ``N`` and ``truth``, whose BSDF
        model is one of :data:`nearlight.physics.reflectance.LOBES`
        (Torrance–Sparrow, Ward, GGX, Beckmann): the bound is for a fit of
        that same family.
    noise_var : ndarray, shape (K, H, W, 3) or (H, W, 3) or float
        Variance of the camera noise of each analyzer image pixel, radiance
        units squared (the noise model evaluated at the noise-free stack).
    pixels : ndarray of bool, shape (H, W), optional
        The pixels the bound counts (default: every surface pixel with a
        normal): e.g. those a fit keeps, for the bound of an estimator that
        leaves the others out.

    Returns
    -------
    dict
        ``crlb_lamp_m``: ``sqrt(trace)`` of the lamp-position block, metres
        (a lower bound on the RMS lamp position error);
        ``crlb_sigma_rel``: the bound on the roughness's standard deviation
        divided by it (the same for its Torrance–Sparrow σ, a fixed multiple).

    Raises
    ------
    UserError
        A capture with several lamps: the bound is for one lamp's fit.
    """
    mask = capture.object_mask & np.all(np.isfinite(capture.N), axis=-1)
    if pixels is not None:
        mask &= pixels
    P, N = np.asarray(capture.P, float)[mask], np.asarray(capture.N, float)[mask]
    cam = np.asarray(capture.camera.position, float)
    bsdf, lobe, lamp, colour, rough = truth_parameters(capture)
    var_is = specular_variance(capture, mask, noise_var)

    def model(theta: np.ndarray) -> np.ndarray:
        b = {"model": bsdf["model"], lobe.colour_key: theta[3:6], lobe.roughness_key: theta[6]}
        return specular_radiance(P, N, cam, theta[:3], 1.0, b)

    theta = np.concatenate([lamp, colour, [rough]])
    scale = float(np.linalg.norm(lamp - P.mean(axis=0)))
    steps = np.concatenate([np.full(3, 1e-6 * scale), 1e-6 * np.maximum(colour, 1e-12), [1e-6 * rough]])
    return bound_columns(crlb(model, theta, noise_var=var_is, steps=steps), rough)


def truth_parameters(capture: Any) -> tuple[dict, Any, np.ndarray, np.ndarray, float]:
    """The true ``θ`` of a one-lamp capture's bound: ``(bsdf, lobe, lamp, colour, roughness)``.

    ``bsdf`` the truth's, ``lobe`` its :data:`~nearlight.physics.reflectance.LOBES` family,
    ``lamp`` shape (3,) metres, ``colour`` shape (3,) (the lobe's colour times the lamp
    intensity through the polarizer: what a fit with ``I_lamp = 1`` estimates), the roughness.

    Raises
    ------
    UserError
        A capture with several lamps: the bound is for one lamp's fit.
    """
    truth = capture.truth
    bsdf = truth["bsdf"]
    lobe = LOBES[bsdf["model"]]
    lamp = one_lamp_position(truth, where=capture_name(capture), what="the Cramér–Rao bound")
    colour = np.broadcast_to(np.asarray(bsdf[lobe.colour_key], float), (3,)) * through_polarizer(
        truth.get("lamp_intensity", 2.0))
    return bsdf, lobe, lamp, colour, float(bsdf[lobe.roughness_key])


def specular_variance(capture: Any, mask: np.ndarray, noise_var: Any) -> np.ndarray:
    """Variance of the specular radiance the analyzer stack gives each pixel of ``mask``, shape ``(n, 3)``.

    ``noise_var`` as :func:`specular_crlb`'s. Per-image variances of one pixel
    differ only through shot noise; their mean is what the fit sees.
    """
    nv = np.broadcast_to(np.asarray(noise_var, float), capture.stack.shape)
    beta = stack_phase(capture.stack, capture.analyzer_angles_deg)[mask]
    return nv.mean(axis=0)[mask] * specular_variance_factor(capture.analyzer_angles_deg, beta)


def bound_columns(cov: np.ndarray, rough: float) -> dict[str, float]:
    """``crlb_lamp_m`` (``sqrt(trace)`` of the lamp block, metres) and ``crlb_sigma_rel`` (the roughness's s.d.
    over the roughness) of a bound ``cov`` whose ``θ`` starts ``(lamp x, y, z, colour r, g, b, roughness)``."""
    return {
        "crlb_lamp_m": float(np.sqrt(np.trace(cov[:3, :3]))),
        "crlb_sigma_rel": float(np.sqrt(cov[6, 6]) / rough),
    }
