"""The point-lamp model and its fits: what ``full`` (one lamp or several) fits, from where, and how.

:class:`PointLampModel` is the closed-form specular radiance of docs/physics.md
for one point lamp, ``I_s = colour · F / r²`` (``I_lamp = 1``: the colour
absorbs the lamp intensity, ``F`` the lobe of one family of
:mod:`~nearlight.estimator.lobes`), at fixed surface pixels, with its
analytic Jacobian; several lamps are a sum of it
(:class:`~nearlight.estimator.lampsum.SeveralLampModel`).

Starts: :func:`start_observation` thins the specular mask for the paper's
first stage (:mod:`~nearlight.estimator.first_stage`), and
:func:`peak_ray_starts` spreads starting points along its peak ray.

Fits, of a one- or several-lamp model alike, in the parameters
``(l₁, c₁, …, l_K, c_K, a)`` (each lamp's position in metres and colour, then
the lobe family's roughness; :func:`lamp_bounds`, :func:`typical_scale`):
:func:`short_fit`, a linear-loss fit by variable projection in a few
evaluations; :func:`best_short_fit`, the multi-start over short fits; and
:func:`final_fit`, the robust fit on every fitted pixel
(:func:`~nearlight.estimator.fitting.robust_fit`) with its sandwich covariance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import numpy as np

from ..errors import UserError
from ..physics.reflectance import finite, normalize, shading_geometry
from .first_stage import RaySearch
from .fitting import log_regression, robust_fit
from .lobes import log_derivatives, radiance
from .observation import Observation
from .result import Estimate


class PointLampModel:
    """Specular radiance of a point lamp (I = 1) at fixed pixels, with its Jacobian.

    Parameters ``x = (x, y, z, Ks_R, Ks_G, Ks_B, a)``, ``a`` the lobe family's
    own roughness (σ for Torrance–Sparrow); residuals are
    ``(model − observed) / std``, flattened pixel-major ``[n · 3]``.

    Parameters
    ----------
    P, N : ndarray, shape (n, 3)
        Surface points (m) and unit normals.
    camera : ndarray, shape (3,)
    observed : ndarray, shape (n, 3)
        Specular radiance.
    lobe : str
        A family of :data:`~nearlight.estimator.lobes.FAMILIES`.
    std : ndarray, shape (n, 3), optional
        Standard deviation of each observed value (radiance units); None: 1.
    """

    def __init__(self, P: np.ndarray, N: np.ndarray, camera: np.ndarray, observed: np.ndarray, *,
                 lobe: str = "torrance_sparrow", std: np.ndarray | None = None):
        self.P, self.N, self.camera, self.observed, self.lobe = P, N, camera, observed, lobe
        self.std = std
        self._inv = None if std is None else 1.0 / std
        self.view = normalize(np.asarray(camera, dtype=float) - P)  # the lamp moves, the camera does not
        self._at: tuple[np.ndarray, tuple] | None = None

    def subset(self, rows: slice | np.ndarray) -> PointLampModel:
        """The same model on some of its pixels (contiguous copies: a strided view slows every step of the fit)."""
        def take(a: np.ndarray) -> np.ndarray:
            return np.ascontiguousarray(a[rows])

        return PointLampModel(take(self.P), take(self.N), self.camera, take(self.observed), lobe=self.lobe,
                              std=None if self.std is None else take(self.std))

    def with_lobe(self, lobe: str) -> PointLampModel:
        """The same pixels and weights with another lobe family."""
        return PointLampModel(self.P, self.N, self.camera, self.observed, lobe=lobe, std=self.std)

    def with_geometry(self, P: np.ndarray, N: np.ndarray) -> PointLampModel:
        """The same pixels' observations, weights and lobe on other surface points ``P`` and unit normals ``N``
        (n, 3): ``full``'s joint fit moving the surface."""
        return PointLampModel(P, N, self.camera, self.observed, lobe=self.lobe, std=self.std)

    def _lobe(self, x: np.ndarray) -> tuple:
        """``f = F / r²`` where lit (else 0), shape (n,), the geometry and where lit, at ``x``.

        The last lamp's and roughness's are kept: the solver asks for the
        residuals and then the Jacobian at the same point, which share them,
        and the colours solved at that point (:meth:`linear_colours`) too.
        """
        key = x[[0, 1, 2, 6]]  # the lamp and the roughness: not the colour
        if self._at is not None and np.array_equal(self._at[0], key):
            return self._at[1]
        g = shading_geometry(self.P, self.N, self.camera, x[:3], view=self.view)
        lit = (g.cos_i > 0) & (g.cos_r > 0)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            F = radiance(self.lobe, g.cos_i, g.cos_r, g.alpha, x[6])
            f = np.where(lit, finite(F / g.r**2), 0.0)
        self._at = (np.array(key, dtype=float), (f, g, lit))
        return f, g, lit

    def _weigh(self, r: np.ndarray) -> np.ndarray:
        return r if self._inv is None else r * self._inv

    def residuals(self, x: np.ndarray) -> np.ndarray:
        f = self._lobe(x)[0]
        return self._weigh(f[:, None] * x[3:6] - self.observed).ravel()

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Analytic ``∂ residuals / ∂ x``, shape ``(n · 3, 7)`` (Fortran-ordered).

        With ``h = (l + v)/|l + v|``, ``c = N·h``: ``∂r/∂L = l``,
        ``∂c/∂L = (I − l lᵀ)(I − h hᵀ) N / (|l + v| r)``,
        ``∂cos θi/∂L = (N − cos θi l) / r``, so
        ``∂f/∂L = f (∂ln F/∂c · ∂c/∂L + ∂ln F/∂cos θi · ∂cos θi/∂L − 2 l / r)``
        and ``∂f/∂a = f ∂ln F/∂a`` (:mod:`~nearlight.estimator.lobes`).
        """
        f, g, lit = self._lobe(x)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            d_c, d_i, d_a = (np.where(lit, finite(d), 0.0)
                             for d in log_derivatives(self.lobe, g.cos_i, g.cos_r, g.alpha, x[6]))
        s = g.light + g.view
        inv_s = 1.0 / np.sqrt(np.einsum("ij,ij->i", s, s))
        h = s * inv_s[:, None]
        w = (self.N - np.einsum("ij,ij->i", self.N, h)[:, None] * h) * inv_s[:, None]  # ∂c/∂L = (w − (w·l) l) / r
        # ∂f/∂L = f/r · (d_c w + d_i N − (d_c w·l + d_i cos θi + 2) l)
        along = d_c * np.einsum("ij,ij->i", w, g.light) + d_i * g.cos_i + 2.0
        df_dL = (f / g.r)[:, None] * (d_c[:, None] * w + d_i[:, None] * self.N - along[:, None] * g.light)
        # built parameter-major, (7, n, 3), and returned as its Fortran-ordered transpose: contiguous writes
        # here, and the layout the solver's SVD (LAPACK) takes without a copy
        ks = x[3:6]
        J = np.empty((7, len(f), 3))
        np.multiply(df_dL.T[:, :, None], ks, out=J[:3])
        J[3:6] = 0.0
        for m in range(3):
            J[3 + m, :, m] = f
        np.multiply((f * d_a)[:, None], ks, out=J[6])
        if self._inv is not None:
            J *= self._inv
        return J.reshape(7, -1).T

    def linear_colours(self, x: np.ndarray) -> np.ndarray:
        """``x`` with the (weighted) non-negative least-squares colour for its lamp and roughness.

        Per channel ``Ks = max(Σ w f o / Σ w f², 0)`` (``w = 1/std²``); a
        channel the lamp does not light keeps ``x``'s.
        """
        f = self._lobe(x)[0]
        wt = np.ones_like(self.observed) if self._inv is None else self._inv**2
        fw = f[:, None] * wt
        den = np.sum(fw * f[:, None], axis=0)
        out = np.array(x, dtype=float)
        out[3:6] = np.where(den > 0, np.maximum(np.sum(fw * self.observed, axis=0) / np.where(den > 0, den, 1.0), 0.0),
                            x[3:6])
        return out



#: About how many specular pixels the start's t search and regressions use (:func:`start_observation`).
START_PIXELS = 2000


def start_observation(obs: Observation, n_pixels: int = START_PIXELS) -> Observation:
    """``obs`` with its specular mask thinned to a square lattice of about ``n_pixels`` pixels, for the start.

    The lattice's step is ``⌊√(n_mask / n_pixels)⌋`` pixels (1: the mask as
    it is) and it passes through the peak pixel, so the thinned mask does not
    depend on the order of the pixels and moves with the image only where
    the mask's own edge moves. The start's E_p(t) and regressions
    (:func:`~nearlight.estimator.first_stage.ray_stage`, :func:`peak_ray_starts`) on the
    lattice cost ``1/step²`` of the whole mask's; the start only has to land
    in the minimum's basin, which the multi-start and the short fits then
    settle (see :func:`~nearlight.estimator.full.full_estimate`'s "Speed").

    Parameters
    ----------
    obs : Observation
    n_pixels : int
        Target count; a mask of fewer than ``4 · n_pixels`` pixels is kept whole.

    Returns
    -------
    Observation
        A copy sharing ``obs``'s arrays but ``mask``, shape (H, W).
    """
    step = int(np.sqrt(int(obs.mask.sum()) / n_pixels))
    if step <= 1:
        return obs
    i, j = obs.peak
    lattice = np.zeros_like(obs.mask)
    lattice[i % step::step, j % step::step] = True
    return dataclasses.replace(obs, mask=obs.mask & lattice)


def peak_ray_starts(init: Estimate, obs: Observation, *, n_starts: int) -> list[np.ndarray]:
    """Starting points: the first stage's, then points on its peak ray, the middle distances first.

    The peak ray's t is poorly determined (E_p(t) is flat when the ray misses
    the lamp by a degree or two), so the fit also starts from ``n_starts``
    distances between 0.1 and 3 × the camera–highlight distance (log-spaced),
    each with Ks and σ from the regression line at that distance. They come
    nearest the range's geometric middle first, since those reach the best
    fit most often (all 240 one-lamp captures of the sensitivity study, for
    0.39–1.5 ×) and :func:`best_short_fit` stops
    once two starts agree.

    Returns
    -------
    list of ndarray, shape (7,)
        ``(x, y, z, Ks_R, Ks_G, Ks_B, σ)``, the first stage's first.
    """
    ray = RaySearch(obs)
    starts = [np.concatenate([init.lamp_position, init.ks, [init.sigma]])]
    distances = sorted(np.geomspace(0.1, 3.0, n_starts), key=lambda d: (round(abs(np.log(d / np.sqrt(0.3))), 9), d))
    for t in np.array(distances) * obs.scale:
        X, Y = ray.xy(np.array([t]))
        try:
            ks, sigma, _ = log_regression(X[0], Y[0])
        except UserError:
            continue
        starts.append(np.concatenate([ray.lamp(t), ks, [sigma]]))
    return starts



#: The range of the roughness parameter the lamp fits may reach (rad for Torrance–Sparrow): a spread of facet
#: angles beyond π/2 means nothing; 1e-4 keeps the lobe's width positive, far below any material the benchmark
#: renders. The sanity rules refuse a reported σ at either end (:mod:`nearlight.estimator.sanity`, ``roughness-range``).
ROUGHNESS_RANGE = (1e-4, np.pi / 2)


def lamp_bounds(n_params: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the parameters ``(l₁, c₁, …, l_K, c_K, a)`` of K lamps.

    Parameters
    ----------
    n_params : int
        ``6K + 1``.

    Returns
    -------
    lower, upper : ndarray, shape (n_params,)
        Positions free (m), colours ≥ 0, roughness in :data:`ROUGHNESS_RANGE`.
    """
    colour = colour_columns(n_params)
    lower = np.where(colour, 0.0, -np.inf)
    upper = np.full(n_params, np.inf)
    lower[-1], upper[-1] = ROUGHNESS_RANGE
    return lower, upper


def typical_scale(x: np.ndarray, scale: float) -> np.ndarray:
    """Typical size of each parameter of ``x`` (the fit's variable scaling).

    Parameters
    ----------
    x : ndarray, shape (6K + 1,)
        ``(l₁, c₁, …, l_K, c_K, a)``.
    scale : float
        Camera–highlight distance (m): each position coordinate's size.

    Returns
    -------
    ndarray, shape (6K + 1,)
        ``scale`` per coordinate, ``|colour| + 1e-12`` per channel, the roughness itself.
    """
    colour = colour_columns(len(x))
    out = np.full(len(x), float(scale))
    out[colour] = np.abs(x[colour]) + 1e-12
    out[-1] = x[-1]
    return out


def colour_columns(n_params: int) -> np.ndarray:
    """Which of the parameters ``(l₁, c₁, …, l_K, c_K, a)`` of K lamps are colours.

    Parameters
    ----------
    n_params : int
        ``6K + 1``.

    Returns
    -------
    ndarray of bool, shape (n_params,)
    """
    return np.r_[np.tile(np.r_[np.zeros(3, bool), np.ones(3, bool)], (n_params - 1) // 6), False]


def short_fit(model: Any, x0: np.ndarray, scale: float) -> dict:
    """A linear-loss fit of a one- or several-lamp model from ``x0``, by variable projection.

    The colours enter the model linearly: at every step they are solved for
    (non-negative least squares, the model's ``linear_colours``) and the
    solver moves only the lamps' positions and the roughness (3K + 1
    unknowns), with Kaufman's Jacobian (the full one with the solved
    colours' columns projected out): from the same starts it reaches the
    optimum more often, in fewer evaluations, than a fit of all 6K + 1
    parameters (docs/measurements/estimator-choices.md, "Point-lamp fits").
    Budget: 30 evaluations for one lamp, 100 for several (a two-lamp start
    from a dim lamp's residual needs more).

    Parameters
    ----------
    model : PointLampModel or SeveralLampModel
    x0 : ndarray, shape (6K + 1,)
        Start (clipped to :func:`lamp_bounds`; its colours are not used).
    scale : float
        Camera–highlight distance (m), see :func:`typical_scale` (of the unclipped ``x0``).

    Returns
    -------
    dict
        :func:`~nearlight.estimator.fitting.robust_fit`'s result, its ``x``
        the whole ``(6K + 1,)`` parameters with the solved colours and
        ``cov`` that of the free parameters only.
    """
    lower, upper = lamp_bounds(len(x0))
    start = np.clip(x0, lower, upper)
    colour = colour_columns(len(x0))
    free = ~colour
    last: list = [None, None]

    def solved(u: np.ndarray) -> np.ndarray:
        if last[0] is None or not np.array_equal(last[0], u):
            x = start.copy()
            x[free] = u
            last[:] = [np.array(u, dtype=float), model.linear_colours(x)]
        return last[1]

    def residuals(u: np.ndarray) -> np.ndarray:
        return model.residuals(solved(u))

    def jacobian(u: np.ndarray) -> np.ndarray:
        x = solved(u)
        J = model.jacobian(x)
        return project_out(J[:, free], J[:, colour & (x > 0)])

    result = robust_fit(residuals, start[free], typical=typical_scale(x0, scale)[free], lower=lower[free],
                        upper=upper[free], loss="linear", f_scale=1.0, jac=jacobian,
                        max_nfev=100 if len(x0) > 7 else 30)
    return {**result, "x": solved(result["x"]).copy()}


#: Two short fits whose costs are this close (relative) found the same minimum (:func:`best_short_fit`):
#: well above the spread of one minimum's cost from different starts (≤ 2e-9 relative over the
#: sensitivity study's 240 one-lamp captures) and far below the next minimum's (> 1e-3 there).
SAME_MINIMUM = 1e-6


def best_short_fit(model: Any, starts: Iterable[np.ndarray], scale: float) -> tuple[dict, int]:
    """The lowest-cost :func:`short_fit` over ``starts``, tried in order until two reach the same lowest cost.

    A multi-start search that stops once its best minimum has been found
    twice (costs within :data:`SAME_MINIMUM` of each other): a second start
    landing on it says that its basin is the wide one the starts were spread
    to find, and the remaining starts are there for when the first ones
    disagree. With ``full``'s starts tried middle distance first
    (:func:`peak_ray_starts`) it stops after two on nearly every capture
    (docs/measurements/estimator-choices.md, "Point-lamp fits").

    Parameters
    ----------
    model : PointLampModel or SeveralLampModel
    starts : iterable of ndarray, shape (6K + 1,)
        In the order to try them.
    scale : float
        Camera–highlight distance (m).

    Returns
    -------
    best : dict
        :func:`short_fit`'s result of least cost.
    tried : int
        How many starts were fitted.
    """
    best, found, tried = None, 0, 0
    for x0 in starts:
        r = short_fit(model, x0, scale)
        tried += 1
        if best is None or r["cost"] < best["cost"] - SAME_MINIMUM * best["cost"]:
            best, found = r, 1
            continue
        if r["cost"] <= best["cost"] + SAME_MINIMUM * best["cost"]:
            found += 1
            best = min(best, r, key=lambda v: v["cost"])
        if found >= 2:
            break
    if best is None:
        raise ValueError("best_short_fit: no starts")
    return best, tried


def project_out(Jf: np.ndarray, Jc: np.ndarray) -> np.ndarray:
    """``Jf`` with its projection on the columns of ``Jc`` removed (Kaufman's variable-projection Jacobian).

    The projection does not depend on the columns' lengths, so each column
    of ``Jc`` is first divided by its largest magnitude: a lamp that lights
    almost nothing has colour columns of ~1e-155, whose Gram entries
    underflow to denormals and made the normal equations return inf
    (measured in the sensitivity study, a two-lamp fit). All-zero columns
    are left out; where the scaled Gram matrix is singular (two lamps
    alike), a least-squares solve is used instead.

    Parameters
    ----------
    Jf : ndarray, shape (m, p)
        Jacobian columns of the parameters the solver moves.
    Jc : ndarray, shape (m, q)
        Jacobian columns of the solved (linear) parameters, q ≤ 3K.

    Returns
    -------
    ndarray, shape (m, p)
    """
    size = np.max(np.abs(Jc), axis=0, initial=0.0)
    keep = size > 0
    if not keep.any():
        return Jf
    Q = Jc[:, keep] / size[keep]
    try:  # the Gram matrix is small (≤ 3K × 3K) and, for one lamp, diagonal
        coef = np.linalg.solve(Q.T @ Q, Q.T @ Jf)
    except np.linalg.LinAlgError:
        coef = None
    if coef is None or not np.all(np.isfinite(coef)):
        coef = np.linalg.lstsq(Q, Jf, rcond=None)[0]
    return Jf - Q @ coef


def final_fit(model: Any, x0: np.ndarray, scale: float, *, loss: str, f_scale: float | None,
              floor: float) -> dict:
    """The robust fit of a one- or several-lamp model on every fit pixel, from a short fit's ``x0``.

    Parameters
    ----------
    model : PointLampModel or SeveralLampModel
    x0 : ndarray, shape (6K + 1,)
        Start, within :func:`lamp_bounds` (a :func:`short_fit`'s result).
    scale : float
        Camera–highlight distance (m), see :func:`typical_scale`.
    loss, f_scale
        The robust loss and its scale, as :func:`~nearlight.estimator.fitting.robust_fit`'s.
    floor : float
        :func:`loss_floor`, in the residuals' units.

    Returns
    -------
    dict
        :func:`~nearlight.estimator.fitting.robust_fit`'s result.
    """
    lower, upper = lamp_bounds(len(x0))
    return robust_fit(model.residuals, x0, typical=typical_scale(x0, scale), lower=lower, upper=upper, loss=loss,
                      f_scale=f_scale, jac=model.jacobian, f_floor=floor, start_is_fit=True, tol=FINAL_TOL)


#: :func:`final_fit`'s tolerances (``least_squares``' ``xtol``, ``ftol``, ``gtol``). Measured on the
#: 640×480 analytic board and sphere, noise-free and with the sensitivity study's low camera noise
#: (two seeds): against 1e-12, the estimate moves by at most 2.1e-7 of its standard deviation
#: (lamp ≤ 1.7e-11 m) and the fit takes one or two evaluations fewer of its 3–8 (~20 ms each).
FINAL_TOL = 1e-8


def loss_floor(specular: np.ndarray, std: np.ndarray | None) -> float:
    """The smallest residual scale the fit and the lamp count trust, in the residuals' units.

    The loss stays quadratic within a noise-free capture's float rounding:
    1e-4 of the peak unweighted, one standard deviation weighted (whose
    floor is that same 1e-4 of the peak, :func:`~nearlight.estimator.noise.specular_variance`).

    Parameters
    ----------
    specular : ndarray, shape (n, 3)
        The fit pixels' separated specular radiance.
    std : ndarray, shape (n, 3), or None
        Their standard deviations (None: unweighted fit).

    Returns
    -------
    float
    """
    return 1e-4 * float(np.max(specular)) if std is None else 1.0
