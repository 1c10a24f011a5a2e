"""Surface points and normals from windows per pixel, each as wide as the noise and the surface's bending allow.

Over a whole ``(2w+1)²`` square window centred on the pixel, the odd and even
monomials decouple, so the least-squares gradient of a quadratic is
``Σ Δc·f / Σ Δc²`` (the plane's), unbiased by the curvature; its standard
deviation is ``σ_f / √(Σ Δc²)`` with ``σ_f`` the inverse depth's noise
(:class:`RangeModel`); the value at the centre is the quadratic's ``c₀``.
The sums over any window cost four look-ups in summed-area tables, so every
window of the ladder :data:`HALF_WIDTHS` is computed for every pixel. Each
pixel takes the widest window by the **intersection of confidence
intervals** (ICI; Katkovnik, Egiazarian & Astola, *Local Approximation
Techniques in Signal and Image Processing*, SPIE 2006, ch. 6): widening
while every narrower window's interval ``t ± Γ·s`` (``t`` the log-gradient,
``Γ`` = :data:`GAMMA`) still meets the others, i.e. until the curvature's
bias shows against the noise. A noise-free range keeps small windows (exact
on planes, unbiased to second order on curves); a noisy one widens as far
as the surface stays a quadratic.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.ndimage import distance_transform_cdt

from .range_error import RangeModel

#: Half-widths (pixels) of the square windows tried, ``(2w+1)²`` pixels each.
HALF_WIDTHS = (1, 2, 3, 4, 6, 8, 11, 16, 22, 32, 45, 64, 90, 128, 180, 256)

#: ICI threshold: intervals ``t ± Γ·s`` (s the standard deviation of the window's log-gradient).
GAMMA = 2.0

#: A quantised range's smallest window spans this many depth steps of the local slope.
STEPS_PER_WINDOW = 4.0

#: Largest half-width of the tangent-frame refit (its cost grows with the window's area).
TANGENT_MAX = 6


#: The monomials ``Δc^a Δr^b`` of each degree, split by parity in ``Δc`` and ``Δr``: over a window symmetric about
#: its centre the blocks are orthogonal, so each is fitted alone.
BLOCKS = {
    2: (((0, 0), (2, 0), (0, 2)), ((1, 0),), ((0, 1),), ((1, 1),)),
    3: (((0, 0), (2, 0), (0, 2)), ((1, 0), (3, 0), (1, 2)), ((0, 1), (0, 3), (2, 1)), ((1, 1),)),
}


def _family() -> list[tuple[int, int, list[tuple[tuple[tuple[int, int], ...], np.ndarray]], float]]:
    """The windows and degrees the ICI runs through: ``(half-width, degree, [(block, G⁻¹)], k)``, ``k`` the centre
    gradient's standard deviation per unit noise, sorted by ``k`` falling (the least biased, noisiest first).

    ``G`` is a block's Gram matrix over the whole ``(2w+1)²`` window, the same for every window of that size.
    """
    out = []
    for w in HALF_WIDTHS:
        d = np.arange(-w, w + 1, dtype=float)
        c, r = (x.ravel() for x in np.meshgrid(d, d))
        for degree, blocks in BLOCKS.items():
            if 2 * w + 1 <= degree:
                continue
            inv = []
            for block in blocks:
                basis = np.stack([c**a * r**b for a, b in block])
                inv.append((block, np.linalg.inv(basis @ basis.T)))
            out.append((w, degree, inv, float(np.sqrt(inv[1][1][0, 0]))))
    return sorted(out, key=lambda x: -x[3])


FAMILY = _family()


class _Lazy(dict):
    """A dict that computes a missing key's value once, by ``make(key)``."""

    def __init__(self, make: Callable[[tuple[int, int]], np.ndarray]) -> None:
        super().__init__()
        self.make = make

    def __missing__(self, key: tuple[int, int]) -> np.ndarray:
        self[key] = value = self.make(key)
        return value


def _sat(a: np.ndarray) -> np.ndarray:
    """Summed-area table with a zero first row and column, shape ``(H + 1, W + 1)``."""
    out = np.zeros((a.shape[0] + 1, a.shape[1] + 1))
    np.cumsum(np.cumsum(a, axis=0), axis=1, out=out[1:, 1:])
    return out


def _box(S: np.ndarray, w: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Sums over the ``(2w+1)²`` windows centred on pixels ``(rows, cols)`` (windows inside the image), shape
    ``rows.shape``."""
    r0, r1, c0, c1 = rows - w, rows + w + 1, cols - w, cols + w + 1
    return S[r1, c1] - S[r0, c1] - S[r1, c0] + S[r0, c0]


class _Field:
    """One image ``g`` (``[H, W]``, 0 off the surface) with summed-area tables of ``g·c^p·r^q`` (``p + q ≤ 3``, made
    when first asked for), and the window polynomials fitted to it (:meth:`poly`)."""

    def __init__(self, g: np.ndarray, cc: np.ndarray, rr: np.ndarray) -> None:
        self.raw = _Lazy(lambda pq: _sat(g * cc ** pq[0] * rr ** pq[1]))
        self.cc, self.rr = cc, rr

    def poly(self, w: int, blocks: list, r0: np.ndarray, c0: np.ndarray, dc: np.ndarray, dr: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Value, gradient ``(2, n)`` (per pixel along columns, rows) and the gradient's variance per unit noise
        ``(2, n)`` of each window's polynomial (centred at ``(r0, c0)``, ``blocks`` as :data:`FAMILY`'s) at the
        offsets ``(dc, dr)``."""
        from math import comb

        j0, i0 = self.cc[r0, c0], self.rr[r0, c0]
        box = _Lazy(lambda pq: _box(self.raw[pq], w, r0, c0))

        def moment(a_: int, b_: int) -> np.ndarray:
            """Σ Δc^a Δr^b g over each window, from the raw sums about the image centre."""
            return sum(comb(a_, p) * comb(b_, q) * (-j0) ** (a_ - p) * (-i0) ** (b_ - q) * box[p, q]
                       for p in range(a_ + 1) for q in range(b_ + 1))

        value = np.zeros(r0.size)
        grad = np.zeros((2, r0.size))
        var = np.zeros((2, r0.size))
        for block, inv in blocks:
            coef = inv @ np.stack([moment(a, b) for a, b in block])  # (len(block), n)
            value += sum(coef[m] * dc**a * dr**b for m, (a, b) in enumerate(block))
            for axis in (0, 1):  # d/dΔc, d/dΔr of each monomial at δ
                u = np.stack([(a * dc ** max(a - 1, 0) * dr**b) if axis == 0 else (b * dc**a * dr ** max(b - 1, 0))
                              for a, b in block])
                grad[axis] += np.sum(coef * u, axis=0)
                var[axis] += np.einsum("mn,mk,kn->n", u, inv, u)
        return value, grad, var


def fitted_windows(f: np.ndarray, sf: np.ndarray, valid: np.ndarray, model: RangeModel, zs: np.ndarray, P: np.ndarray,
                   fit: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill ``fit`` (value, gradient per pixel along columns and rows, the gradient's s.d.) and ``half`` by the ICI
    over :data:`FAMILY`; return the fitted points and normals ``(H, W, 3)`` of the windows chosen.

    Each pixel uses the whole window of each size nearest to it that contains
    it (its own, centred, when whole; else one shifted inwards from an edge,
    a hole or a silhouette, by at most ``w``), and evaluates that window's
    polynomial at its own offset ``δ`` from the window's centre, with the
    standard deviation of the gradient there. The ICI runs on the inverse
    depth (whose noise the range model gives); the points and normals come
    from the same windows fitted to the three coordinates of ``P`` (normal =
    ``∂X/∂c × ∂X/∂r``), so that they depend on no camera model: a camera
    whose calibration is off (the bench profile's 0.2°) moves the rays, not
    the points the range measured.
    """
    H, W = valid.shape
    ref = float(np.mean(f[valid]))
    rr, cc = np.meshgrid(np.arange(H) - H / 2, np.arange(W) - W / 2, indexing="ij")  # centred, for precision
    inverse = _Field(np.where(valid, f - ref, 0.0), cc, rr)
    count = _sat(valid.astype(float))
    lo = np.full((H, W, 2), -np.inf)
    hi = np.full((H, W, 2), np.inf)
    alive = valid.copy()
    choice = np.full((H, W), -1)
    centre = np.zeros((2, H, W), int)
    nearest: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for index, (w, degree, blocks, _) in enumerate(FAMILY):
        if 2 * w + 1 > min(H, W):
            continue
        if w not in nearest:
            k_ = 2 * w + 1
            whole = np.zeros((H, W), bool)
            whole[w:H - w, w:W - w] = np.rint(count[k_:, k_:] - count[:-k_, k_:] - count[k_:, :-k_]
                                               + count[:-k_, :-k_]) == k_ * k_
            if not whole.any():
                nearest[w] = (np.zeros((H, W), int) + w + 1, np.zeros((2, H, W), int))
            else:
                nearest[w] = distance_transform_cdt(~whole, metric="chessboard", return_indices=True)
        dist, (ci, cj) = nearest[w]
        rows, cols = np.nonzero(alive & (dist <= w))
        if not rows.size:
            continue
        r0, c0_ = ci[rows, cols], cj[rows, cols]  # the window's centre
        dc, dr = (cols - c0_).astype(float), (rows - r0).astype(float)
        value, (gc, gr), var = inverse.poly(w, blocks, r0, c0_, dc, dr)
        value += ref
        sfp = sf[rows, cols]
        t = np.stack([gc, gr], axis=-1) / value[:, None]
        s = sfp[:, None] * np.sqrt(var.T) / np.abs(value)[:, None]
        if model.quantum_m > 0:
            # a window over fewer than STEPS_PER_WINDOW steps of the local slope reads the terrace, not the slope
            young = np.hypot(gc, gr) * (2 * w + 1) * zs[rows, cols] ** 2 / model.quantum_m < STEPS_PER_WINDOW
        else:
            young = np.zeros(rows.size, bool)
        lo_k, hi_k = np.maximum(lo[rows, cols], t - GAMMA * s), np.minimum(hi[rows, cols], t + GAMMA * s)
        meets = np.all(lo_k <= hi_k, axis=-1) | young
        keep = meets & ~young
        lo[rows[keep], cols[keep]], hi[rows[keep], cols[keep]] = lo_k[keep], hi_k[keep]
        fit[rows[meets], cols[meets]] = np.stack([value, gc, gr, sfp * np.sqrt(var.mean(axis=0))], axis=-1)[meets]
        half[rows[meets], cols[meets]] = w
        choice[rows[meets], cols[meets]] = index
        centre[:, rows[meets], cols[meets]] = np.stack([r0, c0_])[:, meets]
        alive[rows[~meets], cols[~meets]] = False
    # the points and normals: the chosen windows fitted to x, y and z
    X0 = P[valid].mean(axis=0)
    coords = [_Field(np.where(valid, P[..., k] - X0[k], 0.0), cc, rr) for k in range(3)]
    Xf = np.full((H, W, 3), np.nan)
    Nf = np.full((H, W, 3), np.nan)
    for index in np.unique(choice[choice >= 0]):
        w, _, blocks, _ = FAMILY[index]
        rows, cols = np.nonzero(choice == index)
        r0, c0_ = centre[0, rows, cols], centre[1, rows, cols]
        dc, dr = (cols - c0_).astype(float), (rows - r0).astype(float)
        fits = [field.poly(w, blocks, r0, c0_, dc, dr)[:2] for field in coords]
        Xf[rows, cols] = np.stack([v for v, _ in fits], axis=-1) + X0
        dXdc = np.stack([g[0] for _, g in fits], axis=-1)
        dXdr = np.stack([g[1] for _, g in fits], axis=-1)
        n = np.cross(dXdc, dXdr)
        Nf[rows, cols] = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return Xf, Nf


def tangent_fit(P: np.ndarray, valid: np.ndarray, N: np.ndarray, where: np.ndarray, half: np.ndarray,
                iterations: int = 2) -> np.ndarray:
    """Normals at the pixels ``where`` from a quadric height field over each one's tangent plane, shape ``(n, 3)``.

    Near a silhouette the inverse depth over the pixel grid is no polynomial
    (it has a square-root singularity at the limb), so a grazing pixel's
    window is refitted in 3-D: heights along its current normal over the
    plane across it, ``h = c₀ + c₁u + c₂v + c₃u² + c₄uv + c₅v²`` over the
    ``(2w+1)²`` pixels around it (``w`` = ``half``), and the normal of that
    quadric at the pixel; twice, the second time in the first fit's frame.
    Range noise along a grazing ray lies nearly in that plane, so it moves
    the points along the surface more than off it.
    """
    H, W = valid.shape
    rows, cols = np.nonzero(where)
    out = N[rows, cols].copy()
    for wv in np.unique(half):
        sel = np.flatnonzero(half == wv)
        d = np.arange(-wv, wv + 1)
        di, dj = (x.ravel() for x in np.meshgrid(d, d, indexing="ij"))
        ri = np.clip(rows[sel, None] + di, 0, H - 1)
        cj = np.clip(cols[sel, None] + dj, 0, W - 1)
        ok = valid[ri, cj] & (np.abs(rows[sel, None] + di - ri) + np.abs(cols[sel, None] + dj - cj) == 0)
        Q = np.where(ok[..., None], P[ri, cj] - P[rows[sel], cols[sel]][:, None, :], 0.0)
        n = out[sel]
        for _ in range(iterations):
            e1 = np.cross(n, np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
            e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
            e2 = np.cross(n, e1)
            u, v, h = (np.einsum("pkx,px->pk", Q, e) for e in (e1, e2, n))
            count = np.maximum(ok.sum(1, keepdims=True), 1)
            scale = np.sqrt(np.sum(ok * (u * u + v * v), axis=1, keepdims=True) / count)
            u, v = u / scale, v / scale
            A = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1) * ok[..., None]
            G = np.einsum("pki,pkj->pij", A, A)
            good = ok.sum(1) >= 8
            G[~good] = np.eye(6)
            coef = np.linalg.solve(G, np.einsum("pki,pk->pi", A, h * ok)[..., None])[..., 0]
            # the quadric's normal at the pixel itself (u = v = 0): the gradient is (c1, c2) per unit of u/scale
            m = n - (coef[:, 1:2] * e1 + coef[:, 2:3] * e2) / scale
            m /= np.linalg.norm(m, axis=-1, keepdims=True)
            n = np.where(good[:, None], m, n)
        out[sel] = n
    return out
