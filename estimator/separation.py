"""Separation of the specular and diffuse components (paper §2.3).

Through an ideal analyzer at angle θ a pixel sees
``I(θ) = Id/2 + Is·cos²(θ − β) = a + b cos 2θ + c sin 2θ`` with
``a = (Id + Is)/2`` and ``sqrt(b² + c²) = Is/2``. So ``Imax = a + Is/2`` and
``Imin = Id/2``: specular = Imax − Imin, diffuse = 2·Imin (``docs/physics.md``; the
formulas are :mod:`nearlight.physics.polarization`'s).

A calibrated rig's extinction ratios (``capture.rig``) undo what a real
analyzer and a leaky lamp polarizer do to this model, exactly
(:func:`rig_correction`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter

from ..errors import UserError
from ..physics.polarization import linear_stokes, separate_extrema, separate_stokes
from ..physics.reflectance import channel_sum


#: Side (pixels) of the neighbourhood whose phase the ``projected`` separation takes the amplitude along.
PHASE_WINDOW = 5


def _maxmin(stack: np.ndarray, angles_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's Imax − Imin over the sampled angles.

    Exact only when the samples include β and β + 90°; otherwise it
    under-estimates Is by ``Is·sin²(δ)``, δ the distance from β to the nearest
    sample (≤ half the angular step).
    """
    if len(np.unique(np.mod(angles_deg, 180.0))) < 2:
        raise UserError("analyzer_angles_deg: maxmin separation needs at least 2 distinct angles (mod 180°)")
    return separate_extrema(stack.max(axis=0).astype(float), stack.min(axis=0).astype(float))


def _coefficients(stack: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """``[3, H, W, 3]``: per-pixel least-squares ``a, b, c`` of ``a + b cos 2θ + c sin 2θ`` (= ½ S0, S1, S2)."""
    coef = linear_stokes(stack, angles_deg)
    coef *= 0.5
    return coef


def _fit(stack: np.ndarray, angles_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares Stokes fit per pixel (every angle, ≥ 3); specular ``sqrt(S1² + S2²) = Is``.

    The amplitude of noisy coefficients is biased upwards (Rician): where Is
    is small against the noise, specular comes out positive on average.
    """
    return separate_stokes(*linear_stokes(stack, angles_deg))


def _projected(stack: np.ndarray, angles_deg: np.ndarray, *, size: int = PHASE_WINDOW) -> tuple[np.ndarray, np.ndarray]:
    """Fit per pixel, then project ``(b, c)`` on the phase of its neighbourhood.

    The phase 2β comes from the sum of ``(b, c)`` over the ``size × size``
    neighbourhood and the three channels, leaving the pixel itself out, so it
    is independent of the pixel's own noise: specular ``= 2 (b, c)·(cos 2β̂,
    sin 2β̂)`` is then unbiased under zero-mean noise (and may be negative).
    Exact on noise-free stacks where β is constant over the neighbourhood;
    a smooth β that turns by δ across it costs a factor ≈ cos 2δ.
    """
    a, b, c = _coefficients(stack, angles_deg)
    ub, uc = neighbourhood_phase(b, c, size)
    ub, uc = ub[..., None], uc[..., None]
    # in place, the same numbers: b ← b·ub + c·uc (half the amplitude), a ← 2 (a − half), b ← 2 half
    b *= ub
    c *= uc
    b += c
    a -= b
    a *= 2.0
    b *= 2.0
    return b, a


def neighbourhood_phase(b: np.ndarray, c: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``(cos 2β̂, sin 2β̂)``, shape (H, W) each: the phase of ``(b, c)`` summed over the ``size × size``
    neighbourhood and the three channels, the pixel itself left out (``(1, 0)`` where that sum is 0)."""
    bs, cs = channel_sum(b), channel_sum(c)
    nb = uniform_filter(bs, size, mode="constant") * size**2 - bs
    nc = uniform_filter(cs, size, mode="constant") * size**2 - cs
    norm = np.hypot(nb, nc)
    safe = norm > 0
    return (np.divide(nb, norm, out=np.ones_like(norm), where=safe),
            np.divide(nc, norm, out=np.zeros_like(norm), where=safe))


def specular_phase(capture: Any, *, method: str = "fit") -> np.ndarray | None:
    """The polarization angle β̂ (H, W) that ``method``'s specular amplitude is measured along, or None.

    ``projected`` takes the amplitude along its neighbourhood's phase
    (:func:`_projected`), ``fit`` along the pixel's own (the phase of the
    channels' summed ``(b, c)``); the specular of several lamps polarized at
    angles ``β_k`` is then ``Σ_k Is_k cos 2(β_k − β̂)`` (exact for
    ``projected``, noise-free for ``fit``), not ``Σ_k Is_k``. ``maxmin`` and
    a capture without a stack measure no phase: None. Radians, in the
    analyzer angles' frame (counter-clockwise from the image's rightward
    horizontal); the rig's extinction ratios scale ``(b, c)`` and leave it.
    """
    if capture.stack is None or method not in ("fit", "projected"):
        return None
    _, b, c = _coefficients(capture.stack, np.asarray(capture.analyzer_angles_deg, float))
    if method == "projected":
        ub, uc = neighbourhood_phase(b, c, PHASE_WINDOW)
        return 0.5 * np.arctan2(uc, ub)
    return 0.5 * np.arctan2(channel_sum(c), channel_sum(b))


#: Separation methods by name.
SEPARATION_METHODS: dict[str, Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]] = {
    "fit": _fit,
    "projected": _projected,
    "maxmin": _maxmin,
}


def rig_correction(specular: np.ndarray, diffuse: np.ndarray, *, analyzer_extinction_ratio: float | None = None,
                   lamp_extinction_ratio: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Specular and diffuse radiance of an ideal analyzer's separation, corrected for a real rig.

    Analyzer (extinction ratio ε_a, ``k_a = 1/ε_a``): the recorded images are
    ``½ [(1 + k_a) S0 + (1 − k_a)(S1 cos 2θ + S2 sin 2θ)]``
    (:func:`nearlight.physics.polarization.analyzer_stack`), i.e. the ideal
    analyzer's images of ``S' = ((1 + k_a) S0, (1 − k_a) S1, (1 − k_a) S2)``.
    Every separation method reads them as the ideal model of S', so it returns
    ``specular' = (1 − k_a) √(S1² + S2²)`` and ``specular' + diffuse' = S0'
    = (1 + k_a) S0``; dividing undoes it exactly (noise-free), from any
    set of angles.

    Lamp polarizer (ε_l, ``k_l = 1/ε_l``): unpolarized light leaves it with
    ``I/2 · (1 + k_l)`` and DoLP ``(1 − k_l)/(1 + k_l)`` (``docs/physics.md``).
    The specular lobe in the paper's ``ideal`` mode (a non-depolarizing
    mirror) keeps that DoLP, and the diffuse lobe depolarizes fully, so the
    polarized amplitude the separation measures is ``(1 − k_l)/(1 + k_l)``
    of the specular radiance, the rest of which lands in ``diffuse``. The
    correction scales the amplitude by ``(1 + k_l)/(1 − k_l)`` and moves the
    same amount out of the diffuse: both are then exact, and the specular is
    the radiance of the intensity that really reaches the surface,
    ``I/2 · (1 + k_l)``, which Ks absorbs (``docs/physics.md``). A closed-form
    scale only in ``ideal`` mode: a Fresnel reflection polarizes the leaked
    light by an amount that depends on the geometry, which no scale undoes.

    Parameters
    ----------
    specular, diffuse : ndarray, shape (H, W, 3)
        What :func:`separate`'s method returned for the ideal model.
    analyzer_extinction_ratio, lamp_extinction_ratio : float or None
        ε ≥ 1 (``capture.rig``); None: ideal, no correction (the input is
        returned as it is).

    Returns
    -------
    specular, diffuse : ndarray, shape (H, W, 3)

    Raises
    ------
    UserError
        An extinction ratio of 1 (or below): that filter does not polarize,
        so the stack holds no specular signal to separate.
    """
    ratios = {"analyzer_extinction_ratio": analyzer_extinction_ratio,
              "lamp_polarizer_extinction_ratio": lamp_extinction_ratio}
    for name, e in ratios.items():
        if e is not None and not float(e) > 1.0:
            raise UserError(f"rig.{name} = {e}: that polarizer does not polarize (ε must exceed 1), "
                            "so there is no specular to separate")
    if analyzer_extinction_ratio is None and lamp_extinction_ratio is None:
        return specular, diffuse
    ka = 0.0 if analyzer_extinction_ratio is None else 1.0 / float(analyzer_extinction_ratio)
    S0 = (specular + diffuse) / (1.0 + ka)
    specular = specular * specular_gain(analyzer_extinction_ratio, lamp_extinction_ratio)
    return specular, S0 - specular


def specular_gain(analyzer_extinction_ratio: float | None, lamp_extinction_ratio: float | None) -> float:
    """The factor :func:`rig_correction` multiplies the specular by: ``(1 + k_l) / ((1 − k_a)(1 − k_l))``, ``k = 1/ε``.

    1 for an ideal rig (both None).
    """
    ka, kl = (0.0 if e is None else 1.0 / float(e) for e in (analyzer_extinction_ratio, lamp_extinction_ratio))
    return (1.0 + kl) / ((1.0 - ka) * (1.0 - kl))


def separate(stack: np.ndarray, angles_deg: np.ndarray, *, method: str = "fit",
             analyzer_extinction_ratio: float | None = None,
             lamp_extinction_ratio: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Specular and diffuse images from an analyzer stack.

    Parameters
    ----------
    stack : ndarray, shape (K, H, W, 3)
        Radiance through the analyzer at each angle.
    angles_deg : ndarray, shape (K,)
        Analyzer angles, degrees (only their differences matter).
    method : {"fit", "projected", "maxmin"}, optional
        ``"fit"`` (default): per-pixel least squares of
        ``a + b cos 2θ + c sin 2θ`` over every angle, exact from 3 distinct
        angles up for noise-free data, biased upwards under noise where the
        specular is faint. ``"projected"``: the same fit with the amplitude
        taken along the neighbourhood's phase, unbiased under noise (see
        :func:`_projected`). ``"maxmin"``: the paper's max − min over the
        samples, exact only when the samples hit the extrema (dense stacks).
    analyzer_extinction_ratio, lamp_extinction_ratio : float or None, optional
        The rig's extinction ratios (``capture.rig``; None: ideal, the
        default): the result is corrected for them (:func:`rig_correction`).

    Returns
    -------
    specular, diffuse : ndarray, shape (H, W, 3)
        ``Imax − Imin`` and ``2·Imin`` of the ideal rig (the specular and
        diffuse radiance), float64.
    """
    try:
        fn = SEPARATION_METHODS[method]
    except KeyError:
        raise UserError(f"separation: expected one of {', '.join(SEPARATION_METHODS)}, got {method!r}") from None
    stack = np.asarray(stack)  # float64 as it is fitted (linear_stokes), or at the end (maxmin)
    angles_deg = np.asarray(angles_deg, dtype=float)
    if stack.ndim != 4 or stack.shape[0] != angles_deg.shape[0]:
        raise UserError(
            f"analyzer stack: shape {stack.shape} does not match {angles_deg.shape[0]} analyzer angles "
            "(expected K x H x W x 3)"
        )
    specular, diffuse = fn(stack, angles_deg)
    return rig_correction(specular, diffuse, analyzer_extinction_ratio=analyzer_extinction_ratio,
                          lamp_extinction_ratio=lamp_extinction_ratio)


def separate_capture(capture: Any, *, method: str = "fit") -> tuple[np.ndarray, np.ndarray]:
    """:func:`separate` of a capture's analyzer stack with the extinction ratios its ``rig`` states.

    Parameters
    ----------
    capture : Capture
        With ``stack``, ``analyzer_angles_deg`` and ``rig``.
    method : {"fit", "projected", "maxmin"}, optional

    Returns
    -------
    specular, diffuse : ndarray, shape (H, W, 3)
    """
    rig = capture.rig
    return separate(capture.stack, capture.analyzer_angles_deg, method=method,
                    analyzer_extinction_ratio=rig.analyzer_extinction_ratio,
                    lamp_extinction_ratio=rig.lamp_polarizer_extinction_ratio)  # fmt: skip
