"""Linear-Stokes fit of an analyzer stack with its residual (for tests and contact sheets).

The fit and the derived images are :mod:`nearlight.physics.polarization`'s; this adds the
per-angle residual and holds them together (amplitude, Imin, DoLP, AoLP).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..physics.polarization import aolp, analyzer_matrix, dolp, linear_amplitude, linear_stokes, separate_stokes


class StokesFit(NamedTuple):
    """Per-pixel least-squares fit; arrays ``[H, W, C]`` (``residual`` ``[K, H, W, C]``)."""

    S0: np.ndarray
    S1: np.ndarray
    S2: np.ndarray
    residual: np.ndarray

    @property
    def amplitude(self) -> np.ndarray:
        """``Imax − Imin = sqrt(S1² + S2²)``."""
        return linear_amplitude(self.S1, self.S2)

    @property
    def imin(self) -> np.ndarray:
        """``Imin = Id/2``."""
        return 0.5 * separate_stokes(self.S0, self.S1, self.S2)[1]

    @property
    def dolp(self) -> np.ndarray:
        return dolp(self.S0, self.amplitude)

    @property
    def aolp(self) -> np.ndarray:
        """Angle of linear polarization, radians in (−π/2, π/2], from the image horizontal."""
        return aolp(self.S1, self.S2)


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
