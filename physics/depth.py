"""What a range sensor reads: a depth with Gaussian noise, then quantised to its step.

The one home of this formula: the generator applies it to a render
(``generator.range_sensor.perturb_range``), the estimator simulates it from a
fitted surface to learn how its fit scatters under the staircase
(``estimator.whole_surface.staircase_cov``).

Numpy only; imports no pipeline stage.
"""

from __future__ import annotations

import numpy as np


def read_depth(depth: np.ndarray, *, noise: np.ndarray | float = 0.0, quantum_m: float = 0.0,
               offset_m: float = 0.0) -> np.ndarray:
    """The sensor's reading of ``depth`` (metres, any shape): ``depth + noise``, then rounded to the nearest level
    ``k·quantum_m + offset_m`` when ``quantum_m > 0``.

    Parameters
    ----------
    depth : ndarray
        True depth along the sensor's axis (the ray's length or ``z``), metres.
    noise : ndarray or float
        The noise drawn for each pixel (``σ·ξ``), metres, broadcast against ``depth``.
    quantum_m : float
        Step of the levels, metres (0: not quantised).
    offset_m : float
        Where the lattice of levels sits, in ``[0, quantum_m)``.
    """
    moved = np.asarray(depth, dtype=float) + noise
    if quantum_m > 0:
        moved = np.round((moved - offset_m) / quantum_m) * quantum_m + offset_m
    return moved
