"""Error metrics: small pure functions, one number each, units in the docstring.

Every function takes the estimate first and the truth second and returns a
float; feeding the truth as the estimate gives exactly zero (tested). Where the
problem leaves something free, the metric removes it explicitly: Ks is only
known up to the lamp's intensity, so :func:`ks_relative_error` fits the one
global scale first (as SDPS-Net does for light intensities).

Geometry convention: the *highlight point* is the surface point where the true
lamp's mirror reflection reaches the camera (smallest half-vector angle α over
the surface pixels, :func:`highlight_point`); distances and directions of the
lamp are measured from it, as the paper measures ``t`` along the ray from the
peak pixel.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..physics.polarization import through_polarizer
from ..physics.reflectance import shading_geometry, ts_sigma_from_ward


def _vec(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=float).reshape(3)


def lamp_position_error(est: Any, true: Any) -> float:
    """Euclidean distance between estimated and true lamp positions, metres.

    Parameters
    ----------
    est, true : array_like, shape (3,)
        Lamp positions, metres.
    """
    return float(np.linalg.norm(_vec(est) - _vec(true)))


def lamp_position_error_pct(est: Any, true: Any, *, origin: Any) -> float:
    """Lamp position error as a percentage of the true lamp's distance from ``origin``, %.

    Parameters
    ----------
    est, true, origin : array_like, shape (3,)
        Estimated lamp, true lamp and the point distances are measured from
        (the highlight point), metres.
    """
    return 100.0 * lamp_position_error(est, true) / float(np.linalg.norm(_vec(true) - _vec(origin)))


def direction_error_deg(est: Any, true: Any, *, origin: Any) -> float:
    """Angle between the directions to the estimated and true lamps seen from ``origin``, degrees.

    Parameters
    ----------
    est, true, origin : array_like, shape (3,)
        Metres. ``origin`` is the highlight point.
    """
    a, b = _vec(est) - _vec(origin), _vec(true) - _vec(origin)
    # atan2 of |a x b| and a.b is accurate near 0 degrees, where arccos is not.
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(a, b))), float(np.dot(a, b))))


def distance_error_signed(est: Any, true: Any, *, origin: Any) -> float:
    """Estimated minus true lamp distance from ``origin``, metres (positive: too far)."""
    return float(np.linalg.norm(_vec(est) - _vec(origin)) - np.linalg.norm(_vec(true) - _vec(origin)))


def distance_error(est: Any, true: Any, *, origin: Any) -> float:
    """Absolute error of the lamp's distance from ``origin``, metres."""
    return abs(distance_error_signed(est, true, origin=origin))


def sigma_relative_error(est: float, true: float) -> float:
    """``|σ_est − σ_true| / σ_true``, dimensionless (NaN when ``true`` is NaN)."""
    return abs(float(est) - float(true)) / float(true)


def ks_relative_error(est: Any, true: Any) -> float:
    """Relative error of the specular colour Ks after the best global scale, dimensionless.

    The lamp's intensity multiplies Ks, so an estimator only knows Ks up to one
    scale ``s``. With ``s = (est · true) / (est · est)`` (least squares),
    returns ``‖s·est − true‖ / ‖true‖``; 0 when ``est`` is proportional to
    ``true``; 1 when ``est`` is zero.

    Parameters
    ----------
    est, true : array_like, shape (3,)
        Per-channel Ks (any common units).
    """
    e, t = _vec(est), _vec(true)
    ee = float(e @ e)
    s = float(e @ t) / ee if ee > 0 else 0.0
    return float(np.linalg.norm(s * e - t) / np.linalg.norm(t))


def specular_rmse(rendered: np.ndarray, observed: np.ndarray, mask: np.ndarray) -> float:
    """Root-mean-square difference of two specular images over ``mask``, radiance units.

    Parameters
    ----------
    rendered, observed : ndarray, shape (H, W, 3)
        Re-rendered and true specular radiance.
    mask : ndarray of bool, shape (H, W)
        Pixels to compare (the surface).
    """
    d = np.asarray(rendered, dtype=float)[mask] - np.asarray(observed, dtype=float)[mask]
    return float(np.sqrt(np.mean(np.square(d))))


def highlight_point(P: np.ndarray, N: np.ndarray, camera_position: Any, lamp_position: Any) -> np.ndarray:
    """The surface point of smallest half-vector angle α: where the specular peak lies, metres.

    Parameters
    ----------
    P, N : ndarray, shape (H, W, 3)
        Surface points (NaN where no surface) and unit normals.
    camera_position, lamp_position : array_like, shape (3,)

    Returns
    -------
    ndarray, shape (3,)
    """
    mask = np.all(np.isfinite(P), axis=-1) & np.all(np.isfinite(N), axis=-1)
    g = shading_geometry(P[mask], N[mask], _vec(camera_position), _vec(lamp_position))
    alpha = np.where((g.cos_i > 0) & (g.cos_r > 0), g.alpha, np.inf)
    return np.asarray(P[mask][int(np.argmin(alpha))], dtype=float)


#: Metric columns (all "lower is better"), in table order, with their units.
METRICS: dict[str, str] = {
    "lamp_position_error_m": "m",
    "lamp_position_error_pct": "% of lamp distance",
    "direction_error_deg": "deg",
    "distance_error_m": "m",
    "sigma_rel_error": "relative",
    "ks_rel_error": "relative (after global scale)",
    "specular_rmse": "radiance",
    "specular_rmse_rel": "relative to peak",
    "runtime_s": "s",
}
#: Other numeric columns of a row (not compared as regressions).
INFO_COLUMNS = ("distance_signed_m", "lamp_distance_true_m", "sigma_truth", "crlb_lamp_m", "crlb_sigma_rel")


def truth_sigma(bsdf: Mapping[str, Any]) -> float:
    """The σ an estimate is compared with: TS ``sigma``; Ward's small-angle equivalent ``alpha/√2``; else NaN."""
    model = bsdf.get("model")
    if model == "torrance_sparrow":
        return float(bsdf["sigma"])
    if model == "ward":
        return ts_sigma_from_ward(float(bsdf["alpha"]))
    return math.nan


def truth_ks(bsdf: Mapping[str, Any]) -> np.ndarray | None:
    """The specular colour an estimate's Ks is compared with (up to scale): ``ks`` or ``rho_s``."""
    for key in ("ks", "rho_s"):
        if key in bsdf:
            return np.broadcast_to(np.asarray(bsdf[key], dtype=float), (3,))
    return None


def truth_estimate(capture: Any) -> Any:
    """The oracle estimate of a Torrance–Sparrow capture, in the estimators' convention.

    Estimators report Ks with the lamp intensity reaching the surface folded in
    (``ks · I_lamp / 2`` behind the ideal polarizer), so that the unit-intensity
    re-render matches the observed specular image.
    """
    truth = capture.truth
    bsdf = truth["bsdf"]
    intensity = np.broadcast_to(np.asarray(truth.get("lamp_intensity", 2.0), dtype=float), (3,))
    from ..estimator import Estimate

    return Estimate(
        method="truth",
        lamp_position=np.asarray(truth["lamp_position"], dtype=float),
        ks=truth_ks(bsdf) * through_polarizer(intensity),
        sigma=truth_sigma(bsdf),
    )


def score(capture: Any, estimate: Any) -> dict[str, float]:
    """Metric columns of ``estimate`` against the truth of the noise-free ``capture``.

    Parameters
    ----------
    capture : Capture
        Noise-free capture with ``truth``, ``N`` and ``extra["truth_specular"]``.
    estimate : Estimate
        Its specular image is re-synthesised by the estimator's own forward
        model (:func:`nearlight.estimator.render_specular`), which knows
        distant-light estimates too.

    A σ the estimator declares undetermined (``estimate.diagnostics["undetermined"]``,
    e.g. ``distant`` on a plane) gets no σ error (NaN): any value fits the data.

    Returns
    -------
    dict
        The :data:`METRICS` columns (but ``runtime_s``) and ``distance_signed_m``,
        ``lamp_distance_true_m``, ``sigma_truth``.
    """
    truth = capture.truth
    bsdf = truth["bsdf"]
    lamp_true = np.asarray(truth["lamp_position"], dtype=float)
    lamp_est = np.asarray(estimate.lamp_position, dtype=float)
    origin = highlight_point(capture.P, capture.N, capture.camera.position, lamp_true)
    sigma_true = truth_sigma(bsdf)
    ks_true = truth_ks(bsdf)
    observed = capture.extra["truth_specular"]
    mask = capture.surface_mask
    from ..estimator import render_specular

    rendered = np.asarray(render_specular(capture, estimate), dtype=float)
    rmse = specular_rmse(rendered, observed, mask)
    return {
        "lamp_position_error_m": lamp_position_error(lamp_est, lamp_true),
        "lamp_position_error_pct": lamp_position_error_pct(lamp_est, lamp_true, origin=origin),
        "direction_error_deg": direction_error_deg(lamp_est, lamp_true, origin=origin),
        "distance_error_m": distance_error(lamp_est, lamp_true, origin=origin),
        "sigma_rel_error": math.nan if "sigma" in estimate.diagnostics.get("undetermined", ())
        else sigma_relative_error(estimate.sigma, sigma_true),
        "ks_rel_error": math.nan if ks_true is None else ks_relative_error(estimate.ks, ks_true),
        "specular_rmse": rmse,
        "specular_rmse_rel": rmse / float(np.max(observed[mask])),
        "distance_signed_m": distance_error_signed(lamp_est, lamp_true, origin=origin),
        "lamp_distance_true_m": float(np.linalg.norm(lamp_true - origin)),
        "sigma_truth": sigma_true,
    }
