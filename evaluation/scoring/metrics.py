"""Scoring: the error metrics, their column registry, the truth they compare with, and :func:`score`.

Every metric is a small pure function, one number each, units in the
docstring. It takes the estimate first and the truth second and returns a
float; feeding the truth as the estimate gives exactly zero (tested). Where the
problem leaves something free, the metric removes it explicitly: Ks is only
known up to the lamp's intensity, so :func:`ks_relative_error` fits the one
global scale first (as SDPS-Net does for light intensities).

Geometry convention: the *highlight point* is the surface point where the true
lamp's mirror reflection reaches the camera (smallest half-vector angle α over
the surface pixels, :func:`highlight_point`); distances and directions of the
lamp are measured from it, as the paper measures ``t`` along the ray from the
peak pixel.

Degenerate inputs: a metric is a finite float or NaN, never ±inf and never an
exception. NaN means "undefined here": a non-finite (NaN or ±inf) estimate or
truth, a true lamp on the point distances are measured from (no direction, no
relative distance), a true σ ≤ 0 (no relative error), a true Ks of zero, an
empty mask, a truth image without a positive peak. Each function's docstring
names its cases; ``tests/evaluation/scoring/test_metrics.py`` runs every metric on
``[-1, 0, 1, -inf, inf, nan]`` inputs, and on ±1e308, whose differences
overflow.

:func:`score` grades an estimate's specular image with the independent
re-synthesis of :mod:`nearlight.evaluation.scoring.independent_resynthesis`, not with the
estimator's own forward model (see that module for why).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from ...errors import UserError
from ...estimator import Estimate
from ...estimator.highlights import segment_highlights
from ...physics.polarization import through_polarizer
from ...physics.reflectance import LOBES, mitsuba_ts_sigma, shading_geometry, ts_sigma
from .calibration import MAHALANOBIS_COLUMN, lamp_mahalanobis_sq
from .independent_resynthesis import fitted_stage, resynthesize
from .matching import gate_radii, match_lamps

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
#: The estimate itself (lamp position in m, σ in rad, Ks per channel), so a row can be re-synthesised.
ESTIMATE_COLUMNS = ("est_lamp_x_m", "est_lamp_y_m", "est_lamp_z_m", "est_sigma", "est_ks_r", "est_ks_g", "est_ks_b")
#: The lobe family the estimate's σ and Ks stand for (a string column): ``full``'s fitted family
#: (``stages["full"]["lobe"]``), ``torrance_sparrow`` for every other method. σ and Ks are that family's
#: Torrance–Sparrow equivalent (same head-on peak and small-angle width), so with this column a row gives
#: back the fitted family's own BSDF (:func:`~nearlight.physics.reflectance.convert_bsdf`).
LOBE_COLUMN = "est_lobe"
#: Lamp counts of every row: true lamps, lamps the estimate reports, true lamps matched to no estimate,
#: estimates matched to no true lamp (:mod:`nearlight.evaluation.scoring.matching`). 1, 1, 0, 0 for a one-lamp
#: method on a one-lamp capture.
LAMP_COUNT_COLUMNS = ("n_lamps_true", "n_lamps_found", "lamps_missed", "lamps_extra")
#: Separate highlights in a several-lamp capture's noise-free specular image (its rows only).
HIGHLIGHTS_COLUMN = "highlights_true"
#: 1 when the method chose the number of lamps itself (``full``'s ``lamps=auto``), else 0: the report's
#: "Lamps found" section then shows how often it counted right even where every capture has one lamp.
COUNTED_COLUMN = "lamps_counted"
#: Other numeric columns of a row (not compared as regressions).
INFO_COLUMNS = ("distance_signed_m", "lamp_distance_true_m", "sigma_truth", "crlb_lamp_m", "crlb_sigma_rel",
                *ESTIMATE_COLUMNS, *LAMP_COUNT_COLUMNS, HIGHLIGHTS_COLUMN, COUNTED_COLUMN, MAHALANOBIS_COLUMN)


def estimate_columns(estimate: Any) -> dict[str, Any]:
    """A result row's record of ``estimate``: :data:`ESTIMATE_COLUMNS` (floats), :data:`LOBE_COLUMN` and :data:`COUNTED_COLUMN`."""
    values = [*np.ravel(estimate.lamp_position), estimate.sigma, *np.broadcast_to(estimate.ks, (3,))]
    stage = fitted_stage(estimate)
    return {**dict(zip(ESTIMATE_COLUMNS, map(float, values))), LOBE_COLUMN: str(stage.get("lobe") or "torrance_sparrow"),
            COUNTED_COLUMN: float(stage.get("lamps_option") == "auto")}


def _vec(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=float).reshape(3)


def _finite_or_nan(x: float) -> float:
    """``x`` as a float, NaN when it is ±inf or NaN."""
    x = float(x)
    return x if math.isfinite(x) else math.nan


def _all_finite(*arrays: np.ndarray) -> bool:
    return all(bool(np.all(np.isfinite(a))) for a in arrays)


def _overflow_is_inf() -> np.errstate:
    """Finite inputs near the float64 limit may overflow to ±inf (or inf − inf = NaN) on the way: no
    warning, the result goes through :func:`_finite_or_nan`."""
    return np.errstate(over="ignore", invalid="ignore")


def lamp_position_error(est: Any, true: Any) -> float:
    """Euclidean distance between estimated and true lamp positions, metres.

    Parameters
    ----------
    est, true : array_like, shape (3,)
        Lamp positions, metres.

    Returns
    -------
    float
        Metres; NaN when either position is not finite.
    """
    e, t = _vec(est), _vec(true)
    if not _all_finite(e, t):
        return math.nan
    with _overflow_is_inf():
        return _finite_or_nan(np.linalg.norm(e - t))


def lamp_position_error_pct(est: Any, true: Any, *, origin: Any) -> float:
    """Lamp position error as a percentage of the true lamp's distance from ``origin``, %.

    Parameters
    ----------
    est, true, origin : array_like, shape (3,)
        Estimated lamp, true lamp and the point distances are measured from
        (the highlight point), metres.

    Returns
    -------
    float
        Percent; NaN when a point is not finite or the true lamp is at
        ``origin`` (a percentage of a zero distance is undefined).
    """
    e, t, o = _vec(est), _vec(true), _vec(origin)
    if not _all_finite(e, t, o):
        return math.nan
    with _overflow_is_inf():
        reference = float(np.linalg.norm(t - o))
    if reference == 0.0:
        return math.nan
    return _finite_or_nan(100.0 * lamp_position_error(e, t) / reference)


def direction_error_deg(est: Any, true: Any, *, origin: Any) -> float:
    """Angle between the directions to the estimated and true lamps seen from ``origin``, degrees.

    Parameters
    ----------
    est, true, origin : array_like, shape (3,)
        Metres. ``origin`` is the highlight point.

    Returns
    -------
    float
        Degrees in [0, 180]; NaN when a point is not finite or either lamp is
        at ``origin`` (it has no direction from there).
    """
    e, t, o = _vec(est), _vec(true), _vec(origin)
    if not _all_finite(e, t, o):
        return math.nan
    with _overflow_is_inf():
        a, b = e - o, t - o
        if not (np.any(a) and np.any(b)):
            return math.nan
        # atan2 of |a x b| and a.b is accurate near 0 degrees, where arccos is not.
        return _finite_or_nan(math.degrees(math.atan2(float(np.linalg.norm(np.cross(a, b))), float(np.dot(a, b)))))


def distance_error_signed(est: Any, true: Any, *, origin: Any) -> float:
    """Estimated minus true lamp distance from ``origin``, metres (positive: too far).

    Defined for a true lamp at ``origin`` too (then it is the estimate's
    distance); NaN when a point is not finite.
    """
    e, t, o = _vec(est), _vec(true), _vec(origin)
    if not _all_finite(e, t, o):
        return math.nan
    with _overflow_is_inf():
        return _finite_or_nan(np.linalg.norm(e - o) - np.linalg.norm(t - o))


def distance_error(est: Any, true: Any, *, origin: Any) -> float:
    """Absolute error of the lamp's distance from ``origin``, metres (NaN as :func:`distance_error_signed`)."""
    return abs(distance_error_signed(est, true, origin=origin))


def sigma_relative_error(est: float, true: float) -> float:
    """``|σ_est − σ_true| / σ_true``, dimensionless.

    Parameters
    ----------
    est, true : float
        Estimated and true roughness σ, radians.

    Returns
    -------
    float
        NaN when either is not finite, or when ``true ≤ 0`` (a relative error
        of a zero roughness, a perfect mirror, is undefined; the absolute σ
        is in the row's ``sigma_truth`` beside it).
    """
    e, t = float(est), float(true)
    if not (math.isfinite(e) and math.isfinite(t)) or t <= 0.0:
        return math.nan
    return _finite_or_nan(abs(e - t) / t)


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

    Returns
    -------
    float
        NaN when either is not finite or ``true`` is zero (no colour to
        compare with).
    """
    e, t = _vec(est), _vec(true)
    if not _all_finite(e, t) or not np.any(t):
        return math.nan
    with _overflow_is_inf():
        ee = float(e @ e)
        s = float(e @ t) / ee if ee > 0 else 0.0
        return _finite_or_nan(np.linalg.norm(s * e - t) / np.linalg.norm(t))


def specular_rmse(rendered: np.ndarray, observed: np.ndarray, mask: np.ndarray) -> float:
    """Root-mean-square difference of two specular images over ``mask``, radiance units.

    Parameters
    ----------
    rendered, observed : ndarray, shape (H, W, 3)
        Re-rendered and true specular radiance.
    mask : ndarray of bool, shape (H, W)
        Pixels to compare (the surface).

    Returns
    -------
    float
        Radiance; NaN when ``mask`` is empty or a compared pixel is not finite
        (e.g. the NaN image of a non-finite estimate).
    """
    r, o = np.asarray(rendered, dtype=float)[mask], np.asarray(observed, dtype=float)[mask]
    if r.size == 0 or not _all_finite(r, o):
        return math.nan
    with _overflow_is_inf():
        return _finite_or_nan(np.sqrt(np.mean(np.square(r - o))))


def specular_rmse_relative(rendered: np.ndarray, observed: np.ndarray, mask: np.ndarray) -> float:
    """:func:`specular_rmse` divided by the largest observed radiance over ``mask``, dimensionless.

    Parameters as :func:`specular_rmse`. NaN where it is NaN, or when the
    observed image has no positive finite peak over ``mask`` (nothing to be
    relative to).
    """
    rmse = specular_rmse(rendered, observed, mask)
    seen = np.asarray(observed, dtype=float)[mask]
    peak = float(np.max(seen)) if seen.size else math.nan
    if math.isnan(rmse) or not (math.isfinite(peak) and peak > 0.0):
        return math.nan
    return _finite_or_nan(rmse / peak)


def highlight_point(P: np.ndarray, N: np.ndarray, camera_position: Any, lamp_position: Any) -> np.ndarray:
    """The surface point of smallest half-vector angle α: where the specular peak lies, metres.

    Parameters
    ----------
    P, N : ndarray, shape (H, W, 3)
        Surface points (NaN where no surface) and unit normals.
    camera_position, lamp_position : array_like, shape (3,)
        Metres.

    Returns
    -------
    ndarray, shape (3,)
        Metres; all NaN when no surface point sees both the lamp and the
        camera (no highlight, so nothing to measure from).
    """
    mask = np.all(np.isfinite(P), axis=-1) & np.all(np.isfinite(N), axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = shading_geometry(P[mask], N[mask], _vec(camera_position), _vec(lamp_position))
    alpha = np.where((g.cos_i > 0) & (g.cos_r > 0), g.alpha, np.inf)
    if not np.any(np.isfinite(alpha)):
        return np.full(3, np.nan)
    return np.asarray(P[mask][int(np.argmin(alpha))], dtype=float)


def truth_sigma(bsdf: Mapping[str, Any]) -> float:
    """The σ an estimate is compared with, radians.

    A model with a closed form (:data:`~nearlight.physics.reflectance.LOBES`):
    the Torrance–Sparrow σ of its lobe's small-angle width
    (:func:`~nearlight.physics.reflectance.ts_sigma`: Torrance–Sparrow its
    ``sigma``, Ward and Beckmann ``alpha / √2``, GGX ``alpha / 2``); a
    Mitsuba BSDF (``{"model": "mitsuba", "bsdf": {...}}``): its microfacet
    distribution's σ (:func:`~nearlight.physics.reflectance.mitsuba_ts_sigma`,
    e.g. ``pplastic``); any other (no isotropic microfacet roughness): NaN,
    no σ to compare with.
    """
    model = bsdf.get("model")
    if model == "mitsuba":
        sigma = mitsuba_ts_sigma(bsdf["bsdf"])
        return math.nan if sigma is None else sigma
    if model not in LOBES:
        return math.nan
    return ts_sigma(model, float(bsdf[LOBES[model].roughness_key]))


def truth_ks(bsdf: Mapping[str, Any]) -> np.ndarray | None:
    """The specular colour an estimate's Ks is compared with (up to scale): ``ks`` or ``rho_s``.

    Returns
    -------
    ndarray, shape (3,), or None
        Per channel, in the BSDF's units; None when the BSDF has neither key.
    """
    for key in ("ks", "rho_s"):
        if key in bsdf:
            return np.broadcast_to(np.asarray(bsdf[key], dtype=float), (3,))
    return None


def truth_estimate(capture: Any) -> Any:
    """The oracle estimate of a Torrance–Sparrow capture, in the estimators' convention.

    Estimators report Ks with the lamp intensity reaching the surface folded in
    (``ks · I_lamp / 2`` behind the ideal polarizer, ``docs/physics.md``), so
    that the unit-intensity re-render matches the observed specular image.

    Parameters
    ----------
    capture : Capture
        With ``truth["lamp_position"]`` (m), ``truth["bsdf"]`` and
        ``truth["lamp_intensity"]`` (W/sr per channel; 2 when absent).

    Returns
    -------
    Estimate
        ``method="truth"``, a point lamp: every metric of :func:`score` is 0
        against a Torrance–Sparrow truth (up to the truth image's float32
        storage).

    Raises
    ------
    UserError
        A capture with several lamps (:func:`one_lamp_position`).
    """
    truth = capture.truth
    bsdf = truth["bsdf"]
    intensity = np.broadcast_to(np.asarray(truth.get("lamp_intensity", 2.0), dtype=float), (3,))

    return Estimate(
        method="truth",
        lamp_position=one_lamp_position(truth, where=capture_name(capture), what="the oracle estimate"),
        ks=truth_ks(bsdf) * through_polarizer(intensity),
        sigma=truth_sigma(bsdf),
    )


def true_lamps(truth: Mapping[str, Any]) -> np.ndarray:
    """The true lamp positions of a capture's ``truth``, shape (m, 3), metres.

    A one-lamp capture's ``truth["lamp_position"]`` (v1 captures have only
    that), else every ``truth["lamps"][i]["position"]`` in their order.

    Raises
    ------
    KeyError
        A truth with neither.
    """
    if "lamp_position" in truth:
        return np.asarray(truth["lamp_position"], dtype=float).reshape(1, 3)
    return np.asarray([lamp["position"] for lamp in truth["lamps"]], dtype=float).reshape(-1, 3)


def capture_name(capture: Any) -> str:
    """How a message names ``capture``: the file it was read from, else ``capture``."""
    source = getattr(capture, "source", None)
    return str(source) if source is not None else "capture"


def one_lamp_position(truth: Mapping[str, Any], *, where: str, what: str) -> np.ndarray:
    """The position of the one true lamp, shape (3,), metres, for code that knows only one lamp.

    Parameters
    ----------
    truth : mapping
        A capture's ``truth``.
    where, what : str
        The capture (:func:`capture_name`) and the computation, for the message.

    Raises
    ------
    UserError
        A capture with several lamps (no ``truth["lamp_position"]``), in one
        line naming ``where``, ``what`` and the number of lamps, rather than a
        ``KeyError``.
    """
    if "lamp_position" in truth:
        return np.asarray(truth["lamp_position"], dtype=float).reshape(3)

    n = len(truth.get("lamps") or ())
    raise UserError(f"{where}: {what} expects a capture with one lamp; it has {n} lamps (truth.lamps)")


def estimated_lamps(estimate: Any) -> np.ndarray:
    """Every lamp an estimate reports, shape (k, 3), metres: its ``lamp_positions`` when set (a method that
    finds several lamps), else its one ``lamp_position`` (:meth:`nearlight.estimator.Estimate.found_lamps`)."""
    several = getattr(estimate, "lamp_positions", None)
    if several is None:
        return np.asarray(estimate.lamp_position, dtype=float).reshape(1, 3)
    return np.asarray(several, dtype=float).reshape(-1, 3)


#: Per-lamp columns of a several-lamp capture's row, ``lamp<i>_position_error_m`` and ``..._pct`` (``i`` the
#: true lamp's index in ``truth["lamps"]``; NaN when it was missed). One-lamp rows have none.
PER_LAMP_COLUMN = re.compile(r"^lamp\d+_position_error_(m|pct)$")


def _lamp_columns(lamp_est: np.ndarray | None, lamp_true: np.ndarray, origin: np.ndarray) -> dict[str, float]:
    """The lamp metric columns of one estimated lamp against one true lamp (NaN everything without an estimate)."""
    if lamp_est is None:
        return dict.fromkeys(("lamp_position_error_m", "lamp_position_error_pct", "direction_error_deg",
                              "distance_error_m", "distance_signed_m"), math.nan)
    return {
        "lamp_position_error_m": lamp_position_error(lamp_est, lamp_true),
        "lamp_position_error_pct": lamp_position_error_pct(lamp_est, lamp_true, origin=origin),
        "direction_error_deg": direction_error_deg(lamp_est, lamp_true, origin=origin),
        "distance_error_m": distance_error(lamp_est, lamp_true, origin=origin),
        "distance_signed_m": distance_error_signed(lamp_est, lamp_true, origin=origin),
    }


def _worst(values: list[float]) -> float:
    """The largest of ``values``, NaN when any is NaN (a missed lamp has no error to be smaller than)."""
    return math.nan if any(math.isnan(v) for v in values) else max(values)


def lamp_scores(capture: Any, estimate: Any) -> dict[str, Any]:
    """The lamp columns of ``estimate`` against every true lamp of ``capture``, through the matching.

    Each true lamp's errors are measured from its own highlight point
    (:func:`highlight_point`), against the estimated lamp matched to it
    (:func:`nearlight.evaluation.scoring.matching.match_lamps`, gated by
    :func:`~nearlight.evaluation.scoring.matching.gate_radii`).

    One true and one estimated lamp (every one-lamp capture scored with a
    one-lamp method): there is nothing to choose between, so no gate; the pair
    is scored as it always was (the same numbers as before matching existed),
    counts 1, 1, 0, 0 (a non-finite estimate is missed and extra, its errors NaN
    as before).

    Several true or estimated lamps: the row's lamp columns are the *worst*
    over the true lamps (largest error, ``distance_signed_m`` the signed error
    of largest magnitude), NaN when any true lamp was missed. Worst, not mean:
    a method that finds one lamp well and the other badly, or not at all, must
    not look half good, and a missed lamp has no error to average; with one
    lamp the worst is that lamp's error. Each lamp's own errors are in the
    ``lamp<i>_position_error_m`` and ``_pct`` columns.

    Returns
    -------
    dict
        ``lamp_position_error_m``, ``lamp_position_error_pct``,
        ``direction_error_deg``, ``distance_error_m``, ``distance_signed_m``,
        ``lamp_distance_true_m`` (with several lamps, the nearest lamp's
        distance from its highlight), the :data:`LAMP_COUNT_COLUMNS`, and with
        several true lamps the per-lamp columns (:data:`PER_LAMP_COLUMN`) and
        ``highlights_true`` (:func:`_highlights_true`).
    """
    lamps = true_lamps(capture.truth)
    found = estimated_lamps(estimate)
    origins = np.array([highlight_point(capture.P, capture.N, capture.camera.position, t) for t in lamps])
    one = len(lamps) == 1 and len(found) == 1
    matching = match_lamps(found, lamps, None if one else gate_radii(lamps, origins))
    per_lamp = []
    for j, (t, o) in enumerate(zip(lamps, origins)):
        i = matching.estimate_of(j)
        lamp_est = found[0] if one else (None if i is None else found[i])  # one and one: scored even if missed
        per_lamp.append(_lamp_columns(lamp_est, t, o))
    with _overflow_is_inf():
        distances = [_finite_or_nan(np.linalg.norm(t - o)) for t, o in zip(lamps, origins)]
    if len(lamps) == 1:
        out = dict(per_lamp[0])
        out["lamp_distance_true_m"] = distances[0]
    else:
        out = {c: _worst([p[c] for p in per_lamp]) for c in per_lamp[0] if c != "distance_signed_m"}
        signed = [p["distance_signed_m"] for p in per_lamp]
        out["distance_signed_m"] = math.nan if any(math.isnan(v) for v in signed) else max(signed, key=abs)
        out["lamp_distance_true_m"] = math.nan if any(math.isnan(d) for d in distances) else min(distances)
    out.update(n_lamps_true=float(len(lamps)), n_lamps_found=float(len(found)),  # floats, as every column
               lamps_missed=float(len(matching.missed)), lamps_extra=float(len(matching.extra)))
    if len(lamps) > 1:
        out[HIGHLIGHTS_COLUMN] = _highlights_true(capture)
        for j, p in enumerate(per_lamp):
            out[f"lamp{j}_position_error_m"] = p["lamp_position_error_m"]
            out[f"lamp{j}_position_error_pct"] = p["lamp_position_error_pct"]
    return out


def _highlights_true(capture: Any) -> float:
    """Separate highlights in the noise-free specular image (``extra["truth_specular"]``), NaN without one.

    The count of :func:`~nearlight.estimator.highlights.segment_highlights` (the
    estimators' own segmentation, at its default dip) over pixels with a
    surface point: where two lamps' highlights have merged into one blob it
    reads 1, so a sweep over their separation shows where they merge beside
    which methods still find both lamps.
    """
    specular = capture.extra.get("truth_specular")
    if specular is None:
        return math.nan
    located = np.all(np.isfinite(capture.P), axis=-1)
    return float(len(segment_highlights(np.asarray(specular, dtype=float), located).peaks))


def score(capture: Any, estimate: Any) -> dict[str, float]:
    """Metric columns of ``estimate`` against the truth of the noise-free ``capture``.

    Parameters
    ----------
    capture : Capture
        Noise-free capture with ``truth``, ``P``, ``N`` and
        ``extra["truth_specular"]`` (``(H, W, 3)`` radiance). One lamp
        (``truth["lamp_position"]``) or several (``truth["lamps"]``).
    estimate : Estimate
        Its specular image is re-synthesised for grading by
        :func:`nearlight.evaluation.scoring.independent_resynthesis.resynthesize`, an
        implementation independent of the estimator's forward model; it
        knows distant-light estimates too. Its lamps
        (:func:`estimated_lamps`) are matched to the true ones
        (:func:`lamp_scores`).

    Returns
    -------
    dict of str to float
        The :data:`METRICS` columns (but ``runtime_s``) and ``distance_signed_m``,
        ``lamp_distance_true_m`` (m), ``sigma_truth`` (rad), ``lamp_mahalanobis_sq``
        (:func:`~nearlight.evaluation.scoring.calibration.lamp_mahalanobis_sq`: one true and one
        estimated lamp, else NaN), the
        :data:`LAMP_COUNT_COLUMNS` and, with several true lamps, the per-lamp
        columns (:func:`lamp_scores`: the lamp columns are then the worst over
        the true lamps, NaN when one was missed). Each is finite or
        NaN; NaN rules:

        - a σ the estimator declares undetermined
          (``estimate.diagnostics["undetermined"]``) gets no σ error: any value
          fits the data (``distant`` on a plane also declares its light
          direction undetermined, and is refused before it is scored);
        - a NaN or ±inf in the estimate's ``lamp_position`` makes every lamp
          metric NaN, and both specular RMSEs for a point lamp (a distant
          estimate's image comes from its directions); in ``ks`` or
          ``sigma``, their own error and both specular RMSEs (the
          re-synthesised image is NaN);
        - a true lamp at the highlight point: percentage and direction
          errors NaN; no highlight at all (no surface point sees both lamp
          and camera): every metric measured from it NaN;
        - a true σ ≤ 0: σ error NaN; no Ks in the truth BSDF: Ks error NaN;
        - no ``truth_specular`` in the capture (a ``material.model: mitsuba``
          render, whose BSDF the generator cannot split into specular and
          diffuse parts): both specular RMSEs NaN.

        The specular RMSEs compare the estimate's re-synthesis (its
        ``lamp_position`` with its ``ks`` and ``sigma``) with the observed
        specular image of every lamp together.
    """
    truth = capture.truth
    bsdf = truth["bsdf"]
    lamps = lamp_scores(capture, estimate)
    sigma_true = truth_sigma(bsdf)
    ks_true = truth_ks(bsdf)
    observed = capture.extra.get("truth_specular")
    mask = capture.object_mask  # the object's pixels (a capture with calibration targets has others)
    rendered = resynthesize(capture, estimate)
    rmse = (math.nan, math.nan) if observed is None else (specular_rmse(rendered, observed, mask),
                                                         specular_rmse_relative(rendered, observed, mask))
    out = {
        "lamp_position_error_m": lamps.pop("lamp_position_error_m"),
        "lamp_position_error_pct": lamps.pop("lamp_position_error_pct"),
        "direction_error_deg": lamps.pop("direction_error_deg"),
        "distance_error_m": lamps.pop("distance_error_m"),
        "sigma_rel_error": math.nan if "sigma" in estimate.diagnostics.get("undetermined", ())
        else sigma_relative_error(estimate.sigma, sigma_true),
        "ks_rel_error": math.nan if ks_true is None or "ks" in estimate.diagnostics.get("undetermined", ())
        else ks_relative_error(estimate.ks, ks_true),
        "specular_rmse": rmse[0],
        "specular_rmse_rel": rmse[1],
        "distance_signed_m": lamps.pop("distance_signed_m"),
        "lamp_distance_true_m": lamps.pop("lamp_distance_true_m"),
        "sigma_truth": sigma_true,
    }
    one = lamps["n_lamps_true"] == 1 and lamps["n_lamps_found"] == 1  # lamp_scores's counts
    out[MAHALANOBIS_COLUMN] = lamp_mahalanobis_sq(estimate, true_lamps(truth)[0]) if one else math.nan
    out.update(lamps)
    return out
