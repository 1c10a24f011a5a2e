"""Linear-Stokes fit of an analyzer stack (for tests and contact sheets).

Through an ideal analyzer at θ, ``I(θ) = ½ (S0 + S1 cos 2θ + S2 sin 2θ)``; in
``ideal`` mode this is ``Id/2 + Is cos²(θ − β)``, so ``Imax − Imin = Is`` and
``2·Imin = Id`` (paper §2.3).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


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
    t = np.radians(np.asarray(angles_deg, float))
    A = 0.5 * np.stack([np.ones_like(t), np.cos(2 * t), np.sin(2 * t)], axis=1)  # [K, 3]
    flat = np.asarray(stack, float).reshape(len(t), -1)
    coef, *_ = np.linalg.lstsq(A, flat, rcond=None)
    residual = (flat - A @ coef).reshape(stack.shape)
    S0, S1, S2 = (c.reshape(stack.shape[1:]) for c in coef)
    return StokesFit(S0, S1, S2, residual)
