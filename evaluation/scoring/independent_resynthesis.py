"""Grading re-synthesis: the specular image an estimate predicts, written a second time on purpose.

Why a second implementation
---------------------------
A grading oracle must not share code with the thing it grades. The analytic
generator's truth images (:mod:`nearlight.generator.analytic`), the model the
``full`` method fits (:mod:`nearlight.estimator.full`, its lobe families in
:mod:`nearlight.estimator.lobes`) and the estimator's own re-synthesis
(:func:`nearlight.estimator.render_specular`) all come from
:mod:`nearlight.physics.reflectance`. Graded with that same code, a mistake in
it (a lost ``cos θi``, ``1/r`` for ``1/r²``, a lobe with ``σ`` for ``2σ²``, a
Ward lobe's ``√(cos θi cos θr)`` inverted, a Smith term of the wrong
direction) would appear in the truth, in the fit and in the grade alike, and
``specular_rmse`` would still read 0. So this module writes every specular
lobe again from the formulas of ``docs/physics.md`` (and the paper's eq. 6 and
19), with numpy alone: it imports neither :mod:`nearlight.physics.reflectance`
nor the estimator, and is written differently where it can be: α by ``atan2``
of ``|N × h|`` and ``N · h`` instead of ``arccos``; ``tan²α`` as
``|N × h|² / (N · h)²`` and ``sin²θ`` of the Smith terms from cross products
instead of through an angle; each radiance in a reduced form (``Ks / cos θr``,
``ρs √(cos θi / cos θr)``, ``D G / (4 cos θr)``) instead of the BRDF times
``cos θi``; GGX's ``(a² − 1) cos²α + 1`` as ``a² cos²α + sin²α`` and its Smith
term multiplied through by ``cos θ``; Beckmann's Smith term in ``cot θ / a``.
``tests/evaluation/scoring/test_independent_resynthesis.py`` checks that the two agree to float64
rounding on random geometry for every family, and that the true BSDF
reproduces the analytic generator's ``truth_specular`` for every family: a
change to either side that changes the physics shows up as a disagreement
there.

Which lobe is rendered
----------------------
The families of :data:`FAMILIES`, by a BSDF dict's ``model`` (the dicts of
``capture.json``'s ``truth.bsdf``): ``torrance_sparrow`` (``ks``,
``sigma``), ``ward`` (``rho_s``, ``alpha``), ``ggx`` and ``beckmann``
(``ks``, ``alpha``). ``full`` fits one of them and reports that family's own
BSDF dict in ``estimate.stages["full"]["bsdf"]``; its ``estimate.ks`` and
``sigma`` are only the Torrance–Sparrow lobe of the same head-on peak and
small-angle width, which differs from a Ward or microfacet lobe away from the
peak (a Ward fit graded through it misses by far more than its own fit error).
So :func:`resynthesize` renders the fitted family's dict when there is one
(:func:`fitted_bsdf`; a result row's estimate gets it back from its
``est_lobe`` column, :func:`~nearlight.evaluation.engine.run.row_estimate`), and
otherwise, for every other method, the Torrance–Sparrow lobe of
``estimate.ks`` and ``estimate.sigma``, with the same code and numbers as
before the families were added. A dict of
another model is refused (ValueError), never graded as something else.

The models (``docs/physics.md``, "Lamp" and "Reflectance")
----------------------------------------------------------
Every lobe is ``L = (I / r²) · f · cos θi`` where ``cos θi > 0`` and ``cos θr > 0``,
else 0, with α the angle between the normal and the half vector of the
directions to the lamp and to the camera:

* Torrance–Sparrow, paper eq. 6: ``L = (I / r²) · Ks / cos θr · exp(−α² / 2σ²)``;
* Ward, paper eq. 19 (isotropic, RADIANCE ≤ 3.5):
  ``f = ρs exp(−tan²α / a²) / (4π a² √(cos θi cos θr))``;
* GGX and Beckmann microfacet lobes as Mitsuba 3's rough conductor with its
  Fresnel factor a constant colour: ``f = Ks D G1(θi) G1(θr) / (4 cos θi cos θr)``,
  ``D`` normalised as ``∫ D cos α dω = 1`` (GGX
  ``a² / (π ((a² − 1) cos²α + 1)²)``, Beckmann ``exp(−tan²α / a²) / (π a² cos⁴α)``),
  Smith's ``G1`` as Mitsuba computes it: exact for GGX,
  ``2 / (1 + √(1 + a² tan²θ))``, and Walter et al.'s rational approximation
  for Beckmann; ``a`` is Mitsuba's ``alpha``.

An estimate's colour (``ks``, ``rho_s``) already holds the lamp intensity
reaching the surface (``colour · I_lamp / 2`` behind the ideal polarizer,
which halves unpolarized light), so it is rendered with ``I = 1``:

* near (``light_model["type"] == "point"``): a point lamp at
  ``lamp_position``, ``r`` and the direction to it per surface point, the view
  direction per point towards the camera position (perspective);
* distant (``"distant"``, the baseline the paper argues against): one light
  direction ``l`` and one view direction ``v`` for every pixel, the
  irradiance folded into the colour, so ``L = colour · f · cos θi`` with
  ``cos θi = N · l``, ``cos θr = N · v`` (Torrance–Sparrow:
  ``Ks / cos θr · exp(−α² / 2σ²)``); its ``lamp_position`` plays no part.

Defined behaviour at the edges (tested), for every family:

* a non-finite estimate (NaN or ±inf in ``lamp_position``, the colour, the
  roughness or a distant estimate's directions): every surface pixel is NaN,
  so every error computed from the image is NaN, never a finite number;
* a roughness of 0: Torrance–Sparrow's lobe has a limit, 1 where α = 0
  exactly and 0 elsewhere; Ward's and the microfacet lobes, normalised, tend
  to a delta with no image: every surface pixel NaN, as a non-finite
  estimate. Every lobe depends on the square of its roughness (Beckmann's
  Smith term on its magnitude), so ``-σ`` renders as ``σ`` and ``-a`` as ``a``;
* a lamp exactly on a surface point: that pixel has no direction to the lamp
  and is NaN;
* pixels without a surface (non-finite ``P`` or ``N``) are 0.

Lengths in metres, angles in radians, radiance in the units of the colour.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: ``light_model["type"]`` values this module renders.
LIGHT_MODELS = ("point", "distant")

#: Specular families this module renders, by a BSDF dict's ``model``: its colour key and its roughness key
#: (the keys of ``capture.json``'s ``truth.bsdf`` and of ``full``'s ``stages["full"]["bsdf"]``).
FAMILIES: dict[str, tuple[str, str]] = {
    "torrance_sparrow": ("ks", "sigma"),
    "ward": ("rho_s", "alpha"),
    "ggx": ("ks", "alpha"),
    "beckmann": ("ks", "alpha"),
}


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
    return _near(P, N, camera_position, lamp_position, lambda l, v: _lobe_radiance(N, l, v, ks_, float(sigma)))


def _near(P: np.ndarray, N: np.ndarray, camera_position: Any, lamp_position: Any, lobe: Any) -> np.ndarray:
    """``lobe(l, v) / r²``: a unit-intensity near lamp's radiance from the lobe of unit directions ``(..., 3)``.

    The one home of the near-lamp geometry of :func:`ts_specular_near` and
    :func:`specular_near` (inputs already checked finite).
    """
    d = np.asarray(lamp_position, dtype=float).reshape(3) - P
    r2 = np.sum(d * d, axis=-1)
    to_light = _unit(d)
    to_view = _unit(np.asarray(camera_position, dtype=float).reshape(3) - P)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return lobe(to_light, to_view) / r2[..., None]


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


def _sin2(N: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``|N × w|²``: sin² of the angle between unit vectors (from the cross product, exact near 0)."""
    c = np.cross(N, w)
    return np.sum(c * c, axis=-1)


def _smith_ggx(cos_t: np.ndarray, sin2_t: np.ndarray, a2: float) -> np.ndarray:
    """GGX's exact Smith masking ``2 / (1 + √(1 + a² tan²θ))``, multiplied through by ``cos θ > 0``."""
    return 2.0 * cos_t / (cos_t + np.sqrt(cos_t * cos_t + a2 * sin2_t))


def _smith_beckmann(cos_t: np.ndarray, sin2_t: np.ndarray, a: float) -> np.ndarray:
    """Beckmann's Smith masking as Mitsuba 3 evaluates it: Walter et al.'s (2007) rational approximation in
    ``b = cot θ / a``, ``(3.535 b + 2.181 b²) / (1 + 2.276 b + 2.577 b²)`` for ``b < 1.6``, else 1."""
    b = cos_t / (abs(a) * np.sqrt(sin2_t))
    return np.where(b < 1.6, b * (3.535 + 2.181 * b) / (1.0 + b * (2.276 + 2.577 * b)), 1.0)


def _normalised_lobe_radiance(model: str, N: np.ndarray, to_light: np.ndarray, to_view: np.ndarray,
                              colour: np.ndarray, a: float) -> np.ndarray:
    """``colour · f · cos θi`` of Ward, GGX or Beckmann where lit, else 0: the radiance of a unit lamp at unit
    distance; unit vectors ``(..., 3)``, ``a > 0`` finite; returns ``(..., 3)``.

    With ``τ = tan²α = |N × h|² / (N · h)²`` (no angle is formed):

    * Ward (eq. 19): ``ρs √(cos θi / cos θr) exp(−τ / a²) / (4π a²)``;
    * microfacet: ``Ks D G1(θi) G1(θr) / (4 cos θr)``, GGX ``D = a² / (π (a² cos²α + sin²α)²)``,
      Beckmann ``D = exp(−τ / a²) / (π a² cos⁴α)``.
    """
    cos_i = np.sum(N * to_light, axis=-1)
    cos_r = np.sum(N * to_view, axis=-1)
    h = _unit(to_light + to_view)
    cos_h = np.sum(N * h, axis=-1)  # > 0 wherever lit: N · (l + v) = cos θi + cos θr
    sin2_h = _sin2(N, h)
    a2 = a * a
    lit = (cos_i > 0) & (cos_r > 0)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore", under="ignore"):
        tau_a2 = sin2_h / (a2 * cos_h * cos_h)  # tan²α / a²
        if model == "ward":
            value = np.sqrt(cos_i / cos_r) * np.exp(-tau_a2) / (4.0 * np.pi * a2)
        else:
            if model == "ggx":
                d = a2 / (np.pi * np.square(a2 * cos_h * cos_h + sin2_h))
                g = _smith_ggx(cos_i, _sin2(N, to_light), a2) * _smith_ggx(cos_r, _sin2(N, to_view), a2)
            else:  # beckmann
                d = np.exp(-tau_a2) / (np.pi * a2 * np.square(cos_h * cos_h))
                g = _smith_beckmann(cos_i, _sin2(N, to_light), a) * _smith_beckmann(cos_r, _sin2(N, to_view), a)
            value = d * g / (4.0 * cos_r)
        radiance = np.where(lit, value, 0.0)
    # as _lobe_radiance: no direction to the lamp (it sits on the point) stays NaN
    radiance = np.where(np.isnan(cos_i) | np.isnan(cos_r), np.nan, radiance)
    return radiance[..., None] * colour


def bsdf_parameters(bsdf: Any) -> tuple[str, np.ndarray, float]:
    """``(model, colour (3,), roughness)`` of a BSDF dict of one of :data:`FAMILIES`, float64.

    Raises
    ------
    ValueError
        ``bsdf`` is not a mapping, its ``model`` is not one of :data:`FAMILIES`, or it lacks the
        model's colour or roughness key.
    """
    model = bsdf.get("model") if hasattr(bsdf, "get") else None
    if model not in FAMILIES:
        raise ValueError(f"estimate bsdf model: expected one of {', '.join(FAMILIES)}, got {model!r}")
    colour_key, roughness_key = FAMILIES[model]
    missing = [k for k in (colour_key, roughness_key) if k not in bsdf]
    if missing:
        raise ValueError(f"estimate bsdf of model {model!r} lacks {' and '.join(map(repr, missing))}")
    colour = np.broadcast_to(np.asarray(bsdf[colour_key], dtype=float), (3,))
    return model, colour, float(np.asarray(bsdf[roughness_key], dtype=float))


def _renderable(model: str, colour: np.ndarray, roughness: float, *geometry: Any) -> bool:
    """Finite parameters, and a roughness that is not 0 for a normalised lobe (a delta there: no image)."""
    return _finite(colour, roughness, *geometry) and (model == "torrance_sparrow" or roughness != 0.0)


def specular_near(P: np.ndarray, N: np.ndarray, camera_position: Any, lamp_position: Any, bsdf: Any) -> np.ndarray:
    """Specular radiance of a near point lamp of unit intensity, perspective view, for any of :data:`FAMILIES`.

    ``L = (1 / r²) · colour · f · cos θi`` where the lamp and the camera are
    above the surface, else 0; ``torrance_sparrow`` is :func:`ts_specular_near`.

    Parameters
    ----------
    P, N, camera_position, lamp_position
        As :func:`ts_specular_near`.
    bsdf : mapping
        A BSDF dict (``model`` in :data:`FAMILIES`, its colour and roughness
        keys); the colour holds the lamp intensity reaching the surface.

    Returns
    -------
    ndarray, shape (..., 3)
        Radiance, float64; all NaN when ``lamp_position`` or the BSDF's
        numbers are not finite, or a normalised lobe's roughness is 0; NaN at
        a point the lamp sits on.

    Raises
    ------
    ValueError
        As :func:`bsdf_parameters`.
    """
    model, colour, a = bsdf_parameters(bsdf)
    if model == "torrance_sparrow":
        return ts_specular_near(P, N, camera_position, lamp_position, colour, a)
    P, N = np.asarray(P, dtype=float), np.asarray(N, dtype=float)
    if not _renderable(model, colour, a, lamp_position):
        return np.full((*P.shape[:-1], 3), np.nan)
    return _near(P, N, camera_position, lamp_position,
                 lambda l, v: _normalised_lobe_radiance(model, N, l, v, colour, a))


def specular_distant(N: np.ndarray, light_direction: Any, view_direction: Any, bsdf: Any) -> np.ndarray:
    """Specular radiance under a distant light and a distant viewer, for any of :data:`FAMILIES`.

    ``L = colour · f · cos θi`` with ``cos θi = N · l``, ``cos θr = N · v``;
    the irradiance is folded into the colour; ``torrance_sparrow`` is
    :func:`ts_specular_distant`. Returns and raises as :func:`specular_near`.
    """
    model, colour, a = bsdf_parameters(bsdf)
    if model == "torrance_sparrow":
        return ts_specular_distant(N, light_direction, view_direction, colour, a)
    N = np.asarray(N, dtype=float)
    if not _renderable(model, colour, a, light_direction, view_direction):
        return np.full((*N.shape[:-1], 3), np.nan)
    light = np.broadcast_to(_unit(np.asarray(light_direction, dtype=float).reshape(3)), N.shape)
    view = np.broadcast_to(_unit(np.asarray(view_direction, dtype=float).reshape(3)), N.shape)
    return _normalised_lobe_radiance(model, N, light, view, colour, a)


def fitted_stage(estimate: Any) -> dict[str, Any]:
    """``full``'s stage of ``estimate`` (``estimate.stages["full"]``), or ``{}`` when it has none.

    The one reader of what ``full`` fitted (``lobe``, ``bsdf``, ``lamps_option``)
    for grading and for result rows (:func:`~nearlight.evaluation.scoring.metrics.estimate_columns`).
    """
    stage = (getattr(estimate, "stages", None) or {}).get("full")
    return stage if isinstance(stage, dict) else {}


def fitted_bsdf(estimate: Any) -> Any:
    """The BSDF dict of the lobe family ``full`` fitted (``estimate.stages["full"]["bsdf"]``), or None.

    Any other estimate (every other method) has none and is rendered from
    its Torrance–Sparrow ``ks`` and ``sigma``.
    """
    return fitted_stage(estimate).get("bsdf")


def resynthesize(capture: Any, estimate: Any) -> np.ndarray:
    """The specular image ``estimate`` predicts on the geometry of ``capture``, for grading.

    Parameters
    ----------
    capture : Capture
        Its ``P`` (metres, NaN off the surface), ``N`` (unit normals; renormalised
        here, as they are stored in float32) and ``camera.position``.
    estimate : Estimate
        ``lamp_position`` (metres), ``light_model``: ``{"type": "point"}`` or
        ``{"type": "distant", "light_direction": l, "view_direction": v}``, and
        the lobe: the BSDF dict of the family ``full`` fitted,
        ``stages["full"]["bsdf"]``, when there is one (:func:`fitted_bsdf`),
        else the Torrance–Sparrow ``ks`` (3,) and ``sigma`` (radians).

    Returns
    -------
    ndarray, shape (H, W, 3)
        Specular radiance, float64: 0 where there is no surface (non-finite
        ``P`` or ``N``) or the lamp or camera is below it; NaN on every
        surface pixel when the estimate is not finite.

    Raises
    ------
    ValueError
        The capture has no normals, the estimate's ``light_model["type"]``
        is not one of :data:`LIGHT_MODELS`, or its fitted BSDF dict's
        ``model`` is not one of :data:`FAMILIES` (or lacks its keys).
    """
    if capture.N is None:
        raise ValueError("grading needs the capture's normals N (the noise-free capture has them)")
    kind = estimate.light_model.get("type", "point")
    if kind not in LIGHT_MODELS:
        raise ValueError(f"estimate light_model.type: expected one of {', '.join(LIGHT_MODELS)}, got {kind!r}")
    bsdf = fitted_bsdf(estimate)
    if bsdf is not None:
        bsdf_parameters(bsdf)  # refuse an unknown model before anything is rendered
    P = np.asarray(capture.P, dtype=float)
    N = _unit(np.asarray(capture.N, dtype=float))
    surface = np.all(np.isfinite(P), axis=-1) & np.all(np.isfinite(N), axis=-1)
    out = np.zeros((*P.shape[:-1], 3))
    lm = estimate.light_model
    if bsdf is None:  # the Torrance–Sparrow path every method but ``full`` takes, unchanged
        if kind == "point":
            out[surface] = ts_specular_near(P[surface], N[surface], capture.camera.position, estimate.lamp_position,
                                            estimate.ks, estimate.sigma)  # fmt: skip
        else:
            out[surface] = ts_specular_distant(N[surface], lm["light_direction"], lm["view_direction"],
                                               estimate.ks, estimate.sigma)  # fmt: skip
    elif kind == "point":
        out[surface] = specular_near(P[surface], N[surface], capture.camera.position, estimate.lamp_position, bsdf)
    else:
        out[surface] = specular_distant(N[surface], lm["light_direction"], lm["view_direction"], bsdf)
    return out
