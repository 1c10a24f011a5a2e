"""Surface normals from the range image by local plane fits."""

from __future__ import annotations

import numpy as np


def normals_from_positions(P: np.ndarray, camera_position: np.ndarray, *, window: int = 3) -> np.ndarray:
    """Unit normals from world positions by a least-squares plane per pixel.

    Each pixel's normal is the eigenvector of the smallest eigenvalue of the
    covariance of the finite positions in its ``window × window``
    neighbourhood, oriented towards the camera. Exact for planes; on curved
    surfaces the error is O(window · pixel footprint / radius of curvature).

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
        World positions, metres; NaN where there is no surface.
    camera_position : ndarray, shape (3,)
    window : int, optional
        Odd neighbourhood size, pixels.

    Returns
    -------
    ndarray, shape (H, W, 3)
        Unit normals; NaN where there is no surface or fewer than 3 neighbours.
    """
    P = np.asarray(P, dtype=float)
    H, W, _ = P.shape
    half = window // 2
    valid = np.all(np.isfinite(P), axis=-1)
    Pz = np.where(valid[..., None], P, 0.0)
    # Centre on each pixel's own position to keep the sums well conditioned.
    ref = Pz
    pad = ((half, half), (half, half), (0, 0))
    Pp = np.pad(Pz, pad)
    vp = np.pad(valid, pad[:2])
    count = np.zeros((H, W))
    s1 = np.zeros((H, W, 3))
    s2 = np.zeros((H, W, 3, 3))
    for di in range(window):
        for dj in range(window):
            q = Pp[di : di + H, dj : dj + W] - ref
            v = vp[di : di + H, dj : dj + W]
            q = np.where(v[..., None], q, 0.0)
            count += v
            s1 += q
            s2 += q[..., :, None] * q[..., None, :]
    ok = valid & (count >= 3)
    n = np.maximum(count, 1.0)[..., None]
    mean = s1 / n
    cov = s2 / n[..., None] - mean[..., :, None] * mean[..., None, :]
    cov[~ok] = np.eye(3)
    _, vecs = np.linalg.eigh(cov)
    N = vecs[..., :, 0]
    to_cam = np.asarray(camera_position, dtype=float) - Pz
    N = np.where((np.sum(N * to_cam, axis=-1) < 0)[..., None], -N, N)
    N[~ok] = np.nan
    return N
