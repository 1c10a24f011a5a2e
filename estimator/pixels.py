"""Which pixels the nonlinear fits use."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import UserError
from .noise import CameraNoise, camera_noise, censored_pixels
from .observation import Observation
from ..physics.reflectance import any_channel, channel_sum


def fit_pixels(obs: Observation, *, max_pixels: int, saturation: float | None) -> np.ndarray:
    """Boolean ``[H, W]`` mask of the pixels a fit uses.

    Every surface pixel when there are at most ``max_pixels``; otherwise the
    ``max_pixels`` brightest (mean specular), which hold the lobe. Pixels with
    any specular channel at or above ``saturation`` are dropped.
    """
    use = obs.surface.copy()
    if saturation is not None:
        use &= ~any_channel(obs.specular >= saturation)
    n = int(use.sum())
    if n > max_pixels:
        lum = np.where(use, channel_sum(obs.specular) / 3, -np.inf).ravel()  # the mean, bit for bit
        keep = _brightest(lum, np.flatnonzero(use), max_pixels)
        use = np.zeros(lum.shape, bool)
        use[keep] = True
        use = use.reshape(obs.surface.shape)
    if int(use.sum()) < 10:
        raise UserError(f"specular: only {int(use.sum())} usable pixels for the fit (saturation={saturation})")
    return use


def _brightest(lum: np.ndarray, candidates: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``lum``'s ``k`` largest values, as ``np.argpartition(lum, -k)[-k:]`` picks them.

    ``lum`` is ``-inf`` outside ``candidates`` (more than ``k`` of them). When
    the ``k`` largest candidates are strictly above the rest, they are the
    only set ``argpartition`` can return, and partitioning the candidates
    alone finds them (640×480 board: ~1.5 ms against ~27 ms over the whole
    image); on a tie at the k-th value the whole image is partitioned as
    before, so that the same pixels win the tie.
    """
    vals = lum[candidates]
    part = np.argpartition(vals, -k)
    if vals[part[:-k]].max() < vals[part[-k:]].min():
        return candidates[part[-k:]]
    return np.argpartition(lum, -k)[-k:]


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
        kept = use & ~censored_pixels(capture, camera, obs.surface, judged=use)
        use = kept if int(kept.sum()) >= 10 else use
    return use, camera
