"""Polarization: the analyzer model, the Stokes fit, separation, DoLP/AoLP, the lamp polarizer.

The conventions of ``docs/physics.md``, each written once. Through an ideal
linear analyzer at angle θ (counter-clockwise from the image's rightward
horizontal) a pixel sees

- ``I(θ) = ½ (S0 + S1 cos 2θ + S2 sin 2θ)`` (Stokes form, :func:`analyzer_stack`), or
  in ``ideal`` mode
- ``I(θ) = Id/2 + Is·cos²(θ − β)`` (paper §2.3, :func:`analyzer_stack_ideal`),

the same model: ``S0 = Id + Is``, ``sqrt(S1² + S2²) = Is``, ``β = ½ atan2(S2, S1)``.
So ``Imax − Imin = sqrt(S1² + S2²) = Is`` (specular) and ``2·Imin = S0 − Is =
Id`` (diffuse). Note: polanalyser's ``cvtStokesToDiffuse`` returns Imin, not
2·Imin.

The lamp sits behind an ideal linear polarizer: unpolarized, it passes half
its radiant intensity (:func:`through_polarizer`). Its filter faces a point
(the generator's: ``object.position``), its axis projected into the filter's
plane (:func:`filter_axes`); the light it sends along a ray is polarized along
Korger's effective axis, and a specular (``ideal``) reflection mirrors that
in the microfacet, which sets the angle β in the image
(:func:`specular_aolp`).

Numpy only; imports no pipeline stage.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import UserError

#: Fraction of an unpolarized lamp's radiant intensity an ideal linear polarizer passes.
POLARIZER_TRANSMISSION = 0.5


def through_polarizer(intensity: Any) -> np.ndarray:
    """Radiant intensity reaching the scene from a lamp behind an ideal linear polarizer, W/sr.

    Parameters
    ----------
    intensity : array_like
        The bare lamp's radiant intensity (per channel), W/sr.

    Returns
    -------
    ndarray, same shape
        ``intensity / 2``: the polarizer halves unpolarized light.
    """
    return np.asarray(intensity, dtype=float) / 2.0


# --------------------------------------------------------------------------- the analyzer model


def analyzer_matrix(angles_deg: Any) -> np.ndarray:
    """``[K, 3]`` rows ``½ (1, cos 2θ, sin 2θ)``: maps ``(S0, S1, S2)`` to the K analyzer images."""
    two_theta = 2.0 * np.radians(np.asarray(angles_deg, dtype=float))
    return 0.5 * np.stack([np.ones_like(two_theta), np.cos(two_theta), np.sin(two_theta)], axis=1)


def analyzer_stack(stokes: np.ndarray, angles_deg: Any, *, extinction_ratio: float | None = None) -> np.ndarray:
    """Analyzer images: ideal ``½ (S0 + S1 cos 2θ + S2 sin 2θ)``, or through a real polarizer.

    A real linear polarizer has principal intensity transmittances ``k1 = 1``
    and ``k2 = 1/ε`` (ε its extinction ratio): ``½ [(1 + 1/ε) S0 + (1 − 1/ε)
    (S1 cos 2θ + S2 sin 2θ)]``. On fully polarized light (a mirror) the
    darkest image is then ``1/ε`` of the brightest instead of 0 (Malus's law
    with a floor).

    Parameters
    ----------
    stokes : ndarray, shape (3, H, W, C)
        S0, S1, S2 (radiance; x axis of the Stokes frame = image horizontal).
    angles_deg : array_like, shape (K,)
        Analyzer angles, degrees (each shot its own: they need not be distinct).
    extinction_ratio : float or None, optional
        ε ≥ 1; None: the ideal analyzer (the first formula, exactly).

    Returns
    -------
    ndarray, shape (K, H, W, C)
    """
    t = np.radians(np.asarray(angles_deg, float))[:, None, None, None]
    if extinction_ratio is None:
        return 0.5 * (stokes[0] + stokes[1] * np.cos(2 * t) + stokes[2] * np.sin(2 * t))
    k2 = 1.0 / float(extinction_ratio)
    return 0.5 * ((1.0 + k2) * stokes[0] + (1.0 - k2) * (stokes[1] * np.cos(2 * t) + stokes[2] * np.sin(2 * t)))


def analyzer_stack_ideal(diffuse: np.ndarray, specular: np.ndarray, phase: np.ndarray, angles_deg: Any) -> np.ndarray:
    """Ideal-analyzer images ``Id/2 + Is·cos²(θ − β)`` (paper §2.3, ``ideal`` mode).

    Parameters
    ----------
    diffuse, specular : ndarray, shape (H, W, C)
        Id and Is, radiance.
    phase : ndarray, shape (H, W)
        β, the analyzer angle of maximum specular transmission, radians.
    angles_deg : array_like, shape (K,)
        Analyzer angles θ, degrees.

    Returns
    -------
    ndarray, shape (K, H, W, C), float64
    """
    cos2 = np.cos(np.radians(np.asarray(angles_deg, dtype=float))[:, None, None] - phase[None]) ** 2
    return diffuse[None] / 2.0 + specular[None] * cos2[..., None]


def analyzer_modulation(angles_deg: Any, phase: Any) -> np.ndarray:
    """``½ cos 2(θ − β)``: a polarized part's share in the reading of an ideal analyzer at θ, beyond its mean.

    The same model about the mean reading: ``I(θ) = ½ S0 + Is · ½ cos 2(θ − β)``
    (``= Id/2 + Is·cos²(θ − β)``, :func:`analyzer_stack_ideal`), so a reading is
    its level ``½ S0`` plus ``Is`` times this.

    Parameters
    ----------
    angles_deg : array_like, shape (K,)
        Analyzer angles θ, degrees.
    phase : array_like
        β of each pixel (the analyzer angle of maximum transmission of its polarized part), radians.

    Returns
    -------
    ndarray, shape ``(K, *phase.shape)``
    """
    theta = np.radians(np.asarray(angles_deg, dtype=float)).reshape((-1,) + (1,) * np.ndim(phase))
    return 0.5 * np.cos(2.0 * (theta - phase))


# --------------------------------------------------------------------------- its inversion


def linear_stokes(stack: np.ndarray, angles_deg: Any) -> np.ndarray:
    """Per-pixel least-squares ``S0, S1, S2`` of an analyzer stack: the one Stokes fit.

    Parameters
    ----------
    stack : ndarray, shape (K, ...)
        Radiance through the analyzer at each angle.
    angles_deg : array_like, shape (K,)
        Analyzer angles, degrees; at least 3 distinct (mod 180°).

    Returns
    -------
    ndarray, shape (3, ...)

    Raises
    ------
    UserError
        Fewer than 3 distinct angles (mod 180°): the fit is undetermined.
    """
    A = analyzer_matrix(angles_deg)
    if np.linalg.matrix_rank(A) < 3:
        raise UserError(
            "analyzer_angles_deg: separating polarization needs at least 3 distinct angles (mod 180°), "
            f"got {list(np.asarray(angles_deg).tolist())}"
        )
    stack = np.asarray(stack)
    flat = stack.reshape(len(A), -1)
    fit = np.linalg.pinv(A)
    out = np.empty((3, flat.shape[1]))
    # block by block, each converted to float64 while it is in cache: the same numbers as converting the
    # whole (float32) stack first, in half the time (640×480×3, 8 angles: 8 ms against 16 ms)
    buf = np.empty((len(A), min(STOKES_BLOCK, flat.shape[1])))
    for start in range(0, flat.shape[1], STOKES_BLOCK):
        stop = min(start + STOKES_BLOCK, flat.shape[1])
        block = buf[:, : stop - start]
        block[...] = flat[:, start:stop]
        np.matmul(fit, block, out=out[:, start:stop])
    return out.reshape(3, *stack.shape[1:])


#: Pixel values per block of :func:`linear_stokes` (a multiple of 16, so that the blocks split the
#: product where a matrix kernel's own tiles do).
STOKES_BLOCK = 16384


def linear_amplitude(S1: np.ndarray, S2: np.ndarray) -> np.ndarray:
    """``Imax − Imin = sqrt(S1² + S2²)``: the specular radiance Is in ``ideal`` mode."""
    return np.hypot(S1, S2)


def separate_stokes(S0: np.ndarray, S1: np.ndarray, S2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Specular and diffuse radiance from linear Stokes parameters (paper §2.3).

    Returns
    -------
    specular, diffuse : ndarray
        ``Imax − Imin = sqrt(S1² + S2²)`` and ``2·Imin = S0 − sqrt(S1² + S2²)``.
    """
    amplitude = linear_amplitude(S1, S2)
    return amplitude, S0 - amplitude


def separate_extrema(imax: np.ndarray, imin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Specular and diffuse radiance from the brightest and darkest analyzer images (paper §2.3).

    Returns
    -------
    specular, diffuse : ndarray
        ``Imax − Imin`` and ``2·Imin``.
    """
    return imax - imin, 2.0 * imin


def dolp(S0: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
    """Degree of linear polarization ``sqrt(S1² + S2²) / S0``, dimensionless; 0 where ``S0 ≤ 0``.

    Parameters
    ----------
    S0 : ndarray
        Total radiance.
    amplitude : ndarray, same shape
        ``sqrt(S1² + S2²)`` (:func:`linear_amplitude`).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(S0 > 0, amplitude / S0, 0.0)


def aolp(S1: np.ndarray, S2: np.ndarray) -> np.ndarray:
    """Angle of linear polarization ``½ atan2(S2, S1)``, radians in (−π/2, π/2], from the image horizontal.

    In ``ideal`` mode this is β, the analyzer angle of maximum transmission.
    """
    return 0.5 * np.arctan2(S2, S1)


# --------------------------------------------------------------------------- the lamp's polarizer and β


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1, keepdims=True)


def filter_axes(axis: Any, facing: Any) -> tuple[np.ndarray, np.ndarray]:
    """Transmission and absorbing axes of a lamp's filter, unit vectors in its plane.

    Parameters
    ----------
    axis : array_like, shape (3,)
        The scene's ``lamp.polarizer_axis`` (world).
    facing : array_like, shape (3,)
        The filter's normal: from the lamp towards the point it faces.

    Returns
    -------
    transmit, absorb : ndarray, shape (3,)
        ``transmit`` = ``axis`` projected into the filter's plane; ``absorb`` =
        ``facing × transmit``.
    """
    n = np.asarray(facing, float) / np.linalg.norm(facing)
    t = np.asarray(axis, float) - np.dot(axis, n) * n
    t /= np.linalg.norm(t)
    return t, np.cross(n, t)


def specular_aolp(P: np.ndarray, camera_position: Any, camera_up: Any, lamp: Any, axis: Any, aim: Any) -> np.ndarray:
    """Angle β of the linear polarization of a polarized point lamp's ``ideal`` specular reflection, per pixel.

    The lamp at ``lamp`` sits behind a linear polarizer whose filter faces
    ``aim`` (normal ``aim − lamp``), its axis ``axis`` projected into the
    filter's plane (:func:`filter_axes`). Along the ray ``k = (P − lamp)/|P −
    lamp|`` the light is polarized along Korger's effective axis ``e = k ×
    â⊥``, ``â⊥`` the filter's absorbing axis projected normal to ``k`` (Korger
    et al. 2013; the generator's lamp). An ``ideal`` specular reflection (the
    Mueller matrix ``diag(1, 1, −1, −1)`` in the microfacet's s/p frames: a
    perfect mirror) at the microfacet of normal ``h = (v − k)/|v − k|``
    mirrors the field: ``e_r = e − 2 (e·h) h``, normal to ``v``. β is its
    angle counter-clockwise from the image's rightward horizontal, in the
    analyzer's frame (Mitsuba's Stokes frame of each camera ray: ``x =
    (−v) × up / |…|``, ``y = v × x``). It does not depend on the surface
    normal, only on where the pixel's point is. Measured against renders of
    one lamp (sphere and board, 160×120): within 5e-5° where the specular is
    above a tenth of its peak (``tests/test_polarization_aolp.py``).

    Parameters
    ----------
    P : ndarray, shape (n, 3)
        Surface points (m).
    camera_position : array_like, shape (3,)
    camera_up : array_like, shape (3,)
        The camera's up vector (``to_world``'s second column).
    lamp : array_like, shape (3,)
        Lamp position (m).
    axis : array_like, shape (3,)
        The filter's axis (world; projected into its plane here).
    aim : array_like, shape (3,)
        The point the filter faces (world, m).

    Returns
    -------
    ndarray, shape (n,)
        β, radians (the analyzer angle of maximum transmission, modulo π).
    """
    lamp = np.asarray(lamp, float)
    absorb = filter_axes(axis, np.asarray(aim, float) - lamp)[1]
    k = _unit(P - lamp)
    e = korger_axis(k, absorb)
    v = _unit(np.asarray(camera_position, float) - P)
    h = _unit(v - k)
    e_r = e - 2.0 * _dot(e, h) * h
    x, y = analyzer_frame(v, camera_up)
    return np.arctan2(_dot(e_r, y)[..., 0], _dot(e_r, x)[..., 0])


def korger_axis(k: np.ndarray, absorb: Any) -> np.ndarray:
    """The effective transmission axis of a tilted linear polarizer for light leaving along ``k``: ``k × â⊥``,
    ``â⊥`` the filter's absorbing axis ``absorb`` projected normal to ``k`` (Korger et al. 2013; the generator's
    lamp, :mod:`nearlight.generator.lamp`).

    Parameters
    ----------
    k : ndarray, shape (..., 3)
        Unit propagation directions (lamp → point).
    absorb : array_like, shape (3,)
        The filter's absorbing axis (:func:`filter_axes`).

    Returns
    -------
    ndarray, shape (..., 3)
        Unit vectors normal to ``k``.
    """
    return np.cross(k, _unit(absorb - _dot(absorb, k) * k))


def analyzer_frame(view: np.ndarray, camera_up: Any) -> tuple[np.ndarray, np.ndarray]:
    """The analyzer's Stokes frame of each camera ray, as the generator rotates Mitsuba's Stokes into it.

    Parameters
    ----------
    view : ndarray, shape (..., 3)
        Unit directions from the surface points towards the camera.
    camera_up : array_like, shape (3,)
        The camera's up vector (``to_world``'s second column).

    Returns
    -------
    x, y : ndarray, shape (..., 3)
        ``x = (−v) × up / |…|`` (the image's rightward horizontal), ``y = v × x``: an analyzer angle θ is
        counter-clockwise from ``x``.
    """
    x = _unit(np.cross(-view, np.asarray(camera_up, float)))
    return x, np.cross(view, x)
