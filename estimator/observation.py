"""What every method starts from: the specular image, geometry and highlight.

:func:`observe` validates an in-memory :class:`~nearlight.capture.Capture`
(files are validated by :func:`nearlight.capture.read_capture`), separates the
analyzer stack when there is no ``specular`` image, derives normals from ``P``
when ``N`` is absent, and finds the specular mask and the peak pixel. It never
reads ``capture.truth``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from nearlight.capture import Capture
from nearlight.errors import UserError
from nearlight.estimator.normals import normals_from_positions
from nearlight.estimator.separation import separate
from nearlight.reflectance import normalize

#: Fewest specular pixels the regressions and fits accept.
MIN_SPECULAR_PIXELS = 10


@dataclasses.dataclass(frozen=True)
class Observation:
    """A capture reduced to what the estimators use (float64, world frame, metres).

    Attributes
    ----------
    specular : ndarray, shape (H, W, 3)
        Specular radiance (separated or given); 0 off the surface.
    P, N : ndarray, shape (H, W, 3)
        Positions and unit normals; NaN off the surface.
    V : ndarray, shape (H, W, 3)
        Unit vectors from the surface to the camera.
    cos_r : ndarray, shape (H, W)
        cos θr = N·V.
    surface : ndarray, shape (H, W), bool
        Pixels with a finite position and normal facing the camera.
    mask : ndarray, shape (H, W), bool
        Specular pixels: surface, every channel > 0, mean ≥ ``threshold`` ×
        peak, and not an isolated hot pixel (> 2 × its 3×3 median).
    peak : tuple of int
        (row, column) of the brightest mean specular, isolated hot pixels
        excluded (see :func:`_spikes`, :func:`_peak_pixel`). A discrete
        choice: it stays put under float rounding (pixels within
        :data:`PEAK_TIE` of the maximum are tied and resolved by position),
        but jumps where a pixel's brightness crosses that band.
    camera_position : ndarray, shape (3,)
    scale : float
        Distance from the camera to the peak's surface point, metres: the
        capture's length scale, from which method defaults are derived.
    """

    specular: np.ndarray
    P: np.ndarray
    N: np.ndarray
    V: np.ndarray
    cos_r: np.ndarray
    surface: np.ndarray
    mask: np.ndarray
    peak: tuple[int, int]
    camera_position: np.ndarray
    scale: float

    @property
    def peak_point(self) -> np.ndarray:
        """Surface point of the peak pixel, shape (3,)."""
        return self.P[self.peak]


def _check_shapes(capture: Capture) -> None:
    name, hw = capture.name, (capture.height, capture.width)
    if np.shape(capture.P) != (*hw, 3):
        raise UserError(f"{name}: channel P: shape {np.shape(capture.P)}, expected {(*hw, 3)} (height x width x 3)")
    for key in ("N", "specular", "diffuse"):
        img = getattr(capture, key)
        if img is not None and np.shape(img) != (*hw, 3):
            raise UserError(f"{name}: channel {key}: shape {np.shape(img)}, expected {(*hw, 3)}")
    if capture.stack is not None:
        k = 0 if capture.analyzer_angles_deg is None else len(capture.analyzer_angles_deg)
        if np.shape(capture.stack) != (k, *hw, 3):
            raise UserError(
                f"{name}: channels pol<k>: stack shape {np.shape(capture.stack)} does not match "
                f"{k} analyzer angles x {hw[0]} x {hw[1]} x 3"
            )


def surface_geometry(capture: Capture) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``P, N, V, cos_r, surface`` of a capture (normals from ``P`` when ``N`` is absent)."""
    _check_shapes(capture)
    cam = np.asarray(capture.camera.position, dtype=float)
    P = np.asarray(capture.P, dtype=float)
    if capture.N is not None:
        N = normalize(np.asarray(capture.N, dtype=float))
    else:
        N = normals_from_positions(P, cam)
    finite = np.all(np.isfinite(P), axis=-1) & np.all(np.isfinite(N), axis=-1)
    V = normalize(cam - np.where(finite[..., None], P, 0.0))
    cos_r = np.where(finite, np.sum(np.where(finite[..., None], N, 0.0) * V, axis=-1), 0.0)
    surface = finite & (cos_r > 0)
    return P, N, V, cos_r, surface


def specular_image(capture: Capture, *, separation: str = "fit") -> np.ndarray:
    """The capture's specular image ``[H, W, 3]``: given, or separated from the stack."""
    _check_shapes(capture)
    if capture.specular is not None:
        spec, channel = np.asarray(capture.specular, dtype=float), "specular"
    elif capture.stack is not None:
        spec = separate(capture.stack, capture.analyzer_angles_deg, method=separation)
        spec, channel = spec[0], "pol<k>"
    else:
        raise UserError(f"{capture.name}: no image: expected pol<k>.R/G/B channels or specular.R/G/B")
    surface = capture.surface_mask
    bad = surface & ~np.all(np.isfinite(spec), axis=-1)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise UserError(f"{capture.name}: channel {channel}: NaN or Inf at surface pixel (row {i}, column {j})")
    return spec


def _spikes(lum: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """Isolated hot pixels: more than twice the 3×3 median of their neighbourhood."""
    from scipy.ndimage import median_filter

    med = median_filter(np.where(surface, lum, 0.0), size=3, mode="nearest")
    return surface & (lum > 2.0 * np.maximum(med, 0.0))


#: Pixels within this fraction of the brightest count as sharing the maximum
#: (:func:`_peak_pixel`): 2⁻¹⁹ ≈ 1.9e-6, i.e. 16 float32 ulps, so that two
#: pixels equal but for float rounding (a symmetric scene's mirror-image
#: peaks, rendered on two machines) do not flip the peak with the last bits.
PEAK_TIE = 2.0**-19


def _peak_pixel(lum: np.ndarray, usable: np.ndarray) -> tuple[int, int]:
    """Brightest usable pixel; when several share the maximum to within
    :data:`PEAK_TIE` (a clipped highlight, mirror-image peaks), the one
    nearest their centroid, then the first in row-major order."""
    value = np.where(usable, lum, -np.inf)
    top = value >= value.max() - PEAK_TIE * abs(value.max())
    rows, cols = np.nonzero(top)
    if len(rows) == 1:
        return int(rows[0]), int(cols[0])
    k = int(np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2))
    return int(rows[k]), int(cols[k])


def observe(capture: Capture, *, separation: str = "fit", threshold: float = 0.05) -> Observation:
    """Reduce a capture to an :class:`Observation`.

    Parameters
    ----------
    capture : Capture
    separation : {"fit", "projected", "maxmin"}, optional
        How to separate an analyzer stack (ignored when the capture has a
        ``specular`` image).
    threshold : float, optional
        Specular mask threshold, as a fraction of the peak pixel's mean
        specular radiance.

    Raises
    ------
    UserError
        Shapes that disagree, NaNs at surface pixels, no specular pixel above
        the threshold, or a peak on the image border.
    """
    P, N, V, cos_r, surface = surface_geometry(capture)
    spec = specular_image(capture, separation=separation)
    spec = np.where(surface[..., None], spec, 0.0)
    lum = spec.mean(axis=-1)
    usable = surface & ~_spikes(lum, surface)
    peak = _peak_pixel(lum, usable)
    peak_value = lum[peak]
    if not surface.any() or not peak_value > 0:
        raise UserError(f"{capture.name}: specular: no specular pixel on the surface (all specular radiance <= 0)")
    mask = usable & np.all(spec > 0, axis=-1) & (lum >= threshold * peak_value)
    if mask.sum() < MIN_SPECULAR_PIXELS:
        raise UserError(
            f"{capture.name}: specular: only {int(mask.sum())} pixels above threshold {threshold} x peak "
            f"(need {MIN_SPECULAR_PIXELS}); lower --option threshold=..."
        )
    i, j = peak
    if i in (0, capture.height - 1) or j in (0, capture.width - 1):
        raise UserError(
            f"{capture.name}: specular: peak pixel (row {i}, column {j}) is on the image border; "
            "the highlight is cut off, so its peak is not the mirror point"
        )
    cam = np.asarray(capture.camera.position, dtype=float)
    return Observation(
        specular=spec,
        P=P,
        N=N,
        V=V,
        cos_r=cos_r,
        surface=surface,
        mask=mask,
        peak=(int(i), int(j)),
        camera_position=cam,
        scale=float(np.linalg.norm(cam - P[i, j])),
    )
