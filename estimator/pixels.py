"""Which pixels the nonlinear fits use."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import UserError
from .noise import CameraNoise, camera_noise, censored_pixels
from .observation import Observation
from ..physics.reflectance import channel_sum


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
        lum = np.where(use, channel_sum(obs.specular) / 3, -np.inf).ravel()  # the mean, bit for bit
        keep = np.argpartition(lum, -max_pixels)[-max_pixels:]
        use = np.zeros(lum.shape, bool)
        use[keep] = True
        use = use.reshape(obs.surface.shape)
    if int(use.sum()) < 10:
        raise UserError(f"specular: only {int(use.sum())} usable pixels for the fit (saturation={saturation})")
    return use


def weighted_fit_pixels(capture: Any, obs: Observation, *, noise: str, max_pixels: int,
                        saturation: float | None) -> tuple[np.ndarray, CameraNoise | None]:
    """The pixels of a fit weighted by ``noise`` (``"auto"`` or ``"none"``), and the camera model weighing them.

    :func:`fit_pixels`; with ``noise="auto"`` the capture's camera
    (:func:`~nearlight.estimator.noise.camera_noise`, None when it has none)
    and without the dark pixels it may have clipped at zero
    (:func:`~nearlight.estimator.noise.censored_pixels`), unless fewer than
    10 pixels would be left (then all of :func:`fit_pixels`'s).

    Returns
    -------
    use : ndarray of bool, shape (H, W)
    camera : CameraNoise or None
    """
    use = fit_pixels(obs, max_pixels=max_pixels, saturation=saturation)
    camera = camera_noise(capture, surface=obs.surface) if noise == "auto" else None
    if camera is not None:
        kept = use & ~censored_pixels(capture, camera, obs.surface)
        use = kept if int(kept.sum()) >= 10 else use
    return use, camera
