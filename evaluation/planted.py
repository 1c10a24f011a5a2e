"""Planted regressions: a built-in method made worse by a known amount, to test a regression check.

A regression check is only trusted when it catches a regression of known size
and stays quiet on a re-run with other seeds. :func:`further_along_ray` is a
plug-in method (``nearlight.evaluation.planted:further_along_ray``) that runs a
built-in estimator and moves its lamp a given fraction further along the ray
from the highlight. Run through a sweep under the built-in's own name (a
method entry ``{method: "nearlight.evaluation.planted:further_along_ray", name:
full, options: {base: full}}``), ``nearlight compare`` against a baseline of the real method must
flag it; ``benchmarks/bench_compare.py`` measures the smallest such bias it
catches. :func:`further_along_ray_every` does the same on every few seeds only (a
quarter of the cases of a suite with seeds 0 to 4k − 1, by default): a regression
of some cases, which a scorecard comparison must catch.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..capture import Capture
from ..estimator import Estimate, estimate
from .scoring.metrics import highlight_point


def further_along_ray(capture: Capture, *, base: str = "full", fraction: float = 0.02, **options: Any) -> Estimate:
    """Run method ``base`` on ``capture`` and move its lamp ``fraction`` of its distance further from the highlight.

    Parameters
    ----------
    capture : Capture
    base : str
        A built-in method name (not ``method``: that is the name of the plug-in itself in
        :func:`~nearlight.estimator.estimate`'s call).
    fraction : float
        Relative change of the highlight–lamp distance (0.02: 2 % further).
    **options
        Passed to ``base``.

    Returns
    -------
    Estimate
        The method's estimate with ``lamp_position = h + (1 + fraction)·(lamp − h)``, ``h`` the
        surface point where the estimated lamp's highlight lies (the centroid of the surface
        when the capture has no normals).
    """
    return moved_along_ray(capture, estimate(capture, method=base, **options), fraction)


def further_along_ray_every(capture: Capture, *, every: int = 4, base: str = "full", fraction: float = 0.02,
                            **options: Any) -> Estimate:  # fmt: skip
    """:func:`further_along_ray` on the captures whose camera-noise seed is a multiple of ``every``; method
    ``base`` unchanged on the others.

    The seed is the one the capture records with its camera noise (``meta["noise"]["camera"]["seed"]``,
    written by :func:`nearlight.generator.noise.add_camera_noise`), so the same cases are moved in every
    run, and on a suite whose noisy configurations have the seeds 0 to ``every·k − 1`` exactly one in
    ``every`` of them.

    Parameters
    ----------
    capture : Capture
        A capture with camera noise (one without has no seed to select by: ``ValueError``).
    every : int
        One seed in ``every`` is moved (≥ 1).
    base, fraction, **options
        As :func:`further_along_ray`.

    Returns
    -------
    Estimate
    """
    seed = capture.meta.get("noise", {}).get("camera", {}).get("seed")
    if seed is None:
        raise ValueError("further_along_ray_every: the capture records no camera-noise seed to select it by")
    if not (isinstance(every, int) and every >= 1):
        raise ValueError(f"further_along_ray_every: every: expected an integer >= 1, got {every!r}")
    est = estimate(capture, method=base, **options)
    return moved_along_ray(capture, est, fraction) if int(seed) % every == 0 else est


def moved_along_ray(capture: Capture, est: Estimate, fraction: float) -> Estimate:
    """A copy of ``est`` with each of its lamps ``fraction`` of its distance further from its highlight.

    Parameters
    ----------
    capture : Capture
        The capture ``est`` was made from (its ``P`` and ``N`` place the highlights).
    est : Estimate
    fraction : float

    Returns
    -------
    Estimate
        ``lamp_position = h + (1 + fraction)·(lamp − h)``, ``h`` as in :func:`further_along_ray`; every
        row of ``lamp_positions`` (an estimate of several lamps) likewise, each from its own highlight.
    """

    def moved(lamp: np.ndarray) -> np.ndarray:
        if capture.N is not None:
            origin = highlight_point(capture.P, capture.N, capture.camera.position, lamp)
        else:
            origin = np.nanmean(capture.P[capture.surface_mask], axis=0)
        return origin + (1.0 + fraction) * (lamp - origin)

    lamps = None if est.lamp_positions is None else np.array([moved(lamp) for lamp in est.lamp_positions])
    return dataclasses.replace(est, lamp_position=moved(np.asarray(est.lamp_position, dtype=float)),
                               lamp_positions=lamps)


def without_censoring(capture: Capture, **options: Any) -> Estimate:
    """Method ``full`` with its dark pixels fitted as separated: the revert of the censored likelihood.

    ``full`` measures the specular of pixels whose readings the sensor may have clipped at zero from
    those readings (:func:`~nearlight.estimator.censored.censored_specular`); before that it fitted
    them as separated, whose specular is biased upwards there. This plug-in finds no such pixel
    (:func:`~nearlight.estimator.noise.censored_pixels` replaced for the call), so every fitted pixel
    is fitted as separated. Replacing a module attribute is not thread-safe: run it in a sweep's worker
    processes, one task at a time per process, as the engine does.

    Parameters
    ----------
    capture : Capture
    **options
        ``full``'s options.
    """
    from unittest import mock

    from ..estimator import pixels

    def none_dark(capture: Any, noise: Any, surface: np.ndarray, **_: Any) -> np.ndarray:
        return np.zeros(surface.shape, bool)

    with mock.patch.object(pixels, "censored_pixels", none_dark):
        return estimate(capture, method="full", **options)
