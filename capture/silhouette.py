"""Do the image and the range agree? A mirrored depth map found by the object's silhouette.

A depth map stored upside down (its rows in the other order) or mirrored left
to right, but back-projected with the right intrinsics, gives a ``P`` whose
rays go through their pixels: :func:`nearlight.estimator.geometry.check_rays`
cannot see it. What it does change is *where* the object is in the range: its
silhouette there (pixels with a valid depth, finite ``P``) is the image's
silhouette (pixels with signal) mirrored. This module compares the two masks
as stored and with the range flipped up/down, left/right and both (180°), by
two overlaps: the fraction of the image's signal pixels that have a range
(a lamp lights only part of a sphere: its shadowed side has range and no
signal, so this one is high for a good capture) and the intersection over
union (IoU) of the masks; it calls the geometry mirrored when a flip fits
clearly better in either (:data:`FLIP_MIN_COVER`, :data:`FLIP_MARGIN`).

Not seen, by design (the check never refuses these): an object filling the
whole image (a board larger than the view: no silhouette, every mask the
same), an image with signal nearly everywhere (a lit background), a silhouette
symmetric under the flip (a centred sphere: then every flip fits alike), and a
range mask that is nearly empty or full. Thresholds, measured on the rig
simulator's round trips and their flipped versions: ``docs/rig-files.md``
("The depth map and the image must agree").
"""

from __future__ import annotations

import numpy as np

from ..errors import UserError

#: The luminance range :func:`signal_mask` splits, in decades below the image's 99.9th percentile (darker: background).
SIGNAL_DECADES = 3.0
#: A flip must give a valid range to at least this fraction of the image's signal pixels to be called a better fit.
FLIP_MIN_COVER = 0.5
#: ... and beat the range as stored by at least this much, in that fraction or in the masks' IoU.
FLIP_MARGIN = 0.15
#: Masks covering less or more than these fractions of the image are no silhouette: no check.
MIN_COVER, MAX_COVER = 0.01, 0.97
#: The flips compared, by the name messages use.
FLIPS = {"up/down": (slice(None, None, -1), slice(None)),
         "left/right": (slice(None), slice(None, None, -1)),
         "up/down and left/right": (slice(None, None, -1), slice(None, None, -1))}  # fmt: skip


def signal_mask(lum: np.ndarray) -> np.ndarray:
    """``[H, W]`` bool: the pixels with signal, by Otsu's threshold on the log luminance.

    The luminance (NaN and values <= 0 as the darkest) is taken in decades,
    clipped to :data:`SIGNAL_DECADES` below the 99.9th percentile (the
    background's read noise and exact zeros fall together at that floor), and split where the
    two classes' between-class variance is largest (Otsu, 256 bins): the
    background (read noise, or 0) from the object (diffuse light, decades
    above it). A strong highlight does not move the split (a threshold at a
    fraction of the brightest pixels would cut a sphere down to its highlight).
    """
    lum = np.where(np.isfinite(lum), lum, 0.0)
    top = float(np.percentile(lum, 99.9)) if lum.size else 0.0
    if not top > 0:
        return np.zeros(lum.shape, bool)
    x = np.log10(np.maximum(lum, top * 10.0**-SIGNAL_DECADES))
    hist, edges = np.histogram(x, bins=256)
    w = np.cumsum(hist).astype(float)
    m = np.cumsum(hist * (edges[:-1] + edges[1:]) / 2)
    n, total = w[-1], m[-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        between = (total * w / n - m) ** 2 / (w * (n - w))
    between[~np.isfinite(between)] = -1.0
    return x > edges[int(np.argmax(between)) + 1]


def _cover(sig: np.ndarray, valid: np.ndarray) -> float:
    n = np.count_nonzero(sig)
    return np.count_nonzero(sig & valid) / n if n else 1.0


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 1.0


def silhouette_overlap(lum: np.ndarray, valid: np.ndarray, *, measure: str = "cover") -> dict[str, float]:
    """How well the range's silhouette holds the image's, as stored and flipped.

    Parameters
    ----------
    lum : ndarray, shape (H, W)
        Luminance of the image (any scale; NaN: no signal).
    valid : ndarray, shape (H, W), bool
        Pixels with a valid range (finite ``P``).
    measure : {"cover", "iou"}
        ``cover`` (what :func:`mirrored` decides by): the fraction of the
        image's signal pixels (:func:`signal_mask`) that have a valid range;
        ``iou``: intersection over union of the two masks (for comparison: a
        lamp lights only part of a sphere, so the sphere's shadowed side has
        range and no signal, and its IoU is low however the range is stored).

    Returns
    -------
    dict
        ``"as stored"`` and each of :data:`FLIPS`: the measure, 0 to 1.
    """
    sig = signal_mask(lum)
    valid = np.asarray(valid, bool)
    f = _cover if measure == "cover" else _iou
    out = {"as stored": f(sig, valid)}
    out.update({name: f(sig, valid[idx]) for name, idx in FLIPS.items()})
    return out


def mirrored(lum: np.ndarray, valid: np.ndarray) -> tuple[str, float, float] | None:
    """The flip of the range that holds the image's silhouette clearly better than as stored, or None.

    Returns
    -------
    (flip, cover_flipped, cover_as_stored) or None
        The fractions of the image's signal pixels with a valid range
        (:func:`silhouette_overlap`). None when either mask covers less than
        :data:`MIN_COVER` or more than :data:`MAX_COVER` of the image (no
        silhouette: an object filling the view, a lit background), or when no
        flip reaches :data:`FLIP_MIN_COVER` and beats the range as stored by
        :data:`FLIP_MARGIN` in that fraction or in the IoU.
    """
    valid = np.asarray(valid, bool)
    sig = signal_mask(lum)
    for m in (sig, valid):
        if not MIN_COVER <= m.mean() <= MAX_COVER:
            return None
    cover, iou = silhouette_overlap(lum, valid), silhouette_overlap(lum, valid, measure="iou")
    gain = {flip: max(cover[flip] - cover["as stored"], iou[flip] - iou["as stored"]) for flip in FLIPS}
    flip = max(gain, key=gain.get)
    if cover[flip] >= FLIP_MIN_COVER and gain[flip] >= FLIP_MARGIN:
        return flip, cover[flip], cover["as stored"]
    return None


#: :func:`check_silhouette` looks at a lattice of about this many pixels (every pixel up to 2 x this many).
CHECK_PIXELS = 20_000


def lattice(height: int, width: int, pixels: int = CHECK_PIXELS) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of a lattice of about ``pixels`` pixels, centred, so that a flip maps it onto itself
    (to within one pixel)."""
    step = max(1, int(np.sqrt(height * width / pixels)))

    def axis(n: int) -> np.ndarray:
        k = (n - 1) // step + 1
        return np.arange(k) * step + (n - 1 - (k - 1) * step) // 2

    return axis(height), axis(width)


def capture_luminance(capture, rows: np.ndarray | None = None, cols: np.ndarray | None = None) -> np.ndarray | None:
    """``[h, w]``: a capture's mean analyzer image (or its diffuse + specular) on the lattice ``rows`` x ``cols``
    (default every pixel); None without either."""
    at = np.ix_(np.arange(capture.height) if rows is None else rows, np.arange(capture.width) if cols is None else cols)
    if capture.stack is not None:
        return np.nanmean(np.asarray(capture.stack[(slice(None), *at)], float), axis=(0, -1))
    if capture.diffuse is None:  # a specular image alone is the highlight, not the object
        return None
    imgs = [np.asarray(i[at], float) for i in (capture.diffuse, capture.specular) if i is not None]
    return np.nansum(imgs, axis=0).mean(axis=-1)


def check_silhouette(capture) -> None:
    """Raise :class:`~nearlight.errors.UserError` when ``P`` is the image's geometry mirrored (:func:`mirrored`),
    judged on a lattice of about :data:`CHECK_PIXELS` pixels (a 640x480 capture: every 3rd row and column)."""
    rows, cols = lattice(capture.height, capture.width)
    lum = capture_luminance(capture, rows, cols)
    if lum is None:
        return
    found = mirrored(lum, capture.surface_mask[np.ix_(rows, cols)])
    if found is not None:
        flip, best, base = found
        raise UserError(
            f"{capture.name}: channel P: the range is mirrored relative to the image: its silhouette matches the "
            f"image's flipped {flip} ({100 * best:.0f} % of the pixels with signal have a range, {100 * base:.0f} % as stored); flip the depth map "
            f"{flip} where the capture was made"
        )
