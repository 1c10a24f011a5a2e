"""Grading re-synthesis: the specular image an estimate predicts, written a second time on purpose.

Why a second implementation
---------------------------
A grading oracle must not share code with the thing it grades. The analytic
generator's truth images (:mod:`nearlight.generator.analytic`), the model the
``full`` method fits (:mod:`nearlight.estimator.full`) and the estimator's own
re-synthesis (:func:`nearlight.estimator.render_specular`) all come from
:mod:`nearlight.physics.reflectance`. Graded with that same code, a mistake in
it (a lost ``cos θi``, ``1/r`` for ``1/r²``, a lobe with ``σ`` for ``2σ²``)
would appear in the truth, in the fit and in the grade alike, and
``specular_rmse`` would still read 0. So this module writes the
Torrance–Sparrow image again from the formula of ``docs/physics.md``, with
numpy alone: it imports neither :mod:`nearlight.physics.reflectance` nor the
estimator, and is written differently where it can be (α by ``atan2`` of
``|N × h|`` and ``N · h`` instead of ``arccos``; the radiance in its reduced
form ``Ks / cos θr`` instead of the BRDF times ``cos θi``).
``tests/test_evaluation_resynthesis.py`` checks that the two agree to float64
rounding on random geometry, and that the truth estimate reproduces the
analytic generator's ``truth_specular``: a change to either side that changes
the physics shows up as a disagreement there.

The model (``docs/physics.md``, "Lamp" and "Reflectance")
---------------------------------------------------------
Paper eq. 6, the reflected radiance of the simplified Torrance–Sparrow lobe::

    L = (I / r²) · Ks / cos θr · exp(−α² / 2σ²)    where cos θi > 0 and cos θr > 0, else 0

with α the angle between the normal and the half vector of the directions to
the lamp and to the camera. An estimate's ``ks`` already holds the lamp
intensity reaching the surface (``ks · I_lamp / 2`` behind the ideal
polarizer, which halves unpolarized light), so it is rendered with ``I = 1``:

* near (``light_model["type"] == "point"``): a point lamp at
  ``lamp_position``, ``r`` and the direction to it per surface point, the view
  direction per point towards the camera position (perspective);
* distant (``"distant"``, the baseline the paper argues against): one light
  direction ``l`` and one view direction ``v`` for every pixel, the
  irradiance folded into Ks, so ``L = Ks / cos θr · exp(−α² / 2σ²)`` with
  ``cos θr = N · v``; its ``lamp_position`` plays no part.

Defined behaviour at the edges (tested):

* a non-finite estimate (NaN or ±inf in ``lamp_position``, ``ks``, ``sigma``
  or a distant estimate's directions): every surface pixel is NaN, so every
  error computed from the image is NaN, never a finite number;
* ``sigma == 0`` (a mirror): the lobe's limit, 1 where α = 0 exactly and 0
  elsewhere; the lobe depends on σ² only, so ``-σ`` renders as ``σ``;
* a lamp exactly on a surface point: that pixel has no direction to the lamp
  and is NaN;
* pixels without a surface (non-finite ``P`` or ``N``) are 0.

Lengths in metres, angles in radians, radiance in the units of ``ks``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: ``light_model["type"]`` values this module renders.
LIGHT_MODELS = ("point", "distant")


def _unit(v: np.ndarray) -> np.ndarray:
    """``v / |v|`` along the last axis (zero vectors give NaN, silently)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.sqrt(np.sum(v * v, axis=-1, keepdims=True))


def _lobe_radiance(N: np.ndarray, to_light: np.ndarray, to_view: np.ndarray, ks: np.ndarray, sigma: float) -> np.ndarray:
    """``Ks / cos θr · exp(−α² / 2σ²)`` where lit, else 0; unit vectors ``(..., 3)``, returns ``(..., 3)``."""
    cos_i = np.sum(N * to_light, axis=-1)
    cos_r = np.sum(N * to_view, axis=-1)
    h = _unit(to_light + to_view)
    alpha = np.arctan2(np.linalg.norm(np.cross(N, h), axis=-1), np.sum(N * h, axis=-1))
    two_var = 2.0 * sigma * sigma
    lit = (cos_i > 0) & (cos_r > 0)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore", under="ignore"):
        if two_var > 0:
            lobe = np.exp(-(alpha * alpha) / two_var)
        else:  # the σ → 0 limit: a mirror
            lobe = np.where(alpha == 0, 1.0, 0.0)
        radiance = np.where(lit, lobe / cos_r, 0.0)
    # No direction to the lamp (it sits on the point) is not "unlit": keep it NaN. (α is NaN only where
    # the light and view directions are opposite, and such a point is unlit.)
    radiance = np.where(np.isnan(cos_i) | np.isnan(cos_r), np.nan, radiance)
    return radiance[..., None] * ks


def _finite(*values: Any) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(v, dtype=float)))) for v in values)


def ts_specular_near(
    P: np.ndarray, N: np.ndarray, camera_position: Any, lamp_position: Any, ks: Any, sigma: float
) -> np.ndarray:
    """Torrance–Sparrow specular radiance of a near point lamp of unit intensity, perspective view.

    ``L = Ks / (r² cos θr) · exp(−α² / 2σ²)`` where the lamp and the camera
    are above the surface, else 0 (no shadowing).

    Parameters
    ----------
    P : ndarray, shape (..., 3)
        Surface points, metres (finite).
    N : ndarray, shape (..., 3)
        Unit normals at ``P``.
    camera_position, lamp_position : array_like, shape (3,)
        Centre of projection and lamp, metres.
    ks : array_like, shape (3,) or scalar
        Ks per channel, holding the lamp intensity reaching the surface.
    sigma : float
        Roughness, radians.

    Returns
    -------
    ndarray, shape (..., 3)
        Radiance, float64; all NaN when ``lamp_position``, ``ks`` or ``sigma``
        is not finite; NaN at a point the lamp sits on.
    """
    P, N = np.asarray(P, dtype=float), np.asarray(N, dtype=float)
    ks_ = np.broadcast_to(np.asarray(ks, dtype=float), (3,))
    if not _finite(lamp_position, ks_, sigma):
        return np.full((*P.shape[:-1], 3), np.nan)
    d = np.asarray(lamp_position, dtype=float).reshape(3) - P
    r2 = np.sum(d * d, axis=-1)
    to_light = _unit(d)
    to_view = _unit(np.asarray(camera_position, dtype=float).reshape(3) - P)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return _lobe_radiance(N, to_light, to_view, ks_, float(sigma)) / r2[..., None]


def ts_specular_distant(N: np.ndarray, light_direction: Any, view_direction: Any, ks: Any, sigma: float) -> np.ndarray:
    """Torrance–Sparrow specular radiance under a distant light and a distant viewer.

    ``L = Ks / cos θr · exp(−α² / 2σ²)`` with ``cos θr = N · v`` and α from
    the one half vector of ``l`` and ``v``; the irradiance is folded into Ks.

    Parameters
    ----------
    N : ndarray, shape (..., 3)
        Unit normals.
    light_direction, view_direction : array_like, shape (3,)
        Directions towards the light and the viewer (normalised here).
    ks : array_like, shape (3,) or scalar
        Ks per channel, holding the irradiance.
    sigma : float
        Roughness, radians.

    Returns
    -------
    ndarray, shape (..., 3)
        Radiance, float64; all NaN when a direction, ``ks`` or ``sigma`` is not finite.
    """
    N = np.asarray(N, dtype=float)
    ks_ = np.broadcast_to(np.asarray(ks, dtype=float), (3,))
    if not _finite(light_direction, view_direction, ks_, sigma):
        return np.full((*N.shape[:-1], 3), np.nan)
    light = np.broadcast_to(_unit(np.asarray(light_direction, dtype=float).reshape(3)), N.shape)
    view = np.broadcast_to(_unit(np.asarray(view_direction, dtype=float).reshape(3)), N.shape)
    return _lobe_radiance(N, light, view, ks_, float(sigma))


def resynthesize(capture: Any, estimate: Any) -> np.ndarray:
    """The specular image ``estimate`` predicts on the geometry of ``capture``, for grading.

    Parameters
    ----------
    capture : Capture
        Its ``P`` (metres, NaN off the surface), ``N`` (unit normals; renormalised
        here, as they are stored in float32) and ``camera.position``.
    estimate : Estimate
        ``lamp_position`` (metres), ``ks`` (3,), ``sigma`` (radians) and
        ``light_model``: ``{"type": "point"}`` or ``{"type": "distant",
        "light_direction": l, "view_direction": v}``.

    Returns
    -------
    ndarray, shape (H, W, 3)
        Specular radiance, float64: 0 where there is no surface (non-finite
        ``P`` or ``N``) or the lamp or camera is below it; NaN on every
        surface pixel when the estimate is not finite.

    Raises
    ------
    ValueError
        The capture has no normals, or the estimate's ``light_model["type"]``
        is not one of :data:`LIGHT_MODELS`.
    """
    if capture.N is None:
        raise ValueError("grading needs the capture's normals N (the noise-free capture has them)")
    kind = estimate.light_model.get("type", "point")
    if kind not in LIGHT_MODELS:
        raise ValueError(f"estimate light_model.type: expected one of {', '.join(LIGHT_MODELS)}, got {kind!r}")
    P = np.asarray(capture.P, dtype=float)
    N = _unit(np.asarray(capture.N, dtype=float))
    surface = np.all(np.isfinite(P), axis=-1) & np.all(np.isfinite(N), axis=-1)
    out = np.zeros((*P.shape[:-1], 3))
    if kind == "point":
        out[surface] = ts_specular_near(P[surface], N[surface], capture.camera.position, estimate.lamp_position,
                                        estimate.ks, estimate.sigma)  # fmt: skip
    else:
        lm = estimate.light_model
        out[surface] = ts_specular_distant(N[surface], lm["light_direction"], lm["view_direction"],
                                           estimate.ks, estimate.sigma)  # fmt: skip
    return out
