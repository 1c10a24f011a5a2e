"""Linear Stokes parameters from an analyzer stack: the one least-squares fit.

Through an ideal analyzer at θ a pixel sees ``I(θ) = ½ (S0 + S1 cos 2θ +
S2 sin 2θ)``; in ``ideal`` mode this is ``Id/2 + Is cos²(θ − β)``, so
``Imax − Imin = sqrt(S1² + S2²) = Is`` and ``2·Imin = S0 − Is = Id`` (paper
§2.3). Used by the estimator's separation and the generator's checks and
contact sheets.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import UserError


def analyzer_matrix(angles_deg: Any) -> np.ndarray:
    """``[K, 3]`` rows ``½ (1, cos 2θ, sin 2θ)``: maps ``(S0, S1, S2)`` to the K analyzer images."""
    two_theta = 2.0 * np.radians(np.asarray(angles_deg, dtype=float))
    return 0.5 * np.stack([np.ones_like(two_theta), np.cos(two_theta), np.sin(two_theta)], axis=1)


def linear_stokes(stack: np.ndarray, angles_deg: Any) -> np.ndarray:
    """Per-pixel least-squares ``S0, S1, S2`` of an analyzer stack.

    Parameters
    ----------
    stack : ndarray, shape (K, ...)
        Radiance through the analyzer at each angle.
    angles_deg : array_like, shape (K,)
        Analyzer angles, degrees; at least 3 distinct (mod 180°).

    Returns
    -------
    ndarray, shape (3, ...)

    Raises
    ------
    UserError
        Fewer than 3 distinct angles (mod 180°): the fit is undetermined.
    """
    A = analyzer_matrix(angles_deg)
    if np.linalg.matrix_rank(A) < 3:
        raise UserError(
            "analyzer_angles_deg: separating polarization needs at least 3 distinct angles (mod 180°), "
            f"got {list(np.asarray(angles_deg).tolist())}"
        )
    stack = np.asarray(stack, dtype=float)
    return (np.linalg.pinv(A) @ stack.reshape(len(A), -1)).reshape(3, *stack.shape[1:])
