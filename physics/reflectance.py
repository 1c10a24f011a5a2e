"""Closed-form reflection models and shading geometry (numpy only).

One implementation of the reflectance conventions of ``docs/physics.md``, used
by every stage: the analytic generator (closed-form captures), the generator's
tests (rendered radiance against the closed form), the estimator (its forward
model) and the evaluation (Cramér–Rao bounds, the highlight point). Grading
does not re-render an estimate with it: :mod:`nearlight.evaluation.scoring.independent_resynthesis`
is a deliberate second implementation, tested against this one.
Lengths in metres, angles in radians. Numpy only; imports no pipeline stage.

BSDF parameter dicts are those of ``capture.json``'s ``truth.bsdf``:
``{"model": "torrance_sparrow", "ks": [r, g, b], "sigma": s}``,
``{"model": "ward", "rho_s": [r, g, b], "alpha": a}``, or a microfacet lobe
``{"model": "ggx" | "beckmann", "ks": [r, g, b], "alpha": a}``.

Every specular model is a colour times a dimensionless *shape*,
``f = k · shape(cos θi, cos θr, α; roughness)``: :func:`brdf_shape` is that
shape by model name (:data:`LOBES` lists the models, their colour and
roughness keys and their Torrance–Sparrow-equivalent width), and the
colour-valued functions below multiply it out.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import numpy as np


def normalize(v: np.ndarray, axis: int = -1) -> np.ndarray:
    """Unit vectors along ``axis``; zero vectors give NaN."""
    v = np.asarray(v, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / _length(v, axis=axis, keepdims=True)


def _length(v: np.ndarray, axis: int = -1, keepdims: bool = False) -> np.ndarray:
    """Euclidean length of float vectors along ``axis``: ``np.linalg.norm``'s own arithmetic without its overhead."""
    if axis in (-1, v.ndim - 1) and v.shape[-1] == 3:
        squares = _dot(v, v)
        return np.sqrt(squares[..., None] if keepdims else squares)
    return np.sqrt(np.add.reduce(v * v, axis=axis, keepdims=keepdims))


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.sum(a * b, axis=-1)`` of 3-vectors, shape ``[...]``, bit for bit, without a reduction's overhead.

    NumPy sums a last axis of length 3 left to right, ``(a₀b₀ + a₁b₁) + a₂b₂``,
    which this spells out: the same float64 numbers in a few times less time
    on a few hundred vectors (a fit's model, called hundreds of times).
    """
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def channel_sum(v: np.ndarray) -> np.ndarray:
    """``np.sum(v, axis=-1)`` of a ``[..., 3]`` array, shape ``[...]``, bit for bit (see :func:`_dot`).

    A reduction over so short an axis costs several times two additions
    (640×480×3: ~6 ms against ~1 ms); ``channel_sum(v) / 3`` is likewise
    ``np.mean(v, axis=-1)`` (which divides the sum by the count).
    """
    return v[..., 0] + v[..., 1] + v[..., 2]


def every_channel(v: np.ndarray) -> np.ndarray:
    """``np.all(v, axis=-1)``: pixels where every channel of ``v`` is true.

    Parameters
    ----------
    v : ndarray of bool, shape (..., C)
        Usually ``C = 3`` (R, G, B), spelled out as two ``&``: a reduction
        over so short an axis costs several times as much (640×480: ~8×).

    Returns
    -------
    ndarray of bool, shape (...)
    """
    if v.shape[-1:] != (3,):
        return np.all(v, axis=-1)
    return v[..., 0] & v[..., 1] & v[..., 2]


def any_channel(v: np.ndarray) -> np.ndarray:
    """``np.any(v, axis=-1)``: pixels where some channel of ``v`` is true.

    Parameters
    ----------
    v : ndarray of bool, shape (..., C)
        Usually ``C = 3`` (R, G, B), spelled out as two ``|`` (see :func:`every_channel`).

    Returns
    -------
    ndarray of bool, shape (...)
    """
    if v.shape[-1:] != (3,):
        return np.any(v, axis=-1)
    return v[..., 0] | v[..., 1] | v[..., 2]


def finite(x: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(x)``: NaN to 0, ±inf to the largest float; ``x`` itself when all finite (no copy).

    The same numbers as ``nan_to_num`` for a float array, at the cost of one
    ``isfinite`` pass when there is nothing to replace (a fit's model, called
    hundreds of times per capture). Callers must not write into the result.
    """
    return x if np.isfinite(x).all() else np.nan_to_num(x)


def tangent_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``a, b`` with ``(a, b, d)`` orthonormal, for a unit vector ``d`` of shape (3,)."""
    d = np.asarray(d, dtype=float)
    a = normalize(np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0]))
    return a, np.cross(d, a)


class Geometry(NamedTuple):
    """Per-point shading geometry, arrays of shape ``[...]`` (vectors ``[..., 3]``).

    Attributes
    ----------
    view : unit vector from the surface point to the camera.
    light : unit vector from the surface point to the lamp.
    r : distance from the surface point to the lamp, metres.
    cos_r : cos θr, normal · view.
    cos_i : cos θi, normal · light.
    alpha : α, angle between the normal and the half vector, radians.
    """

    view: np.ndarray
    light: np.ndarray
    r: np.ndarray
    cos_r: np.ndarray
    cos_i: np.ndarray
    alpha: np.ndarray


def shading_geometry(P: np.ndarray, N: np.ndarray, camera_position: np.ndarray, lamp_position: np.ndarray, *,
                     view: np.ndarray | None = None) -> Geometry:
    """Angles and distances for a near point lamp and a perspective camera.

    Parameters
    ----------
    P : ndarray, shape (..., 3)
        Surface points, metres.
    N : ndarray, shape (..., 3)
        Unit normals at ``P``.
    camera_position, lamp_position : ndarray, shape (3,) or broadcastable to P
        Centre of projection and lamp position, metres.
    view : ndarray, shape (..., 3), optional
        ``normalize(camera_position − P)`` when the caller has it already (a
        fit that moves only the lamp); the same numbers either way.

    Returns
    -------
    Geometry
    """
    P = np.asarray(P, dtype=float)
    N = np.asarray(N, dtype=float)
    to_light = np.asarray(lamp_position, dtype=float) - P
    r = _length(to_light)
    light = to_light / r[..., None]
    view = normalize(np.asarray(camera_position, dtype=float) - P) if view is None else view
    half = normalize(light + view)
    cos_r = _dot(N, view)
    cos_i = _dot(N, light)
    alpha = np.arccos(np.clip(_dot(N, half), -1.0, 1.0))
    return Geometry(view, light, r, cos_r, cos_i, alpha)


def torrance_sparrow_lobe(alpha: np.ndarray, sigma: Any) -> np.ndarray:
    """The Gaussian facet lobe of the paper's Torrance–Sparrow model, ``exp(−α² / 2σ²)``, dimensionless.

    Parameters
    ----------
    alpha : ndarray
        Angle between the normal and the half vector, radians.
    sigma : float
        Roughness, radians.
    """
    return np.exp(-np.square(alpha) / (2.0 * sigma**2))


def _ts_shape(cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, sigma: float) -> np.ndarray:
    return torrance_sparrow_lobe(alpha, sigma) / (cos_i * cos_r)


def _ward_shape(cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, alpha_w: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.exp(-np.square(np.tan(alpha)) / alpha_w**2) / (4.0 * np.pi * alpha_w**2 * np.sqrt(cos_i * cos_r))


def beckmann_distribution(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    """Beckmann microfacet distribution ``D = exp(−tan²θh / α²) / (π α² cos⁴θh)``, 1/sr.

    Normalised as ``∫ D cos θh dω = 1``; ``α`` is the RMS facet slope
    (Mitsuba's ``alpha``).

    Parameters
    ----------
    cos_h : ndarray
        Cosine of the angle between the normal and the half vector.
    alpha : float
        Roughness (RMS slope), dimensionless.
    """
    c2 = np.square(cos_h)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return np.exp(-(1.0 - c2) / (c2 * alpha**2)) / (np.pi * alpha**2 * c2 * c2)


def ggx_distribution(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    """GGX (Trowbridge–Reitz) distribution ``D = α² / (π ((α² − 1) cos²θh + 1)²)``, 1/sr.

    The same as ``α² / (π cos⁴θh (α² + tan²θh)²)``; normalised as
    :func:`beckmann_distribution`.
    """
    return alpha**2 / (np.pi * np.square((alpha**2 - 1.0) * np.square(cos_h) + 1.0))


def smith_g1(cos_t: np.ndarray, alpha: float, distribution: str) -> np.ndarray:
    """Smith's masking of one direction at polar cosine ``cos_t``, dimensionless, as Mitsuba 3 computes it.

    GGX: ``2 / (1 + √(1 + α² tan²θ))`` (exact). Beckmann: Walter et al.'s
    (2007) rational approximation in ``a = 1 / (α tanθ)``,
    ``(3.535 a + 2.181 a²) / (1 + 2.276 a + 2.577 a²)`` below ``a = 1.6``
    and 1 above (within 0.35 % of the exact Smith term), which is what
    Mitsuba 3's ``MicrofacetDistribution.smith_g1`` evaluates.
    """
    c2 = np.square(cos_t)
    with np.errstate(invalid="ignore", divide="ignore"):
        tan2 = np.clip(1.0 - c2, 0.0, None) / c2
        if distribution == "ggx":
            return 2.0 / (1.0 + np.sqrt(1.0 + alpha**2 * tan2))
        a = 1.0 / (alpha * np.sqrt(tan2))
        return np.where(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a))


def _microfacet_shape(distribution: str) -> Callable[..., np.ndarray]:
    ndf = {"ggx": ggx_distribution, "beckmann": beckmann_distribution}[distribution]

    def shape(cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, roughness: float) -> np.ndarray:
        g = smith_g1(cos_i, roughness, distribution) * smith_g1(cos_r, roughness, distribution)
        return ndf(np.cos(alpha), roughness) * g / (4.0 * cos_i * cos_r)

    return shape


class Lobe(NamedTuple):
    """One specular model: ``f = colour · shape(cos θi, cos θr, α, roughness)``.

    Attributes
    ----------
    shape : callable
        ``shape(cos_i, cos_r, alpha, roughness) -> ndarray`` (1/sr per unit
        colour), arrays of one shape; ``alpha`` is the half-vector angle.
    colour_key, roughness_key : str
        Keys of the model's BSDF dict.
    ts_sigma_per_roughness : float
        Torrance–Sparrow σ (radians) with this lobe's width at small angles,
        per unit of its roughness: the peak curvature of ``exp(−α²/2σ²)``
        matched to ``exp(−tan²α/a²)`` (Ward, Beckmann: ``1/√2``) or
        ``(1 + tan²α/a²)⁻²`` (GGX: ``1/2``) as ``a → 0``.
    """

    shape: Callable[..., np.ndarray]
    colour_key: str
    roughness_key: str
    ts_sigma_per_roughness: float


#: Specular models by the ``model`` name used in scene files, ``truth.bsdf`` and the estimator's ``lobe``.
LOBES: dict[str, Lobe] = {
    "torrance_sparrow": Lobe(_ts_shape, "ks", "sigma", 1.0),
    "ward": Lobe(_ward_shape, "rho_s", "alpha", 1.0 / math.sqrt(2.0)),
    "beckmann": Lobe(_microfacet_shape("beckmann"), "ks", "alpha", 1.0 / math.sqrt(2.0)),
    "ggx": Lobe(_microfacet_shape("ggx"), "ks", "alpha", 0.5),
}


def _lobe(model: str) -> Lobe:
    try:
        return LOBES[model]
    except KeyError:
        raise ValueError(f"no closed form for specular model {model!r} (expected one of {', '.join(LOBES)})") from None


def brdf_shape(model: str, cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, roughness: float) -> np.ndarray:
    """The specular BRDF of ``model`` per unit colour, 1/sr, shape of ``cos_i``.

    Parameters
    ----------
    model : str
        A key of :data:`LOBES`.
    cos_i, cos_r, alpha : ndarray, shape (...)
        Cosines of incidence and reflection; half-vector angle (radians).
    roughness : float
        The model's roughness (its :attr:`Lobe.roughness_key`).
    """
    return _lobe(model).shape(cos_i, cos_r, alpha, roughness)


def ts_sigma(model: str, roughness: float) -> float:
    """Torrance–Sparrow σ (radians) with the small-angle width of ``model``'s lobe at ``roughness``."""
    return _lobe(model).ts_sigma_per_roughness * roughness


def roughness_for_ts_sigma(model: str, sigma: float) -> float:
    """``model``'s roughness whose lobe has the small-angle width of Torrance–Sparrow ``sigma``: the inverse of :func:`ts_sigma`."""
    return sigma / _lobe(model).ts_sigma_per_roughness


#: Mitsuba 3's isotropic microfacet BSDF plug-ins: each takes ``distribution`` (default ``beckmann``) and a
#: roughness ``alpha`` (default 0.1), or ``alpha_u``/``alpha_v`` (anisotropic).
MITSUBA_MICROFACETS = ("roughconductor", "roughdielectric", "roughplastic", "pplastic")


def mitsuba_ts_sigma(bsdf: Mapping[str, Any]) -> float | None:
    """Torrance–Sparrow σ (radians) of a Mitsuba microfacet BSDF dict, by :func:`ts_sigma` of its distribution.

    Beckmann ``alpha / √2``, GGX ``alpha / 2`` (:data:`LOBES`); Mitsuba's
    defaults fill a missing ``distribution`` (Beckmann) or ``alpha`` (0.1).
    ``pplastic``'s lobe is its distribution's: measured (Mitsuba 3.9.1), its
    specular lobe is the Beckmann conductor's to 0.2 %
    (:mod:`nearlight.rendercompare.lobes`).

    Parameters
    ----------
    bsdf : mapping
        A Mitsuba BSDF dict (``{"type": "pplastic", "alpha": 0.14, ...}``).

    Returns
    -------
    float or None
        None when it is not one of :data:`MITSUBA_MICROFACETS`, is
        anisotropic (``alpha_u``/``alpha_v``), has an ``alpha`` that is not
        a number (a texture dict) or another distribution.
    """
    if bsdf.get("type") not in MITSUBA_MICROFACETS or "alpha_u" in bsdf or "alpha_v" in bsdf:
        return None
    distribution, alpha = bsdf.get("distribution", "beckmann"), bsdf.get("alpha", 0.1)
    if distribution not in ("beckmann", "ggx") or not isinstance(alpha, numbers.Real) or isinstance(alpha, bool):
        return None
    return ts_sigma(distribution, float(alpha))


def peak_shape(model: str, roughness: float) -> float:
    """The shape at normal incidence and reflection (``cos θi = cos θr = 1``, α = 0), 1/sr.

    Torrance–Sparrow: 1; Ward, GGX, Beckmann: ``1 / (4π a²)``. A lobe's colour
    times this is the Torrance–Sparrow Ks with the same peak radiance head-on.
    """
    one = np.ones(1)
    return float(brdf_shape(model, one, one, np.zeros(1), roughness)[0])


def convert_bsdf(bsdf: Mapping[str, Any], model: str) -> dict[str, Any]:
    """The BSDF dict of another lobe family with the same small-angle width and head-on peak.

    Roughness by :func:`ts_sigma` and :func:`roughness_for_ts_sigma`, colour by
    :func:`peak_shape` (Torrance–Sparrow → Ward: ``alpha = √2 σ``, ``rho_s =
    4π alpha² ks``); keys that are neither (``kd``, ``polarization``...) are kept.

    Raises
    ------
    ValueError
        Either model without a closed form (not in :data:`LOBES`).
    """
    old, new = _lobe(bsdf.get("model", "torrance_sparrow")), _lobe(model)
    rough = float(bsdf[old.roughness_key])
    out = {k: v for k, v in bsdf.items() if k not in (old.colour_key, old.roughness_key)}
    new_rough = roughness_for_ts_sigma(model, ts_sigma(bsdf.get("model", "torrance_sparrow"), rough))
    colour = np.asarray(bsdf[old.colour_key], dtype=float) * peak_shape(bsdf.get("model", "torrance_sparrow"), rough)
    out.update(model=model, **{new.colour_key: (colour / peak_shape(model, new_rough)).tolist(),
                               new.roughness_key: new_rough})
    return out


def torrance_sparrow(cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, *, ks: Any, sigma: float) -> np.ndarray:
    """Simplified Torrance–Sparrow BRDF of the paper (eq. 6), 1/sr.

    ``f = Ks exp(-α² / 2σ²) / (cos θi cos θr)``, so that the reflected radiance
    is ``(I / r²) Ks / cos θr · exp(-α² / 2σ²)``.

    Parameters
    ----------
    cos_i, cos_r, alpha : ndarray, shape (...)
    ks : array_like, shape (3,) or scalar
    sigma : float
        Roughness, the standard deviation of the microfacet slope angle, radians.

    Returns
    -------
    ndarray, shape (..., 3)
    """
    return _ts_shape(cos_i, cos_r, alpha, sigma)[..., None] * np.broadcast_to(np.asarray(ks, dtype=float), (3,))


def ward(cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, *, rho_s: Any, alpha_w: float) -> np.ndarray:
    """Isotropic Ward BRDF as in RADIANCE (paper eq. 19), 1/sr.

    ``f = ρs exp(-tan²α / σ'²) / (4π σ'² sqrt(cos θi cos θr))``.

    Parameters
    ----------
    cos_i, cos_r, alpha : ndarray, shape (...)
    rho_s : array_like, shape (3,) or scalar
        Specular reflectance.
    alpha_w : float
        Ward roughness σ' (the ``alpha`` key of a ``ward`` BSDF dict).

    Returns
    -------
    ndarray, shape (..., 3)
    """
    return _ward_shape(cos_i, cos_r, alpha, alpha_w)[..., None] * np.broadcast_to(np.asarray(rho_s, dtype=float), (3,))


def microfacet(cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, *, ks: Any, roughness: float,
               distribution: str) -> np.ndarray:
    """Microfacet BRDF ``f = Ks D(h) G1(i) G1(o) / (4 cos θi cos θr)``, 1/sr, constant Fresnel (in Ks).

    ``D`` is :func:`ggx_distribution` or :func:`beckmann_distribution` and
    ``G1`` Smith's (:func:`smith_g1`), as in Mitsuba 3's rough conductor with
    its Fresnel factor taken as a constant colour.

    Parameters
    ----------
    cos_i, cos_r, alpha : ndarray, shape (...)
    ks : array_like, shape (3,) or scalar
    roughness : float
        Mitsuba's ``alpha``.
    distribution : {"ggx", "beckmann"}

    Returns
    -------
    ndarray, shape (..., 3)
    """
    shape = brdf_shape(distribution, cos_i, cos_r, alpha, roughness)
    return shape[..., None] * np.broadcast_to(np.asarray(ks, dtype=float), (3,))


def ward_alpha_from_ts(sigma: float) -> float:
    """Ward roughness with the lobe width of Torrance–Sparrow ``sigma``: ``α = √2·σ``, radians.

    ``exp(−tan²α/α_w²) ≈ exp(−α²/2σ²)`` for small α.
    """
    return roughness_for_ts_sigma("ward", sigma)


def ts_sigma_from_ward(alpha_w: float) -> float:
    """Torrance–Sparrow σ with the lobe width of Ward roughness ``alpha_w``: ``σ = α/√2``, radians."""
    return ts_sigma("ward", alpha_w)


def ward_from_torrance_sparrow(sigma: float, ks: np.ndarray) -> tuple[float, np.ndarray]:
    """Ward ``(alpha, rho_s)`` with a Torrance–Sparrow lobe's width and peak (:func:`convert_bsdf`).

    ``alpha = √2·σ`` (:func:`ward_alpha_from_ts`) and ``rho_s = 4π alpha² ks``
    (equal peak radiance at normal incidence).
    """
    out = convert_bsdf({"model": "torrance_sparrow", "ks": ks, "sigma": sigma}, "ward")
    return out["alpha"], np.asarray(out["rho_s"])


def torrance_sparrow_from_ward(alpha_w: float, rho_s: np.ndarray) -> tuple[float, np.ndarray]:
    """Torrance–Sparrow ``(sigma, ks)`` with a Ward lobe's width and peak: the inverse of
    :func:`ward_from_torrance_sparrow`."""
    out = convert_bsdf({"model": "ward", "rho_s": rho_s, "alpha": alpha_w}, "torrance_sparrow")
    return out["sigma"], np.asarray(out["ks"])


def specular_brdf(g: Geometry, bsdf: Mapping[str, Any]) -> np.ndarray:
    """The specular BRDF of a BSDF dict at ``g``, 1/sr, shape ``(..., 3)``.

    Raises
    ------
    ValueError
        A ``model`` with no closed form here (not in :data:`LOBES`).
    """
    lobe = _lobe(bsdf.get("model"))
    shape = lobe.shape(g.cos_i, g.cos_r, g.alpha, float(bsdf[lobe.roughness_key]))
    return shape[..., None] * np.broadcast_to(np.asarray(bsdf[lobe.colour_key], dtype=float), (3,))


def specular_radiance(
    P: np.ndarray,
    N: np.ndarray,
    camera_position: np.ndarray,
    lamp_position: np.ndarray,
    intensity: Any,
    bsdf: Mapping[str, Any],
) -> np.ndarray:
    """Specular radiance reflected towards the camera by a point lamp.

    ``L = (I / r²) · f · cos θi``, zero where the lamp or the camera is below
    the surface. No shadowing or inter-reflection.

    Parameters
    ----------
    P, N : ndarray, shape (..., 3)
        Surface points (metres) and unit normals.
    camera_position, lamp_position : ndarray, shape (3,)
    intensity : array_like, shape (3,) or scalar
        Radiant intensity of the lamp reaching the surface, W/sr per channel
        (half the lamp's own intensity behind an ideal polarizer).
    bsdf : mapping
        A BSDF dict with a ``model`` key in :data:`LOBES`.

    Returns
    -------
    ndarray, shape (..., 3)
    """
    g = shading_geometry(P, N, camera_position, lamp_position)
    f = specular_brdf(g, bsdf)
    return _irradiance(g, intensity) * np.where(_lit(g), f, 0.0)


def diffuse_radiance(
    P: np.ndarray,
    N: np.ndarray,
    camera_position: np.ndarray,
    lamp_position: np.ndarray,
    intensity: Any,
    kd: Any,
) -> np.ndarray:
    """Lambertian radiance ``(I / r²) · kd / π · cos θi``, shape ``(..., 3)``.

    Parameters as :func:`specular_radiance`; ``kd`` is the diffuse albedo, shape (3,).
    """
    g = shading_geometry(P, N, camera_position, lamp_position)
    f = np.broadcast_to(np.asarray(kd, dtype=float) / np.pi, (*g.r.shape, 3))
    return _irradiance(g, intensity) * np.where(_lit(g), f, 0.0)


def _lit(g: Geometry) -> np.ndarray:
    return ((g.cos_i > 0) & (g.cos_r > 0))[..., None]


def _irradiance(g: Geometry, intensity: Any) -> np.ndarray:
    """``I cos θi / r²`` per channel, shape ``(..., 3)``."""
    return (np.clip(g.cos_i, 0.0, None) / np.square(g.r))[..., None] * np.asarray(intensity, dtype=float)


def mirror_direction(N: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Direction of the mirror reflection of ``V`` about ``N`` (paper eq. 8).

    ``L_p = 2 (N·V) N − V`` for unit ``N`` and ``V`` (the paper writes it as
    ``N + (N, V) N − V``, which equals it only when ``N·V = 1``; we use the
    exact mirror so that θi = θr holds).

    Parameters
    ----------
    N, V : ndarray, shape (..., 3)
        Unit normal and unit vector towards the viewer.

    Returns
    -------
    ndarray, shape (..., 3)
        Unit vectors.
    """
    N = np.asarray(N, dtype=float)
    V = np.asarray(V, dtype=float)
    return normalize(2.0 * np.sum(N * V, axis=-1, keepdims=True) * N - V)
