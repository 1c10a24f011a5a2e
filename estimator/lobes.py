"""The lobe families ``full`` fits, with the partial derivatives its Jacobian needs.

A family is one of :data:`nearlight.physics.reflectance.LOBES`
(Torrance–Sparrow eq. 6, Ward eq. 19, the GGX and Beckmann microfacet lobes).
Its value comes from there (one home for each formula); this module adds
what only a fit needs: the derivatives of the radiance per unit colour

    F(c, cos θi, cos θr; a) = shape(cos θi, cos θr, α; a) · cos θi,    c = cos α,

with respect to ``c``, ``cos θi`` and the roughness ``a``, as
log-derivatives (``∂ ln F / ∂ ·``), written out per family below and checked
against finite differences of the physics module's shape in
``tests/estimator/test_lobes.py``. ``cos θr`` does not depend on the lamp,
so no derivative in it is needed. ``c`` rather than α is the variable
because every family is smooth in it at the mirror direction (α = 0), where
``∂α/∂L`` is not.

Derivatives per family (``τ = tan²α = (1 − c²)/c²``, ``∂τ/∂c = −2/c³``):

* Torrance–Sparrow, ``F = exp(−α²/2σ²) / cos θr``: ``∂ ln F/∂c = α / (σ² sin α)``
  (→ ``1/σ²`` at α = 0), ``∂ ln F/∂ cos θi = 0``, ``∂ ln F/∂σ = α²/σ³``;
* Ward, ``F = √(cos θi / cos θr) exp(−τ/a²) / (4π a²)``: ``2 / (a² c³)``,
  ``1 / (2 cos θi)``, ``2τ/a³ − 2/a``;
* microfacet, ``F = D(c) G1(cos θi) G1(cos θr) / (4 cos θr)``: ``∂ ln D`` plus
  the Smith terms' ``∂ ln G1``; Beckmann ``ln D = −τ/a² − ln(π a²) − 4 ln c``;
  GGX ``ln D = ln(a²/π) − 2 ln((a² − 1) c² + 1)``; the Smith terms as
  :func:`~nearlight.physics.reflectance.smith_g1` computes them.
"""

from __future__ import annotations

import numpy as np

from ..physics.reflectance import LOBES, brdf_shape

#: Family names ``full`` accepts for its ``lobe`` option, besides ``auto``.
FAMILIES = tuple(LOBES)


def _smith_log_derivatives(cos_t: np.ndarray, a: float, distribution: str) -> tuple[np.ndarray, np.ndarray]:
    """``∂ ln G1 / ∂ cos θ`` and ``∂ ln G1 / ∂ a`` of :func:`~nearlight.physics.reflectance.smith_g1`."""
    c2 = np.square(cos_t)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        T = np.clip(1.0 - c2, 0.0, None) / c2
        dT = -2.0 / (c2 * cos_t)
        if distribution == "ggx":
            S = np.sqrt(1.0 + a * a * T)
            k = -1.0 / (1.0 + S)
            return k * a * a * dT / (2.0 * S), k * a * T / S
        s = np.sqrt(T)
        x = 1.0 / (a * s)
        num, den = 3.535 * x + 2.181 * x * x, 1.0 + 2.276 * x + 2.577 * x * x
        dlng_dx = (3.535 + 4.362 * x) / num - (2.276 + 5.154 * x) / den
        # x = c / (a √(1 − c²)): ∂x/∂c = 1 / (a (1 − c²)^{3/2})
        dx_dc = 1.0 / (a * np.power(np.clip(1.0 - c2, 0.0, None), 1.5))
        inside = x < 1.6
        return (np.where(inside, dlng_dx * dx_dc, 0.0),
                np.where(inside, dlng_dx * (-x / a), 0.0))


def radiance_and_log_derivatives(
    model: str, cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, roughness: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``F = shape · cos θi`` and its log-derivatives in ``c = cos α``, ``cos θi`` and the roughness.

    Parameters
    ----------
    model : str
        A family of :data:`FAMILIES`.
    cos_i, cos_r, alpha : ndarray, shape (n,)
        Geometry where lit (both cosines positive); α in radians.
    roughness : float
        The family's own roughness (σ in radians for Torrance–Sparrow, ``a`` otherwise).

    Returns
    -------
    F, dlnF_dc, dlnF_dcos_i, dlnF_da : ndarray, shape (n,)
    """
    return (radiance(model, cos_i, cos_r, alpha, roughness),
            *log_derivatives(model, cos_i, cos_r, alpha, roughness))


def radiance(model: str, cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, roughness: float) -> np.ndarray:
    """``F = shape · cos θi`` per unit colour and lamp intensity (times ``1/r²``: the radiance), shape (n,)."""
    return brdf_shape(model, cos_i, cos_r, alpha, roughness) * cos_i


def log_derivatives(
    model: str, cos_i: np.ndarray, cos_r: np.ndarray, alpha: np.ndarray, roughness: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``∂ ln F / ∂c``, ``∂ ln F / ∂ cos θi`` and ``∂ ln F / ∂a`` (:func:`radiance_and_log_derivatives`), shape (n,)."""
    a = roughness
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        if model == "torrance_sparrow":
            sin_a = np.sin(alpha)
            ratio = np.where(sin_a > 1e-12, alpha / np.where(sin_a > 1e-12, sin_a, 1.0), 1.0)
            return ratio / a**2, np.zeros_like(alpha), alpha**2 / a**3
        c = np.cos(alpha)
        tau = np.clip(1.0 - c * c, 0.0, None) / (c * c)
        if model == "ward":
            return 2.0 / (a * a * c**3), 0.5 / cos_i, np.full_like(alpha, -2.0 / a) + 2.0 * tau / a**3
        if model == "beckmann":
            d_c, d_a = 2.0 / (a * a * c**3) - 4.0 / c, 2.0 * tau / a**3 - 2.0 / a
        else:  # ggx
            q = (a * a - 1.0) * c * c + 1.0
            d_c, d_a = -4.0 * (a * a - 1.0) * c / q, 2.0 / a - 4.0 * a * c * c / q
        gi_c, gi_a = _smith_log_derivatives(cos_i, a, model)
        _, gr_a = _smith_log_derivatives(cos_r, a, model)
        return d_c, gi_c, d_a + gi_a + gr_a
