"""One surface through every range pixel, when the data say so: a plane, a sphere or a quadric.

Tried in that order, the simplest family first, each accepted when its
residuals are within :data:`PLANE_FIT` times the range noise across the
surface (:func:`normal_noise`): :func:`one_plane` (a board is one plane
over all its pixels, also at its edges, where no centred window is whole),
:func:`one_sphere` (4 parameters), :func:`one_quadric` (Taubin's fit, 9:
a cylinder, a cone, an ellipsoid, two planes meeting at a crease). Every
point and normal is then the surface's, where each point's own direction
from the camera meets it. Only when none fits (a bent plate with a rounded
bend, a torus, a real object) are the normals local
(:mod:`~nearlight.estimator.local_windows`). This is model selection by
the data, not knowledge of the scene: a sphere's four parameters fixed by
10⁴–10⁵ range pixels give its normals to thousandths of a degree at 0.2 mm
of noise, which no local window can (its bound,
:mod:`nearlight.evaluation.scoring.range_bound`, takes the same family).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.ndimage import distance_transform_cdt

from ..physics.depth import read_depth
from .pinhole import optical_axis, pinhole_matrix
from .range_error import RangeModel

#: Spatial blocks (per side) of the jackknife that gives a whole plane's covariance (:func:`one_plane`).
JACKKNIFE_BLOCKS = 4

#: The whole-quadric jackknife evaluates its replicates on every this-many-th row and column.
JACKKNIFE_STEP = 3

#: A plane fits the whole surface when its residual RMS is within this factor of the noise.
PLANE_FIT = 1.5

#: Simulated readings of a quantised range behind :func:`staircase_cov` (its s.d. estimates then good to
#: about 1/√(2·32) = 12 %).
STAIRCASE_DRAWS = 32

#: Gauss–Newton iterations of the sphere's geometric fit (from the algebraic one: converged in 2-3) ...
SPHERE_ITERATIONS = 5
#: ... stopped early when every step is below this many of its parameter's standard deviations: the weights follow
#: the sphere, so each step is a fraction of the last (measured on the analytic sphere at 640×480: 1/8 to 1/40),
#: and after such a step the fit is within about a hundredth of a standard deviation of its optimum.
SPHERE_STEP_SD = 0.1
#: A sphere is refused when its normal equations, scaled to unit diagonal, have a larger condition number: its radius
#: is then not fixed by the points (a bench board that no pixel-grid plane fitted ran off to R = 460 ± 60 m, 1.9e16;
#: the analytic sphere at 160×120 and 640×480 under 0.05-1 mm of noise or 1-mm steps: 31-162).
SPHERE_MAX_CONDITION = 1e12
#: The sphere's Gauss–Newton runs on about this many of the points first (every k-th), then on all from there
#: (one or two steps: the subsample's optimum is a few of its own s.d. from the whole's). Each pass over the
#: ~10⁵ points of a 640×480 sphere costs ~25 ms; from the algebraic start all six did.
SPHERE_SUBSAMPLE = 10000



def jackknife_blocks(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Each pixel's spatial block, ``0 … JACKKNIFE_BLOCKS² − 1``, of the delete-one-block jackknife (row-major)."""
    H, W = shape
    return (np.minimum(rows * JACKKNIFE_BLOCKS // H, JACKKNIFE_BLOCKS - 1) * JACKKNIFE_BLOCKS
            + np.minimum(cols * JACKKNIFE_BLOCKS // W, JACKKNIFE_BLOCKS - 1)).astype(int)


def jackknife_lattice(valid: np.ndarray) -> np.ndarray:
    """The pixels a whole surface's s.d. is evaluated at: every :data:`JACKKNIFE_STEP`-th row and column of
    ``valid`` (all of ``valid`` when none of those is); the others take their nearest's (:func:`from_nearest`)."""
    lattice = np.zeros(valid.shape, bool)
    lattice[::JACKKNIFE_STEP, ::JACKKNIFE_STEP] = True
    lattice &= valid
    return lattice if lattice.any() else valid.copy()


def from_nearest(values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``values`` (``[H, W]``) at every pixel taken from the nearest pixel of ``at`` (chessboard distance): the
    s.d. of a whole-surface fit varies over many pixels, not from one to the next."""
    near = distance_transform_cdt(~at, metric="chessboard", return_indices=True)[1]
    return values[near[0], near[1]]


def directions(X: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """Unit direction of each point ``X`` (n, 3) from the camera: its own, not the camera model's ray."""
    return (X - cam) / np.linalg.norm(X - cam, axis=1, keepdims=True)


def towards(N: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Normals ``N`` (n, 3) turned to face the camera that looks along ``r``."""
    return np.where((np.sum(N * r, axis=1) > 0)[:, None], -N, N)


def normal_noise(n: np.ndarray, r: np.ndarray, along: np.ndarray, model: RangeModel, floor: float) -> np.ndarray:
    """Standard deviation of the range error along each normal ``n`` (m, 3), metres, for points on rays ``r``.

    The error moves a point along its ray: by ``σ`` (along the ray) or by
    ``σ / (r·axis)`` (along ``z``; ``along`` (m,) is :func:`axis_cosine` of ``r``), of which ``|n·r|`` is
    across the surface; with the float32 floor in quadrature.
    """
    return np.hypot(model.equivalent_sigma_m * np.abs(np.einsum("ij,ij->i", n, r)) / along, floor)


def plane_in_space(P: np.ndarray, valid: np.ndarray, cam: np.ndarray, n0: np.ndarray, rays: np.ndarray,
                   model: RangeModel, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """The whole plane's points and normals (towards the camera), fitted to the points in space (no camera model).

    :func:`one_plane` decides that one plane fits (its inverse depth affine
    over the pixels); the plane itself is fitted to ``P``: the weighted
    principal axes of the points, each weighted by the range noise across
    the plane (:func:`normal_noise`, with the pixel-grid fit's unit normal
    ``n0`` (3,)), and each point moved along its own direction from the camera
    onto it. A camera whose calibration is off moves its rays, not the
    points the range measured.
    """
    X = P[valid]
    u = directions(X, cam)
    w = 1.0 / normal_noise(np.broadcast_to(n0, u.shape), u, axis_cosine(u, rays, model), model, floor) ** 2
    centroid = w @ X / w.sum()
    Q = X - centroid
    n = np.linalg.eigh((w[:, None] * Q).T @ Q)[1][:, 0]  # the weighted scatter's least principal axis
    n = n if n @ (cam - centroid) > 0 else -n
    Pf = np.full(P.shape, np.nan)
    Nf = np.full(P.shape, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        Pf[valid] = X - ((Q @ n) / (u @ n))[:, None] * u
    Nf[valid] = n
    return Pf, Nf


def wider(cov: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Each entry of the covariance ``cov`` or of ``other`` (k, k), whichever's pair of variances is larger."""
    return np.where(np.diag(other)[:, None] * np.diag(other)[None, :] > np.diag(cov)[:, None] * np.diag(cov)[None, :],
                    other, cov)


def staircase_cov(J: np.ndarray, sens: np.ndarray, depth: np.ndarray, model: RangeModel, seed: int = 0
                  ) -> np.ndarray:
    """Mean squared error matrix of a whole-surface fit under the range's own error, simulated from the fit.

    A depth map's staircase errors are one sawtooth of the depth, the same
    over a terrace: how far they move a fit depends on where the lattice of
    levels falls, which no residual statistic of one capture sees (on the
    1-mm z-quantised analytic board and sphere the fits' own covariances,
    independent-noise or block-jackknife, were 2.5-3.6 times too small in
    s.d., 40 seeds). So the range is read again off the fitted surface
    (:func:`nearlight.physics.depth.read_depth`: the model's noise, its
    levels at :data:`STAIRCASE_DRAWS` offsets stratified over one step) and
    the fit's linear response to each reading's errors taken, a linearised
    parametric bootstrap: ``Δg = −(JᵀJ)⁻¹ Jᵀ (sens · e)``. The errors are at most
    half a step plus the noise, far inside the fits' curvature, and the
    linear response of a least-squares fit to independent noise is its own
    ``(JᵀJ)⁻¹``, so without a quantum the draws give back the fit's covariance.

    The fits add it to their independent-noise covariance: the lattice moves
    a fit along few directions, so the draws' matrix is nearly singular, and
    a direction it calls still would make any other error (a misfit, the
    noise the draws estimate from 32 samples) a many-sigma one (on the 1-mm
    quantised sphere, mean squared Mahalanobis distances of 15-54 for some
    seeds with the draws' alone). The sum counts the staircase's white share
    twice, at most (1/2.5)² of the total variance.

    Parameters
    ----------
    J : ndarray, shape (n, k)
        The fit's weighted residuals' Jacobian in its parameters ``g``, at the fit.
    sens : ndarray, shape (n,)
        Each weighted residual's change per metre of reading error along the range's axis.
    depth : ndarray, shape (n,)
        The fitted surface's depth along that axis at each pixel, metres.
    model : RangeModel
    seed : int
        Of the simulation's draws (fixed: the same capture gives the same covariance).

    Returns
    -------
    ndarray, shape (k, k)
        ``mean Δg Δgᵀ`` over the draws (the simulated bias included).
    """
    response = np.linalg.inv(J.T @ J) @ (J.T * sens)  # (k, n): Δg per metre of error at each pixel, negated
    rng = np.random.default_rng(seed)
    draws = np.empty((STAIRCASE_DRAWS, J.shape[1]))
    for b in range(STAIRCASE_DRAWS):
        offset = (b + rng.uniform()) / STAIRCASE_DRAWS * model.quantum_m
        noise = rng.normal(0.0, model.sigma_m, len(depth)) if model.sigma_m > 0 else 0.0
        draws[b] = response @ (read_depth(depth, noise=noise, quantum_m=model.quantum_m, offset_m=offset) - depth)
    return draws.T @ draws / STAIRCASE_DRAWS


def axis_cosine(r: np.ndarray, rays: np.ndarray, model: RangeModel) -> np.ndarray:
    """Per unit ray ``r`` (n, 3), metres of the range's axis per metre along the ray: ``r·axis`` for a depth along
    ``z``, 1 along the ray."""
    if model.axis == "z":
        return np.maximum(r @ optical_axis(pinhole_matrix(rays)), 1e-12)
    return np.ones(len(r))


def one_plane(f: np.ndarray, sf: np.ndarray, valid: np.ndarray, cc: np.ndarray, rr: np.ndarray, *,
              jackknife: bool = True) -> tuple[np.ndarray, np.ndarray] | None:
    """``(coefficients [a, b, c] of f ≈ a + b·c + c·r, their covariance)`` when one plane fits every valid pixel
    within :data:`PLANE_FIT` × the noise, else None.

    The covariance is the independent-noise one or, with ``jackknife``, the
    larger of that and a delete-one-block jackknife over
    :data:`JACKKNIFE_BLOCKS`² spatial blocks: a guard against errors
    correlated over the surface that the range's model does not state
    (conservative: on white noise the larger of two estimates of one
    variance, the plane's normal s.d. about 1.2× its error's, 40 seeds). A
    quantised range states its correlation (a staircase's errors are one
    sawtooth over each terrace) and is covered by :func:`staircase_cov`
    instead (the jackknife as well counted it twice).
    """
    if valid.sum() < 20:
        return None
    x, y, w = cc[valid], rr[valid], 1.0 / sf[valid]
    x0, y0 = x.mean(), y.mean()
    A = np.stack([w, (x - x0) * w, (y - y0) * w], axis=1)
    b = f[valid] * w
    # normal equations (A's columns are centred: AᵀA's condition number is about the pixel grid's squared, ~1e5 at
    # 640×480, far inside float64)
    AtA, Atb = A.T @ A, A.T @ b
    coef = np.linalg.solve(AtA, Atb)
    rms = float(np.sqrt(np.mean((A @ coef - b) ** 2)))
    if not rms <= PLANE_FIT:
        return None
    cov = np.linalg.inv(AtA) * max(rms, 1.0) ** 2
    if jackknife:
        # each spatial block's normal equations by weighted bincounts (not a boolean mask per block)
        block = jackknife_blocks(y, x, valid.shape)
        blocks = JACKKNIFE_BLOCKS**2
        AtAk, Atbk = np.empty((blocks, 3, 3)), np.empty((blocks, 3))
        for i in range(3):
            Atbk[:, i] = np.bincount(block, A[:, i] * b, blocks)
            for j in range(i, 3):
                AtAk[:, i, j] = AtAk[:, j, i] = np.bincount(block, A[:, i] * A[:, j], blocks)
        present = np.bincount(block, minlength=blocks) > 0
        if present.sum() >= 4:
            leave = np.linalg.solve(AtA - AtAk[present], (Atb - Atbk[present])[..., None])[..., 0]
            g = int(present.sum())
            jack = (g - 1) / g * (leave - leave.mean(axis=0)).T @ (leave - leave.mean(axis=0))
            cov = wider(cov, jack)
    shift = np.array([[1.0, -x0, -y0], [0, 1, 0], [0, 0, 1]])
    return shift @ coef, shift @ cov @ shift.T


@dataclasses.dataclass(frozen=True)
class SurfaceParameters:
    """A whole surface's parameters as fitted to the range, and their covariance from the range's error.

    What ``full``'s joint fit refines with the lamp (:mod:`~nearlight.estimator.joint_surface`).

    Attributes
    ----------
    kind : {"plane", "sphere"}
    g : ndarray, shape (3,) or (4,)
        A plane's ``m`` with ``m·(X − camera) = 1`` (1/metres), or a sphere's
        ``[cx, cy, cz, R]`` (metres).
    cov : ndarray, shape (k, k)
        Covariance of ``g`` from the range's error (the fit's own: see
        :func:`one_plane`, :func:`one_sphere`).
    """

    kind: str
    g: np.ndarray
    cov: np.ndarray


def on_rays(kind: str, g: np.ndarray, origin: np.ndarray, rays: np.ndarray, near: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Distance along each unit ray ``rays`` (n, 3) from ``origin`` to the surface ``g`` (:class:`SurfaceParameters`),
    and the unit normal there, towards ``origin``; NaN where a ray misses.

    A sphere's root is the nearer one, or the one nearest ``near`` (n,) when given
    (a point on its far side, seen through a hole). The one home of these
    intersections: the fits here, ``full``'s joint fit and the bound under range
    noise (:mod:`nearlight.evaluation.scoring.range_bound`).
    """
    if kind == "plane":  # m·(X − origin) = 1
        with np.errstate(divide="ignore", invalid="ignore"):
            t = 1.0 / (rays @ g)
        n = np.broadcast_to(g / np.linalg.norm(g), rays.shape)
    else:
        c, R = g[:3], g[3]
        b = rays @ (origin - c)
        disc = b * b - (np.sum((origin - c) ** 2) - R * R)
        with np.errstate(invalid="ignore"):
            root = np.sqrt(np.where(disc >= 0, disc, np.nan))
        t = -b - root if near is None else np.where(np.abs(-b - root - near) <= np.abs(-b + root - near),
                                                    -b - root, -b + root)
        # the outward normal (origin − c + t r)/R faces along the ray (n·r = (b + t)/R > 0) at the far root: turned
        n = ((origin - c) + t[:, None] * rays) * (np.where(b + t > 0, -1.0, 1.0) / R)[:, None]
        return t, n
    return t, n * np.where(np.einsum("ij,ij->i", n, rays) > 0, -1.0, 1.0)[:, None]


def one_sphere(P: np.ndarray, valid: np.ndarray, rays: np.ndarray, cam: np.ndarray, model: RangeModel,
               floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, SurfaceParameters] | None:
    """Points, normals, the normals' s.d. and the parameters of one sphere through every valid pixel, when it fits within
    :data:`PLANE_FIT` × the range noise along the normal (a robust scale of the residuals); else None.

    The algebraic fit ``|X|² = 2c·X + k`` (linear), then Gauss–Newton on
    the geometric residuals ``|X − c| − R`` weighted by the range noise
    along the normal (:func:`normal_noise`), each residual's normal and
    weight those of the current sphere where the pixel's ray meets it. The
    noisy point's own direction from the centre leans with its error (a
    point moved by ``δ`` along its ray turns it by ``δ/R`` across), which
    correlates the weights and the Jacobian with the residuals: at 1 mm of
    noise on the analytic sphere that put the radius 3.5 and the centre 2.5
    standard deviations off, the mean squared Mahalanobis distance of the
    fit 22 for its 4 parameters (40 seeds); with the sphere's normals 0.2 s.d.
    and 4.6. (The second-order ``δ²(1 − (n·u)²)/2R`` by which a moved point's
    distance exceeds ``R`` is within that residue and not corrected.)
    The normals' s.d.: the fit's
    covariance ``(JᵀWJ)⁻¹`` (scaled by the residuals' variance when above 1;
    on a quantised range that plus :func:`staircase_cov`'s),
    each of its four principal axes turning every normal by an angle, summed
    in quadrature.
    """
    if valid.sum() < 50:
        return None
    X = P[valid]
    r = directions(X, cam)
    ref = X.mean(axis=0)
    Q = X - ref
    A = np.column_stack([2 * Q, np.ones(len(Q))])
    # least squares, not the normal equations: points on exactly one plane (a range shifted so the pixel-grid
    # plane fit refused it) make A rank-deficient, which lstsq answers and the condition test below refuses
    sol = np.linalg.lstsq(A, np.einsum("ij,ij->i", Q, Q), rcond=None)[0]
    c = sol[:3]
    R = float(np.sqrt(max(sol[3] + c @ c, 0.0)))
    if not R > 0:
        return None
    along = axis_cosine(r, rays, model)
    every = len(Q) // SPHERE_SUBSAMPLE
    if every > 1:
        sub = slice(None, None, every)
        c, R = _sphere_gauss_newton(Q[sub], r[sub], along[sub], cam - ref, model, floor, c, R, SPHERE_ITERATIONS)[:2]
        if not (np.all(np.isfinite(c)) and R > 0):
            return None
    c, R, n, w, res = _sphere_gauss_newton(Q, r, along, cam - ref, model, floor, c, R, SPHERE_ITERATIONS)
    scale = 1.4826 * float(np.median(np.abs(res)))
    if not (scale <= PLANE_FIT and np.all(np.isfinite(c)) and R > 0):
        return None
    J = np.column_stack([-n, -np.ones(len(n))]) * w[:, None]
    H = J.T @ J
    d = np.sqrt(np.diag(H))
    if not (np.all(np.isfinite(H)) and np.all(d > 0) and np.linalg.cond(H / np.outer(d, d)) <= SPHERE_MAX_CONDITION):
        return None  # a radius the points do not fix: a plane-like patch run off to R → ∞
    cov = np.linalg.inv(H) * max(scale, 1.0) ** 2
    centre = c + ref
    near = np.linalg.norm(X - cam, axis=1)
    g = np.concatenate([centre, [R]])
    t, N = on_rays("sphere", g, cam, r, near)
    miss = ~np.isfinite(t)  # a ray grazing the silhouette: its measured point
    if model.quantum_m > 0:
        hit = ~miss
        # a reading's error e along the axis moves the point by e/along along its ray: its distance from the
        # centre by (n·r) e/along
        cov = cov + staircase_cov(J[hit], (w * np.sum(n * r, axis=1))[hit] / along[hit], t[hit] * along[hit], model)
    t[miss], N[miss] = near[miss], towards(n[miss], r[miss])
    Ps = np.full(P.shape, np.nan)
    Ns = np.full(P.shape, np.nan)
    sds = np.full(valid.shape, np.nan)
    on = cam + t[:, None] * r
    Ps[valid], Ns[valid], sds[valid] = on, N, np.where(miss, np.nan, sphere_turn(on, r, g, cov))
    return Ps, Ns, sds, SurfaceParameters("sphere", g, cov)


def sphere_turn(X: np.ndarray, r: np.ndarray, g: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Standard deviation of the angle (radians) by which the normal of the sphere ``g = [c, R]`` at the points
    ``X`` (n, 3) where the unit rays ``r`` meet it turns under the covariance ``cov`` (4, 4) of ``g``: linearised.

    A point ``X = cam + t r`` on ``|X − c| = R`` moves along its ray by
    ``dt = (N·dc + dR)/(N·r)`` (``N = (X − c)/R``, outward) and its normal by ``dN = (r dt − dc − N dR)/R``, at
    right angles to ``N`` (so ``|dN|`` is the angle); summed in quadrature over the covariance's four principal
    axes (not finite where the ray grazes, ``N·r = 0``).
    """
    R = float(g[3])
    N = (X - g[:3]) / R
    vals, vecs = np.linalg.eigh(cov)
    G = vecs * np.sqrt(np.maximum(vals, 0.0))  # columns: one s.d. along each principal axis
    dc, dR = G[:3], G[3]
    Nc, rc = N @ dc, r @ dc  # (n, 4)
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = (Nc + dR) / np.sum(N * r, axis=1)[:, None]
    rN = np.sum(r * N, axis=1)[:, None]
    # |r dt − dc − N dR|² expanded (|r| = |N| = 1)
    sq = dt**2 - 2 * dt * rc - 2 * dt * dR * rN + np.sum(dc * dc, axis=0) + 2 * dR * Nc + dR**2
    return np.sqrt(np.maximum(sq.sum(axis=1), 0.0)) / R


def _sphere_gauss_newton(Q: np.ndarray, r: np.ndarray, along: np.ndarray, cam: np.ndarray, model: RangeModel,
                         floor: float, c: np.ndarray, R: float, iterations: int
                         ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`one_sphere`'s weighted Gauss–Newton from ``(c, R)``, all relative to one reference point.

    ``Q`` (n, 3) the points and ``cam`` the camera, less the reference; ``r`` the points' unit directions from
    the camera, ``along`` their :func:`axis_cosine`. Returns ``(c, R, n, w, res)``: the sphere, and at it each point's outward normal, weight and
    weighted residual.
    """
    for it in range(iterations + 1):
        d = Q - c
        dist = np.sqrt(np.einsum("ij,ij->i", d, d))
        # the normal where each pixel's ray meets the current sphere, not the noisy point's direction from its
        # centre: that one leans with the point's own error (see one_sphere)
        n = on_rays("sphere", np.concatenate([c, [R]]), cam, r)[1]
        miss = ~np.isfinite(n[:, 0])
        n[miss] = d[miss] / dist[miss, None]  # outward on the near side; a miss keeps its point's
        w = 1.0 / normal_noise(n, r, along, model, floor)
        res = (dist - R) * w
        if it == iterations:
            break
        J = np.column_stack([-n, -np.ones(len(n))]) * w[:, None]
        H = J.T @ J
        if not np.all(np.isfinite(H)):
            break  # points no sphere describes (the residuals say so, and one_sphere refuses the fit)
        try:
            step = np.linalg.solve(H, -(J.T @ res))
            var = np.diag(np.linalg.inv(H))
        except np.linalg.LinAlgError:
            break
        c, R = c + step[:3], R + float(step[3])
        if np.all((var > 0) & (np.abs(step) <= SPHERE_STEP_SD * np.sqrt(np.abs(var)))):
            iterations = it + 1  # converged: the next pass only evaluates
    return c, R, n, w, res


def _quadric_design(u: np.ndarray) -> np.ndarray:
    """Rows ``[x², y², z², xy, xz, yz, x, y, z, 1]`` of the points ``u`` (n, 3), shape (n, 10)."""
    x, y, z = u.T
    return np.stack([x * x, y * y, z * z, x * y, x * z, y * z, x, y, z, np.ones_like(x)], axis=1)


def _gradient_selectors() -> np.ndarray:
    """``S`` (3, 10, 10) with each gradient row ``∂D/∂x_i = D·S[i]``: every entry of the gradient of a monomial
    of degree ≤ 2 is a monomial of degree ≤ 1, itself a column of ``D`` (so ``Σ GᵢᵀGᵢ = Sᵢᵀ (DᵀD) Sᵢ``)."""
    S = np.zeros((3, 10, 10))
    x, y, z, one = 6, 7, 8, 9  # the columns of x, y, z and 1 in D
    for i, col in enumerate((x, y, z)):
        S[i, col, i] = 2.0  # ∂(x_i²) = 2 x_i
        S[i, one, 6 + i] = 1.0  # ∂(x_i) = 1
    # the cross terms xy, xz, yz (columns 3, 4, 5)
    S[0, y, 3], S[1, x, 3] = 1.0, 1.0
    S[0, z, 4], S[2, x, 4] = 1.0, 1.0
    S[1, z, 5], S[2, y, 5] = 1.0, 1.0
    return S


GRADIENT = _gradient_selectors()


def _taubin(Mm: np.ndarray, Nm: np.ndarray) -> np.ndarray | None:
    """Taubin's quadric: the generalised eigenvector of ``(Σ DᵀD, Σ GᵀG)`` of the smallest finite eigenvalue."""
    import scipy.linalg

    with np.errstate(all="ignore"):
        vals, vecs = scipy.linalg.eig(Mm, Nm)
    vals = np.real(vals)
    ok = np.isfinite(vals) & (vals > -1e-9 * max(float(np.trace(Mm)), 1e-300))
    if not ok.any():
        return None
    a = np.real(vecs[:, np.flatnonzero(ok)[np.argmin(vals[ok])]])
    return a / np.linalg.norm(a)


def _quadric_surface(a: np.ndarray, o: np.ndarray, rays: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each ray ``o + τ r`` (scaled coordinates) meets the quadric ``a`` nearest ``τ = tau``, and the unit
    gradient there: ``(τ, normal)``, NaN where it misses."""
    A = np.array([[a[0], a[3] / 2, a[4] / 2], [a[3] / 2, a[1], a[5] / 2], [a[4] / 2, a[5] / 2, a[2]]])
    b, c = a[6:9], a[9]
    qa = np.einsum("ni,ij,nj->n", rays, A, rays)
    qb = 2 * rays @ (A @ o) + rays @ b
    qc = o @ A @ o + b @ o + c
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = np.sqrt(np.where(qb * qb - 4 * qa * qc >= 0, qb * qb - 4 * qa * qc, np.nan))
        q = -0.5 * (qb + np.copysign(disc, qb))
        roots = np.stack([q / qa, qc / q])  # both roots, stable
    pick = np.argmin(np.abs(np.nan_to_num(roots, nan=np.inf) - tau), axis=0)
    t = roots[pick, np.arange(len(tau))]
    u = o + t[:, None] * rays
    g = 2 * u @ A + b
    return t, g / np.linalg.norm(g, axis=1, keepdims=True)


def one_quadric(P: np.ndarray, valid: np.ndarray, rays: np.ndarray, cam: np.ndarray, model: RangeModel,
                floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, None] | None:
    """Points, normals and the normals' s.d. of one quadric surface (sphere, cylinder, cone, ellipsoid) through
    every valid pixel, when it fits within :data:`PLANE_FIT` × the range noise along the normal (a robust scale of
    the residuals); else None.

    Taubin's fit (G. Taubin, TPAMI 13(11), 1991: the algebraic residual
    over its gradient, to first order the geometric distance), its
    residuals the Sampson distances ``f/|∇f|``, their noise the range
    error's component along the normal (along the ray: ``σ·|n·r|``; along
    ``z``: ``σ·|n·r| / (r·axis)``). The normals' s.d. is a delete-one-block
    jackknife over :data:`JACKKNIFE_BLOCKS`² spatial blocks (the sums of the
    eigenproblem are additive, so each replicate costs one 10 × 10 solve).
    A plane must be tested before (:func:`one_plane`): it is a degenerate
    quadric, every plane pair through it fitting as well.
    """
    if valid.sum() < 50:
        return None
    X = P[valid]
    ref = X.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((X - ref) ** 2, axis=1))))
    u = (X - ref) / scale
    D = _quadric_design(u)
    block = jackknife_blocks(*np.nonzero(valid), valid.shape)
    present = np.unique(block)
    Mb = np.stack([D[block == k].T @ D[block == k] for k in present])
    Nb = np.einsum("iab,kac,icd->kbd", GRADIENT, Mb, GRADIENT)
    a = _taubin(Mb.sum(0), Nb.sum(0))
    if a is None:
        return None
    o = (cam - ref) / scale
    r = directions(X, cam)
    tau_meas = np.linalg.norm(X - cam, axis=1) / scale
    f = D @ a
    grad = np.stack([D @ (GRADIENT[i] @ a) for i in range(3)], axis=1)
    n = grad / np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-300)
    dist = f / np.maximum(np.linalg.norm(grad, axis=1), 1e-300) * scale  # Sampson distance, metres
    sigma_n = normal_noise(n, r, axis_cosine(r, rays, model), model, floor)
    # a robust scale (1.4826·median|d/σ|: 1 for Gaussian residuals) rather than the RMS: near a silhouette σ·|n·r|
    # is tiny, and there the first-order Sampson distance is least exact
    if not 1.4826 * np.median(np.abs(dist / sigma_n)) <= PLANE_FIT:
        return None
    t, N = _quadric_surface(a, o, r, tau_meas)
    # a ray that grazes the silhouette may miss the fitted quadric by a hair: its measured point, and the quadric's
    # gradient there
    miss = ~np.isfinite(t)
    t[miss], N[miss] = tau_meas[miss], n[miss]
    lattice = jackknife_lattice(valid)
    on = lattice[valid]
    turns = []
    for k in range(len(present)):
        ak = _taubin(Mb.sum(0) - Mb[k], Nb.sum(0) - Nb[k])
        if ak is None:
            return None
        tk, Nk = _quadric_surface(ak, o, r[on], tau_meas[on])
        Nk[~np.isfinite(tk)] = N[on][~np.isfinite(tk)]
        turns.append(Nk * np.sign(np.sum(Nk * N[on], axis=1, keepdims=True)))
    turns = np.stack(turns)
    g = len(present)
    spread = turns - turns.mean(axis=0)
    sd_lattice = np.full(valid.shape, np.nan)
    sd_lattice[lattice] = np.sqrt((g - 1) / g * np.sum(spread**2, axis=(0, 2)))
    sd = from_nearest(sd_lattice, lattice)[valid]
    N = towards(N, r)
    Pq = np.full(P.shape, np.nan)
    Nq = np.full(P.shape, np.nan)
    sdq = np.full(valid.shape, np.nan)
    Pq[valid], Nq[valid], sdq[valid] = cam + (t * scale)[:, None] * r, N, sd
    return Pq, Nq, sdq, None  # a quadric's parameters are not refined with the lamp (yet)
