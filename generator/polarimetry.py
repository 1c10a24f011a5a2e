"""Linear-Stokes fit of an analyzer stack with its residual (for tests and contact sheets).

The fit itself is :func:`nearlight.physics.polarization.linear_stokes`; this adds the
per-angle residual and the derived images (amplitude, Imin, DoLP, AoLP).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..physics.polarization import analyzer_matrix, linear_stokes


class StokesFit(NamedTuple):
    """Per-pixel least-squares fit; arrays ``[H, W, C]`` (``residual`` ``[K, H, W, C]``)."""

    S0: np.ndarray
    S1: np.ndarray
    S2: np.ndarray
    residual: np.ndarray

    @property
    def amplitude(self) -> np.ndarray:
        """``Imax − Imin = sqrt(S1² + S2²)``."""
        return np.hypot(self.S1, self.S2)

    @property
    def imin(self) -> np.ndarray:
        return 0.5 * (self.S0 - self.amplitude)

    @property
    def dolp(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.S0 > 0, self.amplitude / self.S0, 0.0)

    @property
    def aolp(self) -> np.ndarray:
        """Angle of linear polarization, radians in (−π/2, π/2], from the image horizontal."""
        return 0.5 * np.arctan2(self.S2, self.S1)


def fit_stokes(stack: np.ndarray, angles_deg: np.ndarray) -> StokesFit:
    """Fit ``½ (S0 + S1 cos 2θ + S2 sin 2θ)`` to every pixel of ``stack``.

    Parameters
    ----------
    stack : ndarray, shape (K, H, W, C)
    angles_deg : ndarray, shape (K,)
        At least three distinct angles (mod 180°).

    Returns
    -------
    StokesFit
    """
    stack = np.asarray(stack, float)
    S = linear_stokes(stack, angles_deg)
    residual = stack - np.tensordot(analyzer_matrix(angles_deg), S, axes=1)
    return StokesFit(S[0], S[1], S[2], residual)
