"""Highlight segmentation: how many separate highlights a specular image has, and which pixels are whose.

:func:`segment_highlights` splits the smoothed specular image at dips (a
local maximum is a highlight of its own when every path to a brighter one
dips by :data:`HIGHLIGHT_DIP` of its height), then gives every bright pixel
to a peak by a watershed. ``full`` with several lamps starts one lamp at each
highlight (:mod:`nearlight.estimator.several`); every one-lamp method's
estimate carries :func:`several_highlights_warning` when there are several
(:func:`nearlight.estimator.estimate`), and the paper's ray stage names them
when its search fails (:func:`nearlight.estimator.first_stage.ray_stage`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage

from .observation import Observation, shared
from ..physics.reflectance import channel_sum

#: Smoothing of the specular image before segmentation, pixels (Gaussian σ): averages
#: ~ 2π·1.5² ≈ 14 pixels, so camera noise on a lobe's flank does not make local maxima,
#: while lobes a few pixels wide keep their peaks.
SMOOTH_PX = 1.5
#: A local maximum is a highlight of its own when every path to a brighter one dips by at least
#: HIGHLIGHT_DIP of its height and HIGHLIGHT_DIP_ABS of the brightest: two equal Torrance–Sparrow
#: lobes (σ = 0.1) of lamps 30° apart dip by 40 % between them (scenes/two_lamps.yaml), and the
#: absolute part is ≥ 8 standard deviations of the smoothed specular's camera noise at the
#: benchmarks' high noise (5000 e full well: ~3 % of the peak per pixel after separation, / 5
#: by the smoothing), so noise on one lobe's flank makes no highlight.
HIGHLIGHT_DIP = 0.2
HIGHLIGHT_DIP_ABS = 0.05
#: Dip levels are rounded down to multiples of this fraction of the brightest (at most 1/LEVEL_STEP
#: labellings of the image however many noisy candidates; rounding down only merges more).
LEVEL_STEP = 0.005
#: Faintest highlight, fraction of the brightest (the observation's specular mask threshold).
HIGHLIGHT_FLOOR = 0.05


class Highlights(NamedTuple):
    """Separate specular highlights of one observation, brightest first.

    Attributes
    ----------
    peaks : list of tuple of int
        (row, column) of each highlight's brightest smoothed pixel.
    heights : ndarray, shape (k,)
        Smoothed mean specular at each peak (radiance).
    labels : ndarray, shape (H, W), int
        ``i + 1`` on pixels of highlight ``i`` (watershed of the smoothed
        image from the peaks), 0 elsewhere (off the surface or below the floor).
    """

    peaks: list[tuple[int, int]]
    heights: np.ndarray
    labels: np.ndarray


def segment_highlights(specular: np.ndarray, located: np.ndarray, *, smooth_px: float = SMOOTH_PX,
                       dip: float = HIGHLIGHT_DIP, dip_abs: float = HIGHLIGHT_DIP_ABS,
                       floor: float = HIGHLIGHT_FLOOR) -> Highlights:
    """Split a specular image into separate highlights (lobes).

    The mean specular over the channels is smoothed with a Gaussian
    normalised over ``located`` pixels (no darkening at the surface's edge);
    its local maxima above ``floor`` × the brightest are candidates, brightest
    first. A candidate is a highlight when the connected component of
    ``{smoothed ≥ its height − max(dip × its height, dip_abs × brightest)}``
    that holds it contains no brighter candidate (its topographic prominence
    is at least that; the level rounded down to :data:`LEVEL_STEP`). Pixels
    are assigned to highlights by a watershed of the smoothed
    image from the peaks (:func:`scipy.ndimage.watershed_ift`).

    Parameters
    ----------
    specular : ndarray, shape (H, W, 3)
        Specular radiance.
    located : ndarray, shape (H, W), bool
        Pixels with a surface point.
    smooth_px, dip, dip_abs, floor : float
        See :data:`SMOOTH_PX`, :data:`HIGHLIGHT_DIP`, :data:`HIGHLIGHT_DIP_ABS`, :data:`HIGHLIGHT_FLOOR`.

    Returns
    -------
    Highlights
        At least one highlight when any located pixel is positive.
    """
    s, top, peaks = _highlight_peaks(specular, located, smooth_px=smooth_px, dip=dip, dip_abs=dip_abs, floor=floor)
    if not top > 0:
        return Highlights([], np.zeros(0), np.zeros(s.shape, int))
    markers = np.zeros(s.shape, np.int16)
    for i, p in enumerate(peaks):
        markers[p] = i + 1
    bright = located & (s >= floor * top)
    markers[~bright] = -1
    depth = np.round(65535.0 * (1.0 - np.clip(s / top, 0.0, 1.0))).astype(np.uint16)
    labels = np.where(bright, ndimage.watershed_ift(depth, markers), 0)
    return Highlights(peaks, np.array([s[p] for p in peaks]), labels)


def _highlight_peaks(specular: np.ndarray, located: np.ndarray, *, smooth_px: float = SMOOTH_PX,
                     dip: float = HIGHLIGHT_DIP, dip_abs: float = HIGHLIGHT_DIP_ABS, floor: float = HIGHLIGHT_FLOOR) -> tuple[np.ndarray, float, list[tuple[int, int]]]:
    """:func:`segment_highlights`' smoothed image and peaks, without assigning the pixels to them.

    Returns
    -------
    s : ndarray, shape (H, W)
        Mean specular over the channels, smoothed, 0 off ``located``.
    top : float
        Its largest value.
    peaks : list of tuple of int
        (row, column) of each highlight's peak, brightest first; empty unless ``top > 0``.
    """
    lum = np.where(located, np.nan_to_num(channel_sum(specular) / 3), 0.0)  # the mean, bit for bit
    weight = ndimage.gaussian_filter(located.astype(float), smooth_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(located & (weight > 0), ndimage.gaussian_filter(lum, smooth_px) / weight, 0.0)
    top = float(s.max())
    if not top > 0:
        return s, top, []
    is_max = (s == ndimage.maximum_filter(s, size=3)) & located & (s >= floor * top)
    rows, cols = np.nonzero(is_max)
    order = np.lexsort((cols, rows, -s[rows, cols]))  # brightest first, ties by position
    candidates = [(int(rows[i]), int(cols[i])) for i in order]
    peaks: list[tuple[int, int]] = []
    components: dict[int, np.ndarray] = {}  # by level, in steps of LEVEL_STEP × top (rounded down: conservative)
    for rank, (r, c) in enumerate(candidates):
        level = int(np.floor((s[r, c] - max(dip * s[r, c], dip_abs * top)) / (LEVEL_STEP * top)))
        if level not in components:
            components[level] = ndimage.label(located & (s >= level * LEVEL_STEP * top))[0]
        comp = components[level]
        here = comp[r, c]
        if not any(comp[p] == here for p in candidates[:rank]):
            peaks.append((r, c))
    return s, top, peaks


def highlights_of(obs: Observation) -> Highlights:
    """:func:`segment_highlights` of an observation's specular image over its located pixels."""
    return segment_highlights(obs.specular, obs.located)


def several_highlights_warning(obs: Observation) -> str | None:
    """The warning of a one-lamp method on an observation with several separate highlights, else None.

    Counts :func:`highlights_of`'s peaks without its watershed (which pixels belong to each); once per
    observation inside :func:`~nearlight.estimator.observation.shared_observations` (the method and the sanity
    rules both ask).
    """
    return shared(_several_highlights_warning, obs)


def _several_highlights_warning(obs: Observation) -> str | None:
    """:func:`several_highlights_warning`, made afresh."""
    n = len(_highlight_peaks(obs.specular, obs.located)[2])
    if n < 2:
        return None
    return f"{n} separate highlights: this method fits one lamp; try lamps=auto"
