"""Which pixels the nonlinear fits use."""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from .observation import Observation


def fit_pixels(obs: Observation, *, max_pixels: int, saturation: float | None) -> np.ndarray:
    """Boolean ``[H, W]`` mask of the pixels a fit uses.

    Every surface pixel when there are at most ``max_pixels``; otherwise the
    ``max_pixels`` brightest (mean specular), which hold the lobe. Pixels with
    any specular channel at or above ``saturation`` are dropped.
    """
    use = obs.surface.copy()
    if saturation is not None:
        use &= ~np.any(obs.specular >= saturation, axis=-1)
    n = int(use.sum())
    if n > max_pixels:
        lum = np.where(use, obs.specular.mean(axis=-1), -np.inf).ravel()
        keep = np.argpartition(lum, -max_pixels)[-max_pixels:]
        use = np.zeros(lum.shape, bool)
        use[keep] = True
        use = use.reshape(obs.surface.shape)
    if int(use.sum()) < 10:
        raise UserError(f"specular: only {int(use.sum())} usable pixels for the fit (saturation={saturation})")
    return use
