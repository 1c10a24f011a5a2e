"""A range sensor's error on a capture's ``P``: Gaussian noise and quantisation, along the ray or the optical axis.

Two kinds of sensor store their range differently, and their errors differ
in direction as well as kind:

* a light-stripe or time-of-flight sensor measures the **distance along each
  ray** (the generator's ``range.quantum_m`` and ``range_noise`` are of that
  kind);
* a depth map (a 16-bit PNG in millimetres, an RGB-D camera) stores the
  **depth along the optical axis**, ``z``: its steps are planes ``z = k·q``
  across the view, a staircase on any surface slanted to it.

Either way the error moves a point along its own ray: a range sensor's
pixel sees the same surface point's direction, whatever its depth error.
The quantisation grid's offset (where ``k·q`` falls on the surface) is
drawn per seed, so that a study over seeds averages over it rather than
over one fixed staircase.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ..capture import Capture
from ..physics.depth import read_depth
from .noise import _with_noise, noise_rngs, with_range_sensor

AXES = ("ray", "z")


def perturb_range(capture: Capture, *, sigma_m: float = 0.0, quantum_m: float = 0.0,
                  axis: Literal["ray", "z"] = "ray", seed: int = 0) -> Capture:
    """A copy of ``capture`` whose ``P`` carries a range sensor's error (and no ``N``).

    Parameters
    ----------
    capture : Capture
        Needs ``camera.to_world`` for ``axis="z"`` (its third column is the optical axis).
    sigma_m : float
        Standard deviation of Gaussian noise along ``axis``, metres, ≥ 0.
    quantum_m : float
        Quantisation step along ``axis``, metres (0: none), applied after the noise.
    axis : {"ray", "z"}
        Distance along each ray, or depth along the optical axis.
    seed : int
        Draws from ``noise_rngs(seed)[1]`` (the range stream): the noise, then the grid's offset in ``[0, q)``.

    Returns
    -------
    Capture
        ``P`` moved along each ray (float32, as the generator writes it); ``N`` None with the exact normals
        in ``extra["truth_N"]``; ``meta["noise"]["range"]`` records the settings and the offset drawn;
        ``rig.range`` states them (``source`` ``"renderer"``).
    """
    if axis not in AXES:
        raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
    if sigma_m < 0 or quantum_m < 0:
        raise ValueError(f"sigma_m and quantum_m must be >= 0, got {sigma_m}, {quantum_m}")
    if sigma_m == 0 and quantum_m == 0:
        return capture
    cam = np.asarray(capture.camera.position, dtype=float)
    rel = np.asarray(capture.P, dtype=float) - cam
    if axis == "z":
        if capture.camera.to_world is None:
            raise ValueError("axis='z' needs camera.to_world (the optical axis)")
        depth = rel @ np.asarray(capture.camera.to_world, dtype=float)[:3, 2]
    else:
        depth = np.linalg.norm(rel, axis=-1)
    _, rng = noise_rngs(seed)
    noise = rng.normal(0.0, sigma_m, size=depth.shape) if sigma_m > 0 else 0.0
    offset = float(rng.uniform(0.0, quantum_m)) if quantum_m > 0 else 0.0
    moved = read_depth(depth, noise=noise, quantum_m=quantum_m, offset_m=offset)
    with np.errstate(invalid="ignore", divide="ignore"):
        P = (cam + rel * (moved / depth)[..., None]).astype(np.float32)
    extra = dict(capture.extra)
    if capture.N is not None:
        extra["truth_N"] = capture.N
    record = {"sigma_m": float(sigma_m), "quantum_m": float(quantum_m), "axis": axis, "offset_m": offset,
              "seed": int(seed), "normals": "dropped"}
    out = capture.replace(P=P, N=None, extra=extra, meta=_with_noise(capture.meta, "range", record))
    return with_range_sensor(out, sigma_m=sigma_m, quantum_m=quantum_m, axis=axis, source="renderer")
