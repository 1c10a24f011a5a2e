"""The pinhole camera: pixel rays, projection into the image, and the ``saturation: auto`` exposure.

Conventions (``docs/physics.md``), those of Mitsuba's perspective sensor, which
the generator renders with: the camera-to-world matrix has columns ``left``,
``up``, ``forward`` and the origin (the camera looks along its local +z); image
column 0 lies towards ``+left``, row 0 at the top; ``fov_x_deg`` is the
horizontal field of view; rays pass through pixel centres.

Numpy only; imports no pipeline stage.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .reflectance import normalize

#: Fraction of the full well the brightest clean recorded pixel reaches with ``saturation: auto``.
AUTO_EXPOSURE = 0.9


def look_at_matrix(origin: Any, target: Any, up: Any = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world matrix as Mitsuba builds it (camera looks along local +z).

    Columns are ``left``, ``up``, ``forward`` and the origin, so image column 0
    lies towards ``+left``.

    Returns
    -------
    ndarray, shape (4, 4)
    """
    origin = np.asarray(origin, dtype=float)
    forward = normalize(np.asarray(target, dtype=float) - origin)
    left = normalize(np.cross(np.asarray(up, dtype=float), forward))
    new_up = np.cross(forward, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, forward, origin
    return m


def camera_rays(to_world: np.ndarray, width: int, height: int, fov_x_deg: float) -> np.ndarray:
    """Unit ray directions through pixel centres, shape ``(H, W, 3)`` (world frame)."""
    return pixel_ray(to_world, (np.arange(width) + 0.5)[None, :], (np.arange(height) + 0.5)[:, None],
                     width, height, fov_x_deg)  # fmt: skip


def pixel_ray(to_world: np.ndarray, col: Any, row: Any, width: int, height: int, fov_x_deg: float) -> np.ndarray:
    """Unit ray directions through image positions ``(col, row)`` (pixels, centres at ``k + 0.5``), world frame.

    Parameters
    ----------
    to_world : ndarray, shape (4, 4)
    col, row : float or ndarray
        Image coordinates, broadcast together (shape ``S``).
    width, height : int
    fov_x_deg : float

    Returns
    -------
    ndarray, shape ``S + (3,)``
    """
    tan_x = np.tan(np.radians(fov_x_deg) / 2.0)
    tan_y = tan_x * height / width
    u = np.asarray(col, float) / width * 2.0 - 1.0  # -1 at the left edge
    v = 1.0 - np.asarray(row, float) / height * 2.0  # +1 at the top edge
    left, up, forward = to_world[:3, 0], to_world[:3, 1], to_world[:3, 2]
    d = forward + (-u[..., None] * tan_x) * left + (v[..., None] * tan_y) * up
    return normalize(d)


def shifted_target(position: Any, look_at: Any, up: Any, fov_x_deg: float, width: int, height: int,
                   shift_px: Any) -> np.ndarray:  # fmt: skip
    """The look-at point that turns the camera about its centre onto image position ``centre + shift_px``.

    The new optical axis is the old camera's ray through ``(W/2 + dx, H/2 + dy)`` (``dx`` to the right,
    ``dy`` down, pixels), so the scene moves in the image by about ``(−dx, −dy)`` px: a sub-pixel shift of
    where the pixel grid falls on the scene (``camera.shift_px``, ``camera.jitter_px``).

    Parameters
    ----------
    position, look_at, up : array_like, shape (3,)
        The camera as placed (world frame, metres).
    fov_x_deg : float
    width, height : int
    shift_px : array_like, shape (2,)
        ``(dx, dy)``, pixels.

    Returns
    -------
    ndarray, shape (3,)
        A point on the new optical axis, as far from ``position`` as ``look_at`` is (metres).
    """
    position = np.asarray(position, float)
    m = look_at_matrix(position, look_at, up)
    dx, dy = (float(x) for x in shift_px)
    d = pixel_ray(m, width / 2.0 + dx, height / 2.0 + dy, width, height, fov_x_deg)
    return position + np.linalg.norm(np.subtract(look_at, position)) * d


def project(d: np.ndarray, to_world: np.ndarray, width: int, height: int, fov_x_deg: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Where world-frame directions from the camera land in the image: the inverse of :func:`camera_rays`.

    Parameters
    ----------
    d : ndarray, shape (..., 3)
        Directions from the centre of projection (any length), world frame.
    to_world : ndarray, shape (4, 4)
    width, height : int
    fov_x_deg : float

    Returns
    -------
    col, row : ndarray, shape (...)
        Image coordinates in pixels (pixel centres at ``k + 0.5``); meaningless where ``z ≤ 0``.
    z : ndarray, shape (...)
        Depth along the viewing direction (> 0 in front of the camera).
    """
    W, H = width, height
    R = np.asarray(to_world, dtype=float)[:3, :3]
    local = d @ R  # R^T d, row-wise
    z = local[..., 2]
    t = np.tan(np.radians(fov_x_deg) / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        col = (1 - local[..., 0] / z / t) * W / 2
        row = (1 - local[..., 1] / z / (t * H / W)) * H / 2
    return col, row, z


def auto_saturation(*images: np.ndarray) -> float:
    """The ``saturation: auto`` exposure: radiance that fills the full well, from the clean images.

    The brightest clean recorded pixel (over all ``images``, NaN ignored) lands
    at :data:`AUTO_EXPOSURE` (90 %) of the full well, an exposure a careful
    operator would pick; 1 when nothing is brighter than 0.

    Parameters
    ----------
    *images : ndarray
        The clean images the camera records (analyzer stack, separated images).

    Returns
    -------
    float
        Radiance, the images' units.
    """
    peak = max(float(np.nanmax(v)) for v in images)
    return peak / AUTO_EXPOSURE if peak > 0 else 1.0


# --------------------------------------------------------------------------- camera nuisances


def vignetting_gain(width: int, height: int, strength: float) -> np.ndarray:
    """Relative illumination of each pixel centre: ``1 − v·ρ²``, ρ the distance from the image centre over the
    half-diagonal (1 at the corners), so the corners get ``1 − v`` of the centre's light.

    Parameters
    ----------
    width, height : int
        Image size, pixels.
    strength : float
        ``v`` in [0, 1): the fall-off at the corners (0: none).

    Returns
    -------
    ndarray, shape (H, W), float64
        In ``(1 − v, 1]``; dividing by it undoes the vignetting exactly (up to rounding).
    """
    x = np.arange(width) + 0.5 - width / 2.0
    y = np.arange(height) + 0.5 - height / 2.0
    rho2 = (x[None, :] ** 2 + y[:, None] ** 2) / ((width / 2.0) ** 2 + (height / 2.0) ** 2)
    return 1.0 - float(strength) * rho2


def response(radiance: np.ndarray, gamma: float, white: float) -> np.ndarray:
    """A camera's non-linear response: ``white · (L / white)^(1/γ)`` (a gamma curve through 0 and ``white``).

    Parameters
    ----------
    radiance : ndarray
        Linear values L (negative ones are clipped to 0).
    gamma : float
        γ > 0; 1 is linear (then ``radiance`` is returned as it is). sRGB-like cameras: about 2.2.
    white : float
        The value mapped to itself (the full-well radiance), > 0.

    Returns
    -------
    ndarray
        Recorded values; :func:`inverse_response` with the same ``gamma`` and ``white`` gives L back.
    """
    if gamma == 1.0:
        return radiance
    return white * np.power(np.clip(radiance, 0.0, None) / white, 1.0 / gamma)


def inverse_response(recorded: np.ndarray, gamma: float, white: float) -> np.ndarray:
    """The inverse of :func:`response`: linear values from recorded ones (``white · (V / white)^γ``)."""
    if gamma == 1.0:
        return recorded
    return white * np.power(np.clip(recorded, 0.0, None) / white, gamma)
