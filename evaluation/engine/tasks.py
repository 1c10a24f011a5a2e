"""One task: render (or re-use the render), add noise, run the estimator, score it.

:func:`run_task` runs in a worker process (or a Dask worker) and returns one
tidy row: never raises for a failing estimator or render, the row then carries
``status="error"`` and the message (``status="failed"`` when the estimate broke a rule of
:mod:`nearlight.estimator.sanity`: a method's answer the data do not support). The scoring itself (the metric columns,
:func:`~nearlight.evaluation.scoring.metrics.score`, the truth it compares with) lives
in :mod:`nearlight.evaluation.scoring.metrics`; this module only runs it.
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ...errors import one_line
from ...estimator import estimate
from ...estimator.range_error import RangeModel
from ...estimator.sanity import UnsupportedEstimate
from ...physics.reflectance import LOBES
from ..scoring.crlb import camera_noise_variance, specular_crlb
from ..scoring.range_bound import range_crlb
from ..scoring.metrics import INFO_COLUMNS, LOBE_COLUMN, METRICS, estimate_columns, score


def run_method(capture: Any, method: str, options: Mapping[str, Any]) -> Any:
    """Run a built-in method by name or a ``module:function`` estimator on ``capture``, through
    :func:`nearlight.estimator.estimate` (options checked, result type checked, timings, the sanity rules).

    Raises
    ------
    UnsupportedEstimate
        The estimate broke a rule of :mod:`nearlight.estimator.sanity`: the row is a failure, not a number.
    """
    est = estimate(capture, method=method, **options)
    if not est.ok:
        raise UnsupportedEstimate(est)
    return est


def noisy_capture(clean: Any, task: Mapping[str, Any]) -> Any:
    """The capture the estimator sees: the scene's nuisances, camera noise and range noise, all given the task's
    seed (:func:`nearlight.generator.nuisances.through_rig`, as ``nearlight render`` with ``capture.seed``)."""
    from ...generator.nuisances import nuisances_of, through_rig

    realism, nuisances = nuisances_of(task.get("scene") or {})
    return through_rig(clean, nuisances=None if nuisances.off and realism == "none" else nuisances, realism=realism,
                   noise=task["noise"], range_noise=task["range_noise"], seed=task["seed"])  # fmt: skip


def _crlb(clean: Any, task: Mapping[str, Any]) -> dict[str, float]:
    """CRLB columns when they apply (one lamp, a lobe with a closed form, ideal mode, a stack, Gaussian-modelled
    camera noise): the bound with the surface exact (:func:`~nearlight.evaluation.scoring.crlb.specular_crlb`),
    or, where the task's range is noisy or quantised, with the surface's parameters fitted beside the lamp
    (:func:`~nearlight.evaluation.scoring.range_bound.range_crlb`: NaN for a surface neither a plane nor a
    sphere); the range's error along the ray, as the generator applies it, a quantum as its ``q/√12``."""
    bsdf = clean.truth["bsdf"]
    if not task["crlb"] or task["noise"] is None or clean.stack is None or bsdf.get("model") not in LOBES:
        return {}
    if "lamp_position" not in clean.truth:  # several lamps: the bound is for one lamp's fit
        return {}
    if bsdf.get("polarization", "ideal") != "ideal":
        return {}
    noise_var = camera_noise_variance(clean.stack, noise=task["noise"])
    range_sigma = _range_sigma(task)
    if range_sigma > 0:
        bound = range_crlb(clean, noise_var=noise_var, range_sigma_m=range_sigma, axis="ray")
        return {key: bound[key] for key in ("crlb_lamp_m", "crlb_sigma_rel")}
    return specular_crlb(clean, noise_var=noise_var)


def _range_sigma(task: Mapping[str, Any]) -> float:
    """Standard deviation of the task's range error along the ray, metres: its Gaussian noise and the scene's
    depth quantum (``nuisances.range.quantum_m``, a realism profile's included) as ``√(σ² + q²/12)``."""
    from ...generator.nuisances import nuisances_of

    quantum = nuisances_of(task.get("scene") or {})[1].range.quantum_m
    return RangeModel(sigma_m=float(task["range_noise"] or 0.0), quantum_m=quantum).equivalent_sigma_m


def blank_row() -> dict[str, Any]:
    """A row before any work: ``status`` ``"ok"``, every metric and information column NaN, no lobe."""
    row: dict[str, Any] = {"status": "ok", "error": ""}
    row.update(dict.fromkeys(METRICS, math.nan))
    row.update(dict.fromkeys(INFO_COLUMNS, math.nan))
    row[LOBE_COLUMN] = ""
    return row


def failed_row(row: dict[str, Any], stage: str, exc: Exception) -> dict[str, Any]:
    """``row`` after ``exc`` at ``stage`` (a sweep's task or a scorecard's case): ``status`` ``"failed"`` for an
    estimate the data do not support (:class:`UnsupportedEstimate`: the method answered, no number), else
    ``"error"`` with the exception's one-line message and where it was raised."""
    if isinstance(exc, UnsupportedEstimate):
        return {**row, "status": "failed", "error": f"estimate: {exc}"}
    last = traceback.extract_tb(exc.__traceback__)[-1]
    return {**row, "status": "error",
            "error": f"{stage}: {type(exc).__name__}: {one_line(exc)} ({Path(last.filename).name}:{last.lineno})"}


def run_task(task: Mapping[str, Any], *, renderer: Any, cache_dir: str | None) -> dict[str, Any]:
    """Run one task; return its row (metrics, or ``status="error"`` and the message).

    Parameters
    ----------
    task : mapping
        ``task_id``, ``index``, ``config``, ``scene``, ``noise``, ``range_noise``,
        ``seed``, ``method``, ``method_spec``, ``options``, ``crlb`` (see
        :class:`nearlight.evaluation.engine.sweep.Task`).
    renderer : Renderer
    cache_dir : str or None
        Render cache (shared by all workers).
    """
    row = blank_row()
    stage = "render"
    try:
        clean = renderer.render(task["scene"], cache_dir=None if cache_dir is None else Path(cache_dir))
        stage = "noise"
        capture = noisy_capture(clean, task)
        stage = "estimate"
        t0 = time.perf_counter()
        est = run_method(capture, task["method_spec"], task["options"])
        row["runtime_s"] = time.perf_counter() - t0
        row.update(estimate_columns(est))
        stage = "score"
        row.update(score(clean, est))
        stage = "crlb"
        row.update(_crlb(clean, task))
    except Exception as exc:  # a failing task is a row, not a crashed sweep
        return failed_row(row, stage, exc)
    return row
