"""Surface textures: where an object's albedo and roughness vary (numpy; the generator's BSDF has its Dr.Jit twin).

One pattern, a 3-D checker in the object's placed frame (so it moves with the
object and needs no uv coordinates): cells of side ``period`` (m), cell
boundaries at ``(k + ¾)·period`` along each local axis (so a board in its own
plane ``z = 0`` lies inside one layer of cells), sign ``+1`` or ``−1`` by the
parity of the cell. A textured material has albedo ``kd·(1 + c_kd·s)`` and
roughness ``σ·(1 + c_σ·s)`` at a point of sign ``s``: mean ``kd`` and ``σ``
over many cells.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Offset of the cells in periods: boundaries at (k + 1 - OFFSET)·period.
OFFSET = 0.25


def checker_sign(P: np.ndarray, to_world: np.ndarray, period_m: float) -> np.ndarray:
    """The checker's sign at world points ``P``.

    Parameters
    ----------
    P : ndarray, shape (..., 3)
        World points, metres.
    to_world : ndarray, shape (4, 4)
        The object's placement (rotation and translation; ``nearlight.generator.scene.placement``).
    period_m : float
        Cell side, metres.

    Returns
    -------
    ndarray, shape (...)
        +1 or −1 (NaN where ``P`` is NaN).
    """
    M = np.asarray(to_world, float)
    local = (np.asarray(P, float) - M[:3, 3]) @ M[:3, :3]
    k = np.floor(local / period_m + OFFSET).sum(-1)
    return np.where(np.isnan(k), np.nan, 1.0 - 2.0 * np.mod(k, 2.0))


def cell_margin(P: np.ndarray, to_world: np.ndarray, period_m: float) -> np.ndarray:
    """Distance of each point from the nearest cell boundary, in periods (for tests that avoid the seams)."""
    M = np.asarray(to_world, float)
    u = (np.asarray(P, float) - M[:3, 3]) @ M[:3, :3] / period_m + OFFSET
    f = u - np.floor(u)
    return np.min(np.minimum(f, 1.0 - f), axis=-1)


def textured(value: Any, contrast: float, sign: np.ndarray) -> np.ndarray:
    """``value·(1 + contrast·sign)``: the albedo or roughness at points of the given checker sign."""
    return np.asarray(value, float) * (1.0 + float(contrast) * np.asarray(sign, float))
