"""The specular image an estimate predicts, with the estimator's own forward model.

For plots (``nearlight estimate --plot``), the sanity rules
(:mod:`~nearlight.estimator.sanity`) and users' checks. The benchmark does not
grade with it: the evaluation's grading re-synthesis
(:mod:`nearlight.evaluation.scoring.independent_resynthesis`) is a second implementation, so that
a grade shares no code with the model it grades.
"""

from __future__ import annotations

import numpy as np

from ..capture import Capture
from ..errors import UserError
from .distant import distant_specular
from .geometry import surface_geometry
from .result import Estimate
from ..physics.reflectance import specular_radiance


def fitted_bsdf(estimate: Estimate) -> dict | None:
    """The lobe family's own parameters ``full`` fitted (``stages["full"]["bsdf"]``), or None (the estimate's
    Torrance–Sparrow ``ks`` and ``sigma`` are its lobe)."""
    stage = estimate.stages.get("full")
    return stage.get("bsdf") if isinstance(stage, dict) else None


def _point(P, N, camera, estimate: Estimate) -> np.ndarray:
    bsdf = fitted_bsdf(estimate) or {"model": "torrance_sparrow", "ks": estimate.ks, "sigma": estimate.sigma}
    return specular_radiance(P, N, camera, estimate.lamp_position, 1.0, bsdf)


def _distant(P, N, camera, estimate: Estimate) -> np.ndarray:
    lm = estimate.light_model
    light = np.asarray(lm["light_direction"], dtype=float)
    view = np.asarray(lm["view_direction"], dtype=float)
    return distant_specular(N, light, view, estimate.ks, estimate.sigma)


#: Forward models by ``Estimate.light_model["type"]``.
RENDERERS = {"point": _point, "distant": _distant}


def render_specular(capture: Capture, estimate: Estimate) -> np.ndarray:
    """The specular image an estimate predicts for the capture's geometry.

    Uses the capture's ``P`` and ``N`` (normals from ``P`` when absent) and the
    estimate's model: a point lamp of unit intensity at ``lamp_position`` with
    the lobe family ``full`` fitted (``stages["full"]["bsdf"]``), else
    Torrance–Sparrow ``ks`` (which absorbs the lamp intensity) and ``sigma``,
    or the distant baseline's light and view directions.

    Returns
    -------
    ndarray, shape (H, W, 3)
        Specular radiance, float64; 0 off the surface.
    """
    geometry = surface_geometry(capture)
    P, N, surface = geometry.P, geometry.N, geometry.surface
    out = np.zeros((capture.height, capture.width, 3))
    out[surface] = specular_at(P[surface], N[surface], np.asarray(capture.camera.position, dtype=float), estimate)
    return out


def specular_at(P: np.ndarray, N: np.ndarray, camera_position: np.ndarray, estimate: Estimate) -> np.ndarray:
    """:func:`render_specular` at some surface points only.

    Parameters
    ----------
    P, N : ndarray, shape (n, 3)
        Surface points (m) and their unit normals.
    camera_position : ndarray, shape (3,)
        Metres.
    estimate : Estimate

    Returns
    -------
    ndarray, shape (n, 3)
        Specular radiance, float64, finite (0 where the model has none).
    """
    kind = estimate.light_model.get("type", "point")
    if kind not in RENDERERS:
        raise UserError(f"estimate light_model.type: expected one of {', '.join(RENDERERS)}, got {kind!r}")
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return np.nan_to_num(RENDERERS[kind](P, N, camera_position, estimate))
