"""Paper fidelity: why the paper's first stage errs, in numbers, on analytic captures.

Small functions returning dicts of numbers (JSON-ready), for the reproduction
report to call; each builds noise-free closed-form captures
(:mod:`nearlight.generator.analytic`, no renderer) and runs ``paper-init``
with the ORACLE origin ``mirror-oracle`` (the exact mirror point of the true
lamp: truth used by the oracle only), so that the method's own error is
separated from that of its ray's origin:

* :func:`ep_flatness`: 3 + E_p(t) along the exact mirror ray of a TS board at
  fractions of the true t: how little E_p knows of t on a plane.
* :func:`t_star_curve`: t*/t from the origin ``m + s·δ`` (m the mirror point,
  δ its offset to the brightest pixel), against the law 1/(1 + s).
* :func:`ward_bias`: t*/t on the exact ray for a Ward and a TS board of the
  same lobe, against Dc/t (Dc the camera's distance from the mirror point).

Lengths in metres; ratios dimensionless.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ...estimator import estimate
from ...estimator.observation import observation_of, surface_at
from ...estimator.first_stage import RaySearch, mirror_oracle_pixel
from ...generator.analytic import analytic_capture
from ...physics.reflectance import ward_from_torrance_sparrow
from ..scoring.metrics import capture_name, one_lamp_position

#: The TS board of the studies: the analytic default scene with σ = 0.05 (the issue's).
TS_BOARD = {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.05}
#: Camera of :func:`ward_bias`, metres: 0.61 m from the board centre, 35° off its normal.
CAMERA = (0.0, -0.35, 0.5)


def _lamp(capture: Any) -> np.ndarray:
    """The capture's one lamp, metres (a one-line UserError for a capture with several)."""
    return one_lamp_position(capture.truth, where=capture_name(capture), what="the paper-fidelity study")


def _exact_ray(capture: Any) -> tuple[RaySearch, float]:
    """The ray of eq. 9 from the exact mirror point (ORACLE), and the true t along it."""
    obs = observation_of(capture)
    ray = RaySearch(obs, surface_at(obs, mirror_oracle_pixel(capture, obs)))
    t_true = float(np.linalg.norm(_lamp(capture) - ray.origin))
    return ray, t_true


def ep_flatness(*, factors: Sequence[float] = (0.5, 0.9, 1.0, 2.0), bsdf: dict | None = None,
                **scene: Any) -> dict[str, Any]:
    """3 + E_p(t) at ``factor · t_true`` along the exact mirror ray of a TS board.

    E_p ≥ −3 (three correlation coefficients), −3 exactly where the (X, Y_m)
    points are collinear: at the true t on the exact ray, noise-free. The
    smaller the values off the truth, the flatter E_p, and the more any other
    error (the ray's origin, noise) moves its minimum.

    Parameters
    ----------
    factors : sequence of float
        t / t_true at which to evaluate.
    bsdf : dict, optional
        Default :data:`TS_BOARD`.
    **scene
        Further :func:`~nearlight.generator.analytic.analytic_capture` arguments.

    Returns
    -------
    dict
        ``t_true`` (m), ``rows``: ``{"factor", "t", "three_plus_ep"}`` each.
    """
    cap = analytic_capture(bsdf=bsdf or TS_BOARD, analyzer_angles_deg=None, **scene)
    ray, t_true = _exact_ray(cap)
    t = np.asarray(factors, dtype=float) * t_true
    ep = ray.ep(t)
    return {"t_true": t_true, "rows": [{"factor": float(f), "t": float(tt), "three_plus_ep": float(3.0 + e)}
                                       for f, tt, e in zip(factors, t, ep)]}


def t_star_curve(*, shifts: Sequence[float] = (0.0, 0.1, 0.25, 0.5, 1.0), bsdf: dict | None = None,
                 **scene: Any) -> dict[str, Any]:
    """t*/t of ``paper-init`` from the origin ``m + s·(p − m)``, against 1/(1 + s).

    m is the exact mirror point (ORACLE), p the brightest pixel (s = 1 is the
    printed paper's origin). t is the true lamp's distance from that origin.

    Returns
    -------
    dict
        ``rows``: ``{"s", "t_ratio", "law"}`` each (law = 1/(1 + s); None
        where s ≤ −1), ``delta_px`` (|p − m|, pixels).
    """
    cap = analytic_capture(bsdf=bsdf or TS_BOARD, analyzer_angles_deg=None, **scene)
    lamp = _lamp(cap)
    obs = observation_of(cap)
    delta = float(np.linalg.norm(np.asarray(obs.peak, dtype=float) - mirror_oracle_pixel(cap, obs)))
    rows = []
    for s in shifts:
        est = estimate(cap, method="paper-init", sanity=False, origin="mirror-oracle", origin_shift=float(s))
        origin = np.asarray(est.diagnostics["ray_origin"])
        rows.append({"s": float(s), "t_ratio": est.stages["init"]["t"] / float(np.linalg.norm(lamp - origin)),
                     "law": 1.0 / (1.0 + float(s)) if s > -1 else None})
    return {"rows": rows, "delta_px": delta}


def ward_bias(*, dc_over_t: Sequence[float] = (0.5, 0.7, 1.0, 2.0), sigma: float = 0.1,
              camera_position: Sequence[float] = CAMERA, **scene: Any) -> dict[str, Any]:
    """t*/t of ``paper-init`` on the exact mirror ray, Ward vs Torrance–Sparrow, against Dc/t.

    The camera stays put; the lamp sits on the mirror ray of the board's
    centre (so the mirror point is the centre), at ``t = Dc / ratio``. The
    Ward board has the TS lobe's width and peak
    (:func:`~nearlight.physics.reflectance.ward_from_torrance_sparrow`); the
    TS log-linear model is exact for TS, so its t*/t is 1 to the 1-mm grid,
    and the Ward row's distance from 1 is the model's bias on Ward.

    Returns
    -------
    dict
        ``dc`` (m), ``rows``: ``{"dc_over_t", "t", "ts_t_ratio", "ward_t_ratio", "ward_bias"}`` each
        (``ward_bias`` = ward_t_ratio − 1).
    """
    cam = np.asarray(camera_position, dtype=float)
    dc = float(np.linalg.norm(cam))
    mirror = cam * [-1.0, -1.0, 1.0] / dc
    alpha, rho_s = ward_from_torrance_sparrow(sigma, np.array(TS_BOARD["ks"]))
    models = {"ts": {**TS_BOARD, "sigma": sigma}, "ward": {"model": "ward", "rho_s": rho_s.tolist(), "alpha": alpha}}
    rows = []
    for ratio in dc_over_t:
        t = dc / float(ratio)
        row = {"dc_over_t": float(ratio), "t": t}
        for name, bsdf in models.items():
            cap = analytic_capture(bsdf=bsdf, camera_position=tuple(cam), lamp_position=tuple(t * mirror),
                                   analyzer_angles_deg=None, **scene)
            est = estimate(cap, method="paper-init", sanity=False, origin="mirror-oracle", t_max=10.0 * t)
            origin = np.asarray(est.diagnostics["ray_origin"])
            row[f"{name}_t_ratio"] = est.stages["init"]["t"] / float(np.linalg.norm(t * mirror - origin))
        row["ward_bias"] = row["ward_t_ratio"] - 1.0
        rows.append(row)
    return {"dc": dc, "rows": rows}


def ep_curves(capture: Any, *, factors: Sequence[float] | None = None) -> dict[str, Any]:
    """E_p(t) along the peak ray (the printed paper's) and along the exact mirror ray (ORACLE).

    Each ray's t runs over ``factors`` × its own true t (the true lamp's
    distance from the ray's origin; on the peak ray the lamp is off the ray
    and t_true is the distance to it). For the figure of the §4.1 board.

    Returns
    -------
    dict
        ``{"peak": ..., "mirror": ...}``, each ``t_true`` (m), ``t`` (m),
        ``three_plus_ep`` (3 + E_p, ≥ 0) and ``t_star`` (the grid minimiser
        over that dense grid, m); ``delta_px``: |brightest pixel − mirror point|, pixels.
    """
    obs = observation_of(capture)
    delta = float(np.linalg.norm(np.asarray(obs.peak, dtype=float) - mirror_oracle_pixel(capture, obs)))
    lamp = _lamp(capture)
    grid = np.geomspace(0.05, 4.0, 160) if factors is None else np.asarray(factors, dtype=float)
    out = {}
    for name, ray in (("peak", RaySearch(obs)), ("mirror", _exact_ray(capture)[0])):
        t_true = float(np.linalg.norm(lamp - ray.origin))
        t = grid * t_true
        ep = 3.0 + ray.ep(t)
        out[name] = {"t_true": t_true, "t": t.tolist(), "three_plus_ep": ep.tolist(),
                     "t_star": float(t[int(np.argmin(ep))])}
    return {**out, "delta_px": delta}


def distribution(errors: Sequence[float], *, reference: float) -> dict[str, Any]:
    """Median, p10, p90, quartiles of errors (%), and the percentile of ``reference`` among them.

    A failed sample (NaN) counts as a failure: it sorts above every finite
    error (so it can raise the p90 to None, never lower it) and is counted in
    ``failed``. ``reference_percentile`` is the percentage of samples whose
    error is at most ``reference`` (0: the reference is better than every
    sample).

    Returns
    -------
    dict
        ``n``, ``failed``, ``median``, ``p10``, ``p25``, ``p75``, ``p90``
        (None where a failure lands on it), ``min``, ``max``, ``reference``,
        ``reference_percentile``.
    """
    e = np.asarray(errors, dtype=float)
    filled = np.where(np.isnan(e), np.inf, e)
    q = {name: _quantile(np.sort(filled), p) for name, p in
         (("p10", 10), ("p25", 25), ("median", 50), ("p75", 75), ("p90", 90), ("min", 0), ("max", 100))}
    return {"n": int(len(e)), "failed": int(np.isnan(e).sum()), **q,
            "reference": float(reference),
            "reference_percentile": float(100.0 * np.mean(filled <= reference))}


def _quantile(ordered: np.ndarray, p: float) -> float | None:
    """numpy's linear percentile ``p`` of sorted values; None where it needs a failure (+inf)."""
    pos = p / 100.0 * (len(ordered) - 1)
    lo, frac = int(np.floor(pos)), pos - np.floor(pos)
    used = ordered[lo : lo + 2] if frac > 0 else ordered[lo : lo + 1]
    if not np.all(np.isfinite(used)):
        return None
    return float(used[0] + frac * (used[-1] - used[0]))
