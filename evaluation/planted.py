"""Planted regressions: a built-in method made worse by a known amount, to test a regression check.

A regression check is only trusted when it catches a regression of known size
and stays quiet on a re-run with other seeds. :func:`further_along_ray` is a
plug-in method (``nearlight.evaluation.planted:further_along_ray``) that runs a
built-in estimator and moves its lamp a given fraction further along the ray
from the highlight. Run through a sweep under the built-in's own name (a
method entry ``{method: "nearlight.evaluation.planted:further_along_ray", name:
full}``), ``nearlight compare`` against a baseline of the real method must
flag it; ``benchmarks/bench_compare.py`` measures the smallest such bias it
catches.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..capture import Capture
from ..estimator import Estimate, estimate
from .scoring.metrics import highlight_point


def further_along_ray(capture: Capture, *, method: str = "full", fraction: float = 0.02, **options: Any) -> Estimate:
    """Run ``method`` on ``capture`` and move its lamp ``fraction`` of its distance further from the highlight.

    Parameters
    ----------
    capture : Capture
    method : str
        A built-in method name.
    fraction : float
        Relative change of the highlight–lamp distance (0.02: 2 % further).
    **options
        Passed to ``method``.

    Returns
    -------
    Estimate
        The method's estimate with ``lamp_position = h + (1 + fraction)·(lamp − h)``, ``h`` the
        surface point where the estimated lamp's highlight lies (the centroid of the surface
        when the capture has no normals).
    """
    return moved_along_ray(capture, estimate(capture, method=method, **options), fraction)


def moved_along_ray(capture: Capture, est: Estimate, fraction: float) -> Estimate:
    """A copy of ``est`` with its lamp ``fraction`` of its distance further from the highlight.

    Parameters
    ----------
    capture : Capture
        The capture ``est`` was made from (its ``P`` and ``N`` place the highlight).
    est : Estimate
    fraction : float

    Returns
    -------
    Estimate
        ``lamp_position = h + (1 + fraction)·(lamp − h)``, ``h`` as in :func:`further_along_ray`.
    """
    lamp = np.asarray(est.lamp_position, dtype=float)
    if capture.N is not None:
        origin = highlight_point(capture.P, capture.N, capture.camera.position, lamp)
    else:
        origin = np.nanmean(capture.P[capture.surface_mask], axis=0)
    return dataclasses.replace(est, lamp_position=origin + (1.0 + fraction) * (lamp - origin))
