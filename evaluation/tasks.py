"""One task: render (or re-use the render), add noise, run the estimator, score it.

:func:`run_task` runs in a worker process (or a Dask worker) and returns one
tidy row: never raises for a failing estimator or render, the row then carries
``status="error"`` and the message. :func:`score` turns an estimate and the
noise-free capture into the metric columns; :func:`truth_estimate` is the
estimate an oracle would return (every error zero).
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..physics.polarization import through_polarizer
from ..physics.reflectance import ts_sigma_from_ward
from . import metrics

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
#: Other numeric columns of a row (not compared as regressions).
INFO_COLUMNS = ("distance_signed_m", "lamp_distance_true_m", "sigma_truth", "crlb_lamp_m", "crlb_sigma_rel",
                *ESTIMATE_COLUMNS)


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
    origin = metrics.highlight_point(capture.P, capture.N, capture.camera.position, lamp_true)
    sigma_true = truth_sigma(bsdf)
    ks_true = truth_ks(bsdf)
    observed = capture.extra["truth_specular"]
    mask = capture.surface_mask
    from ..estimator import render_specular

    rendered = np.asarray(render_specular(capture, estimate), dtype=float)
    rmse = metrics.specular_rmse(rendered, observed, mask)
    return {
        "lamp_position_error_m": metrics.lamp_position_error(lamp_est, lamp_true),
        "lamp_position_error_pct": metrics.lamp_position_error_pct(lamp_est, lamp_true, origin=origin),
        "direction_error_deg": metrics.direction_error_deg(lamp_est, lamp_true, origin=origin),
        "distance_error_m": metrics.distance_error(lamp_est, lamp_true, origin=origin),
        "sigma_rel_error": math.nan if "sigma" in estimate.diagnostics.get("undetermined", ())
        else metrics.sigma_relative_error(estimate.sigma, sigma_true),
        "ks_rel_error": math.nan if ks_true is None else metrics.ks_relative_error(estimate.ks, ks_true),
        "specular_rmse": rmse,
        "specular_rmse_rel": rmse / float(np.max(observed[mask])),
        "distance_signed_m": metrics.distance_error_signed(lamp_est, lamp_true, origin=origin),
        "lamp_distance_true_m": float(np.linalg.norm(lamp_true - origin)),
        "sigma_truth": sigma_true,
    }


def run_method(capture: Any, method: str, options: Mapping[str, Any]) -> Any:
    """Run a built-in method by name or a ``module:function`` estimator on ``capture``, through
    :func:`nearlight.estimator.estimate` (options checked, result type checked, timings)."""
    from ..estimator import estimate

    return estimate(capture, method=method, **options)


def _noisy(clean: Any, task: Mapping[str, Any]) -> Any:
    """The capture the estimator sees: camera noise, then range noise, both given the task's seed
    (the one seed rule of :mod:`nearlight.generator.noise`, as ``nearlight render`` with ``capture.seed``)."""
    capture = clean
    if task["noise"] is not None:
        from ..generator import add_camera_noise

        capture = add_camera_noise(capture, noise=task["noise"], seed=task["seed"])
    if task["range_noise"] > 0:
        from ..generator import add_range_noise

        capture = add_range_noise(capture, sigma_m=task["range_noise"], seed=task["seed"])
    return capture


def _crlb(clean: Any, task: Mapping[str, Any]) -> dict[str, float]:
    """CRLB columns when they apply (TS truth, ideal mode, a stack, Gaussian-modelled camera noise)."""
    from .crlb import camera_noise_variance, specular_crlb

    bsdf = clean.truth["bsdf"]
    if not task["crlb"] or task["noise"] is None or clean.stack is None or bsdf.get("model") != "torrance_sparrow":
        return {}
    if bsdf.get("polarization", "ideal") != "ideal":
        return {}
    return specular_crlb(clean, noise_var=camera_noise_variance(clean.stack, noise=task["noise"]))


def run_task(task: Mapping[str, Any], *, renderer: Any, cache_dir: str | None) -> dict[str, Any]:
    """Run one task; return its row (metrics, or ``status="error"`` and the message).

    Parameters
    ----------
    task : mapping
        ``task_id``, ``index``, ``config``, ``scene``, ``noise``, ``range_noise``,
        ``seed``, ``method``, ``method_spec``, ``options``, ``crlb`` (see
        :class:`nearlight.evaluation.sweep.Task`).
    renderer : Renderer
    cache_dir : str or None
        Render cache (shared by all workers).
    """
    row: dict[str, Any] = {"status": "ok", "error": ""}
    row.update(dict.fromkeys(METRICS, math.nan))
    row.update(dict.fromkeys(INFO_COLUMNS, math.nan))
    stage = "render"
    try:
        clean = renderer.render(task["scene"], cache_dir=None if cache_dir is None else Path(cache_dir))
        stage = "noise"
        capture = _noisy(clean, task)
        stage = "estimate"
        t0 = time.perf_counter()
        est = run_method(capture, task["method_spec"], task["options"])
        row["runtime_s"] = time.perf_counter() - t0
        values = [*np.ravel(est.lamp_position), est.sigma, *np.broadcast_to(est.ks, (3,))]
        row.update(zip(ESTIMATE_COLUMNS, map(float, values)))
        stage = "score"
        row.update(score(clean, est))
        stage = "crlb"
        row.update(_crlb(clean, task))
    except Exception as exc:  # a failing task is a row, not a crashed sweep
        last = traceback.extract_tb(exc.__traceback__)[-1]
        row["status"] = "error"
        row["error"] = f"{stage}: {type(exc).__name__}: {' '.join(str(exc).split())} ({Path(last.filename).name}:{last.lineno})"
    return row
