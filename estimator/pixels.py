"""Which pixels the nonlinear fits use."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from ..errors import UserError
from .censored import censored_specular
from .noise import VarianceModel, camera_noise, censored_pixels, specular_variance, std_floor
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


class FitPixels(NamedTuple):
    """The pixels of a weighted fit and what it reads there (:func:`weighted_fit_pixels`).

    Attributes
    ----------
    use : ndarray of bool, shape (H, W)
        The fitted pixels.
    camera : VarianceModel or None
        The camera model weighing them (None: equal weights).
    specular : ndarray, shape (H, W, 3)
        The observation's specular, its dark fitted pixels measured from their readings.
    measured : ndarray of bool, shape (H, W)
        Those dark fitted pixels (:func:`~nearlight.estimator.censored.censored_specular`).
    measured_var : ndarray, shape (k, 3)
        Their specular's variance, in ``measured``'s raster order, radiance².
    measured_phase : ndarray, shape (k,)
        The phase (radians) their specular was measured along.
    """

    use: np.ndarray
    camera: VarianceModel | None
    specular: np.ndarray
    measured: np.ndarray
    measured_var: np.ndarray
    measured_phase: np.ndarray

    def variance(self, capture: Any, *, pixels: np.ndarray | None = None) -> np.ndarray:
        """:func:`~nearlight.estimator.noise.specular_variance` of :attr:`specular`, the measured pixels' own.

        ``pixels`` (default: every pixel) must hold every measured pixel.
        Returns shape (H, W, 3), or (n, 3) for the ``n`` pixels asked.
        """
        var = specular_variance(capture, self.specular, self.camera, pixels=pixels)
        if self.measured.any():
            floor = std_floor(self.specular) ** 2  # specular_variance's
            var[self.measured if pixels is None else self.measured[pixels]] = np.maximum(self.measured_var, floor)
        return var


def weighted_fit_pixels(capture: Any, obs: Observation, *, noise: str, max_pixels: int,
                        saturation: float | None) -> FitPixels:
    """The pixels of a fit weighted by ``noise`` (``"auto"`` or ``"none"``), the camera model weighing them,
    and the specular it reads there.

    :func:`fit_pixels`; with ``noise="auto"`` the capture's camera
    (:func:`~nearlight.estimator.noise.camera_noise`, None when it has none).
    The dark pixels among them, whose readings the sensor may have clipped at
    zero (:func:`~nearlight.estimator.noise.censored_pixels`), are measured
    from their readings by a censored likelihood
    (:func:`~nearlight.estimator.censored.censored_specular`) instead of the
    separation, whose specular is biased there; those it cannot measure (no
    neighbour with a level, no convergence) are left out, unless fewer than
    10 pixels would be left (then all of :func:`fit_pixels`'s, as separated;
    docs/measurements/estimator-choices.md, "Dark pixels").

    Returns
    -------
    FitPixels
    """
    use = fit_pixels(obs, max_pixels=max_pixels, saturation=saturation)
    camera = camera_noise(capture, surface=obs.surface) if noise == "auto" else None
    none = np.zeros(use.shape, bool)
    plain = FitPixels(use, camera, obs.specular, none, np.zeros((0, 3)), np.zeros(0))
    if camera is None:
        return plain
    dark = censored_pixels(capture, camera, obs.surface, judged=use)
    if not dark.any():
        return plain
    out = censored_specular(capture, camera, dark, obs.surface)
    rows, cols = np.nonzero(dark)
    kept = use & ~dark
    kept[rows[out.ok], cols[out.ok]] = True
    if int(kept.sum()) < 10:
        return plain
    measured = np.zeros(use.shape, bool)
    measured[rows[out.ok], cols[out.ok]] = True
    specular = obs.specular.copy()
    specular[measured] = out.values[out.ok]
    # dark's raster order, kept by the ok ones: measured's
    return FitPixels(kept, camera, specular, measured, out.variance[out.ok], out.phase[out.ok])

