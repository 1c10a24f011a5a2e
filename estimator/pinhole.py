"""The pinhole behind a capture's rays: ``M`` with ``M·[column, row, 1]`` along each pixel's ray, and its axis."""

from __future__ import annotations

import numpy as np


def pinhole_matrix(rays: np.ndarray) -> np.ndarray:
    """``M`` with ``M·[c, r, 1] ∝`` the ray through pixel ``(row r, column c)`` (centres at ``k + 0.5``).

    Fitted to the unit rays of four pixels well apart (a pinhole's rays are
    exactly of that form: :func:`nearlight.physics.camera.camera_rays`, or
    :func:`nearlight.estimator.geometry.capture_rays`'s fitted pinhole), by
    the direct linear transform over a 5 × 5 lattice of pixels.

    Parameters
    ----------
    rays : ndarray, shape (H, W, 3)

    Returns
    -------
    ndarray, shape (3, 3)
        Scaled so that ``M[:, 2]·n = 1`` with ``n`` the optical axis (:func:`optical_axis`).
    """
    H, W = rays.shape[:2]
    rows = np.linspace(0, H - 1, 5).round().astype(int)
    cols = np.linspace(0, W - 1, 5).round().astype(int)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    d = rays[rr.ravel(), cc.ravel()]
    s = float(max(H, W))
    p = np.stack([(cc.ravel() + 0.5) / s, (rr.ravel() + 0.5) / s, np.ones(rr.size)], axis=1)
    A = np.zeros((2 * len(d), 9))
    A[0::2, 3:6] = -d[:, 2:3] * p
    A[0::2, 6:9] = d[:, 1:2] * p
    A[1::2, 0:3] = d[:, 2:3] * p
    A[1::2, 6:9] = -d[:, 0:1] * p
    M = np.linalg.svd(A, full_matrices=False)[2][-1].reshape(3, 3) @ np.diag([1 / s, 1 / s, 1.0])
    if float((M @ [cols[0] + 0.5, rows[0] + 0.5, 1.0]) @ d[0]) < 0:
        M = -M
    n = np.cross(M[:, 0], M[:, 1])
    n /= np.linalg.norm(n)
    n *= np.sign(n @ M[:, 2])
    return M / float(n @ M[:, 2])


def optical_axis(M: np.ndarray) -> np.ndarray:
    """Unit optical axis of the pinhole ``M`` (normal to the image plane, pointing forward), shape (3,)."""
    n = np.cross(M[:, 0], M[:, 1])
    n /= np.linalg.norm(n)
    return n * np.sign(n @ M[:, 2])
