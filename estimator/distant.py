"""Method ``distant``: the baseline the paper argues against.

A distant light and a distant viewer: one light direction ``l`` and one view
direction ``v`` for the whole image, so α, θi and θr depend on the normal
only, and the irradiance is the same everywhere (absorbed into Ks):
``I_s = Ks / cos θr · exp(−α² / 2σ²)``. ``v`` points from the specular
pixels' centroid to the camera; ``l``, Ks and σ are fitted in two stages:

* global: a deterministic grid of light directions on the hemisphere about
  the specular pixels' mean normal (plus ``l0``, the mirror of ``v`` about
  the peak pixel's normal) times a log-spaced grid of σ (plus the
  regression line's σ at ``l0``, eq. 16–17), Ks per channel profiled out
  by linear least squares; the lowest cost wins, and candidates whose cost
  is within :data:`TIE_TOLERANCE` × Σ I² of the lowest count as tied,
  resolved by the smallest angle to ``l0``, then the smallest ``|ln σ/σ0|``,
  then grid order;
* refinement: a robust fit of ``(l, Ks, σ)`` from the winner, with an
  analytic Jacobian and a weak anchor on ``l`` and σ at the winner
  (:data:`ANCHOR_WEIGHT`).

Why: a local fit depends on its start wherever the landscape over
``(l, σ)`` has several minima, which the grid guards against (on the
analytic spheres of the tests it finds the minimum the former local fit
from ``l0`` found). On a plane the landscape is flat: every pixel has the
same normal, so the distant model is one constant per channel and *every*
light direction and σ fit equally well (only Ks × lobe is determined). The
former fit drifted along that valley wherever the last bits pushed it: the
board of the near-vs-distant study with the lamp 0.1 m away gave direction
errors of 17.5° and 9.6° on two machines, and 9.0°–19.1° after ±1-ulp
changes of one render. So on a plane (α spreads by less than
:data:`PLANE_ALPHA_SPREAD` over the specular pixels) ``l`` stays at ``l0``
and σ at :data:`PLANE_SIGMA`, neither being determined by the data, and
only Ks is fitted; ``diagnostics["undetermined"]`` then names them, and the
rules every estimate passes refuse it (:mod:`nearlight.estimator.sanity`,
``determined``): its lamp is a placeholder.

Stability: a ±1-ulp float32 change of every image (stack, P, N) moves the
light direction by at most 1e-5 rad, ``lamp_position`` by at most 1e-5 of
the camera–highlight distance and σ and Ks by at most 1e-4 relative
(measured on analytic captures: ≤ 2e-7 and ≤ 7e-6;
``tests/estimator/test_stability.py``). The reported lamp hangs from the
peak's surface point (below), a discrete choice: rounding does not move it
(see :data:`~nearlight.estimator.observation.PEAK_TIE`), a larger change
that makes another pixel the brightest does, by that pixel's offset, while
the direction stays.

A distant light has no position: the reported ``lamp_position`` is the
peak's surface point plus ``l`` times the camera–highlight distance (the
distance at which the viewer is also assumed "distant"), and ``light_model``
holds both directions.

Range holes: the fit uses only specular pixels with range (finite ``P``);
the peak, its normal (the start's mirror direction) and its surface point
(the anchor above) may be a hole's filled pixel
(:func:`~nearlight.estimator.geometry.fill_range_holes`).
"""

from __future__ import annotations

import time

import numpy as np
from threadpoolctl import threadpool_limits

from ..capture import Capture
from ..errors import UserError
from .fitting import LOSSES, log_regression, robust_fit
from .observation import Observation, observation_of
from .options import Choice, Count, Fraction, Positive
from .separation import SEPARATION_METHODS
from .pixels import fit_pixels
from .result import Estimate
from ..physics.reflectance import mirror_direction, normalize, tangent_basis, torrance_sparrow, torrance_sparrow_lobe

#: Candidates whose profiled cost is within this fraction of Σ I² of the
#: lowest are tied. A 1-ulp float32 change of every pixel moves a cost by at
#: most 2 · 2⁻²⁴ · Σ |r| |I| ≤ 1.2e-7 Σ I²; 1e-5 is ~80 times that, and far
#: below the cost step between neighbouring grid directions of a curved
#: surface (≥ 1.7e-2 Σ I² measured on two analytic spheres, 96 × 72).
TIE_TOLERANCE = 1e-5

#: Weight of the anchor residuals ``w · (a, b, ln σ/σ_w)`` of the refinement,
#: as a fraction of the largest fitted specular radiance (a, b: tangent
#: offsets of ``l``, radians). Along a flat or nearly flat valley it keeps the
#: fit at the grid winner instead of wherever rounding pushes it; where the
#: data determine ``l`` and σ it moves them by nothing that matters
#: (measured on three analytic spheres: ≤ 3e-8 rad and ≤ 1e-7 relative).
ANCHOR_WEIGHT = 1e-3

#: Smallest lobe ``exp(−α²/2σ²)`` a candidate must reach at some pixel: a
#: light whose lobe is in its far tail everywhere "fits" only through an
#: absurd Ks (1e160 on a plane).
MIN_LOBE = 1e-3

#: σ reported when every pixel has the same α (a plane), radians.
PLANE_SIGMA = 0.1

#: Spread of α over the specular pixels (radians) below which they count as
#: having one α, as on a plane: float32 normals alone spread α = arccos(N·h)
#: near 0 by up to ~5e-4 rad (arccos(1 − 2⁻²⁴)), and a regression line on
#: that spread gives σ from rounding noise.
PLANE_ALPHA_SPREAD = 1e-2

#: Global-stage grid: directions on the hemisphere, σ values (radians), pixels.
N_DIRECTIONS = 256
SIGMA_GRID = np.geomspace(0.005, 0.8, 12)
GRID_PIXELS = 1000


def distant_specular(N: np.ndarray, light: np.ndarray, view: np.ndarray, ks: np.ndarray, sigma: float) -> np.ndarray:
    """Specular radiance under a distant light and viewer, shape ``(..., 3)``.

    Parameters
    ----------
    N : ndarray, shape (..., 3)
        Unit normals.
    light, view : ndarray, shape (3,)
        Unit directions towards the light and the viewer.
    ks : ndarray, shape (3,)
        Ks, absorbing the irradiance.
    sigma : float
        Roughness, radians.
    """
    h = normalize(light + view)
    cos_i, cos_r = N @ light, N @ view
    alpha = np.arccos(np.clip(N @ h, -1.0, 1.0))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        f = torrance_sparrow(cos_i, cos_r, alpha, ks=ks, sigma=sigma) * cos_i[..., None]
    lit = ((cos_i > 0) & (cos_r > 0))[..., None]
    return np.where(lit, np.nan_to_num(f), 0.0)


def hemisphere_directions(axis: np.ndarray, n: int) -> np.ndarray:
    """``n`` near-uniform unit directions on the hemisphere about ``axis`` (Fibonacci), shape (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1.0 - k / n
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    s = np.sqrt(1.0 - z**2)
    e1, e2 = tangent_basis(axis)
    return (s * np.cos(phi))[:, None] * e1 + (s * np.sin(phi))[:, None] * e2 + z[:, None] * np.asarray(axis)


def global_stage(
    N: np.ndarray, I: np.ndarray, view: np.ndarray, lights: np.ndarray, sigmas: np.ndarray,
    light0: np.ndarray, sigma0: float,
) -> dict:
    """Lowest-cost ``(l, σ)`` on a grid with Ks profiled out, ties broken deterministically.

    Parameters
    ----------
    N : ndarray, shape (n, 3)
        Unit normals of the pixels.
    I : ndarray, shape (n, 3)
        Their specular radiance.
    view : ndarray, shape (3,)
    lights : ndarray, shape (L, 3)
        Candidate unit light directions.
    sigmas : ndarray, shape (S,)
        Candidate σ, radians. A candidate counts only if its lobe reaches
        :data:`MIN_LOBE` at some lit pixel.
    light0, sigma0 :
        The tie-break reference: among tied candidates (see
        :data:`TIE_TOLERANCE`), the smallest angle to ``light0``, then the
        smallest ``|ln σ/σ0|``, then the lowest grid index wins.

    Returns
    -------
    dict
        ``light_direction``, ``sigma``, ``ks`` (shape (3,)), ``cost``
        (``½ Σ`` squared residuals), ``n_candidates``, ``n_tied``.
    """
    cos_r = N @ view
    h = normalize(lights + view)  # (L, 3)
    cos_i = lights @ N.T  # (L, n)
    alpha2 = np.arccos(np.clip(h @ N.T, -1.0, 1.0)) ** 2
    lit = (cos_i > 0) & (cos_r > 0)[None]
    log_base = np.where(lit, -np.log(np.where(cos_r > 0, cos_r, 1.0))[None], -np.inf)
    a2_min = np.min(np.where(lit, alpha2, np.inf), axis=1)  # (L,)
    total = float(np.sum(I**2))
    costs = np.full((len(lights), len(sigmas)), np.inf)
    ks = np.zeros((len(lights), len(sigmas), 3))
    for j, s in enumerate(sigmas):
        # log g, shifted per candidate so that its largest g is 1 (no underflow); Ks absorbs the shift.
        log_g = log_base - alpha2 / (2.0 * s**2)
        top = np.max(log_g, axis=1, keepdims=True)
        ok = np.isfinite(top[:, 0]) & (a2_min / (2.0 * s**2) <= -np.log(MIN_LOBE))
        g = np.exp(log_g - np.where(np.isfinite(top), top, 0.0))  # (L, n), 0 where unlit
        gg = np.einsum("ln,ln->l", g, g)
        gi = np.maximum(g @ I, 0.0)  # (L, 3); Ks ≥ 0
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            explained = np.sum(gi**2, axis=1) / gg
            ks[:, j] = gi / gg[:, None] * np.exp(-top)
        costs[ok, j] = 0.5 * (total - explained[ok])
    tied = np.argwhere(costs <= costs.min() + 0.5 * TIE_TOLERANCE * total)
    angle = np.arccos(np.clip(lights @ light0, -1.0, 1.0))
    dist_sigma = np.abs(np.log(sigmas / sigma0))
    li, si = min(map(tuple, tied), key=lambda t: (angle[t[0]], dist_sigma[t[1]], t[0], t[1]))
    ks = ks[li, si]
    return {
        "light_direction": lights[li], "sigma": float(sigmas[si]), "ks": ks, "cost": float(costs[li, si]),
        "n_candidates": int(costs.size), "n_tied": int(len(tied)),
    }


class DistantModel:
    """Residuals of the distant model at fixed pixels, with an anchor, and their Jacobian.

    Parameters ``x = (a, b, Ks_R, Ks_G, Ks_B, σ)``, the light direction being
    ``l = (l_w + a e1 + b e2) / |…|`` with ``(e1, e2)`` a tangent basis at
    ``l_w``. Residuals: ``model − observed`` flattened pixel-major
    ``[n · 3]``, then the anchor ``w · (a, b, ln σ/σ_w)`` (3 entries).

    Parameters
    ----------
    N : ndarray, shape (n, 3)
        Unit normals.
    observed : ndarray, shape (n, 3)
        Specular radiance.
    view, anchor : ndarray, shape (3,)
        Unit view direction and the anchor light direction ``l_w``.
    weight : float
        Anchor weight ``w``, radiance per radian.
    sigma_anchor : float
        σ_w, radians.
    """

    def __init__(self, N: np.ndarray, observed: np.ndarray, view: np.ndarray, anchor: np.ndarray, *,
                 weight: float, sigma_anchor: float):
        self.N, self.observed, self.view, self.anchor = N, observed, view, anchor
        self.e1, self.e2 = tangent_basis(anchor)
        self.weight, self.sigma_anchor = weight, sigma_anchor
        self.cos_r = N @ view

    def light(self, x: np.ndarray) -> np.ndarray:
        """Unit light direction for parameters x, shape (3,)."""
        return normalize(self.anchor + x[0] * self.e1 + x[1] * self.e2)

    def _lobe(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``g = exp(−α²/2σ²) / cos θr`` where lit (else 0) [n], α [n], h and l."""
        l = self.light(x)
        h = normalize(l + self.view)
        alpha = np.arccos(np.clip(self.N @ h, -1.0, 1.0))
        lit = (self.N @ l > 0) & (self.cos_r > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(lit, torrance_sparrow_lobe(alpha, x[5]) / self.cos_r, 0.0)
        return g, alpha, h, l

    def residuals(self, x: np.ndarray) -> np.ndarray:
        g, _, _, _ = self._lobe(x)
        data = (g[:, None] * x[2:5] - self.observed).ravel()
        return np.concatenate([data, self.weight * np.array([x[0], x[1], np.log(x[5] / self.sigma_anchor)])])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Analytic ``∂ residuals / ∂ x``, shape ``(n · 3 + 3, 6)``.

        With ``u = l_w + a e1 + b e2``, ``l = u/|u|``, ``s = l + v``,
        ``h = s/|s|``: ``∂l/∂a = (I − l lᵀ) e1 / |u|``,
        ``∂(N·h)/∂a = N·(I − h hᵀ) ∂l/∂a / |s|``, ``∂α/∂a = −∂(N·h)/∂a / sin α``,
        so ``∂g/∂a = g α/(σ² sin α) · ∂(N·h)/∂a`` (likewise for b) and
        ``∂g/∂σ = g α²/σ³``, ``g`` the lobe of :meth:`residuals`.
        """
        g, alpha, h, l = self._lobe(x)
        sigma = x[5]
        u = self.anchor + x[0] * self.e1 + x[1] * self.e2
        norm_u, norm_s = np.linalg.norm(u), np.linalg.norm(l + self.view)
        sin_a = np.sin(alpha)
        ratio = np.where(sin_a > 1e-12, alpha / np.where(sin_a > 1e-12, sin_a, 1.0), 1.0)
        n = len(g)
        J = np.zeros((n * 3 + 3, 6))
        Jd = J[: n * 3].reshape(n, 3, 6)
        for k, e in enumerate((self.e1, self.e2)):
            dl = (e - (e @ l) * l) / norm_u
            dh = (dl - (dl @ h) * h) / norm_s
            dg = g * ratio / sigma**2 * (self.N @ dh)
            Jd[:, :, k] = dg[:, None] * x[2:5]
        Jd[:, [0, 1, 2], [2, 3, 4]] = g[:, None]
        Jd[:, :, 5] = (g * alpha**2 / sigma**3)[:, None] * x[2:5]
        J[n * 3 + np.arange(3), [0, 1, 5]] = self.weight * np.array([1.0, 1.0, 1.0 / sigma])
        return J


def _initial(obs: Observation, view: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """The mirror direction at the peak; Ks, σ from the regression line there (eq. 16–17); one α?

    The last is true when α spreads by less than :data:`PLANE_ALPHA_SPREAD`
    over the specular pixels (a plane). Then, or when the regression slope is
    not negative, Ks starts at the peak's and σ at :data:`PLANE_SIGMA`.
    """
    m = obs.mask
    light0 = mirror_direction(obs.N[obs.peak], view)
    Nm = obs.N[m]
    h0 = normalize(light0 + view)
    cos_r = Nm @ view
    ok = cos_r > 0
    alpha = np.arccos(np.clip(Nm[ok] @ h0, -1.0, 1.0))
    Y = np.log(obs.specular[m][ok]) + np.log(cos_r[ok])[:, None]
    one_alpha = bool(np.ptp(alpha) < PLANE_ALPHA_SPREAD)
    if not one_alpha:
        try:
            ks0, sigma0, _ = log_regression(0.5 * alpha**2, Y, where=where)
            return light0, ks0, sigma0, False
        except UserError:
            pass  # no falling lobe along α: start as on a plane, but fit l and σ
    # A plane under a distant light and viewer has one α everywhere (the
    # paper's point): start from the peak (α = 0 there) and PLANE_SIGMA.
    return light0, obs.specular[obs.peak] * float(obs.N[obs.peak] @ view), PLANE_SIGMA, one_alpha


def distant_estimate(
    capture: Capture,
    *,
    separation: Choice(SEPARATION_METHODS) = "fit",
    threshold: Fraction = 0.05,
    loss: Choice(LOSSES) = "soft_l1",
    max_pixels: Count = 20000,
    saturation: Positive | None = None,
) -> Estimate:
    """Method ``distant``: fit one light direction, Ks and σ with one view direction.

    See the module docstring for the two stages, the plane case and the
    stated stability under float rounding (light direction to 1e-5 rad, σ
    and Ks to 1e-4 relative; ``lamp_position`` to 1e-5 of the
    camera–highlight distance).

    Parameters
    ----------
    capture : Capture
    separation, threshold :
        As for ``paper-init`` (:func:`~nearlight.estimator.observation.observation_of`).
    loss, max_pixels, saturation :
        As for ``full`` (:func:`~nearlight.estimator.full.full_estimate`).

    Returns
    -------
    Estimate
        ``stages``: ``init`` (mirror direction, Ks and σ of the regression
        line), ``global`` (the grid winner, or why it was skipped) and ``fit``.
    """
    clock = time.perf_counter()
    obs = observation_of(capture, separation=separation, threshold=threshold)
    timings = {"observe": time.perf_counter() - clock}
    clock = time.perf_counter()
    view = normalize(obs.camera_position - obs.P[obs.mask].mean(axis=0))
    light0, ks0, sigma0, one_alpha = _initial(obs, view, where=f"{capture.name}: specular")
    timings["init"] = time.perf_counter() - clock
    clock = time.perf_counter()

    use = fit_pixels(obs, max_pixels=int(max_pixels), saturation=saturation)
    N, I = obs.N[use], obs.specular[use]
    if one_alpha:
        # A plane: the model is one constant per channel, so l and σ are not
        # determined at all; they stay at the start and only Ks is fitted.
        won = {"skipped": "one alpha at every specular pixel (a plane): light direction and sigma kept at the start"}
        lw, sw, ks_start, free = light0, sigma0, ks0, [2, 3, 4]
    else:
        sub = slice(None, None, max(1, len(N) // GRID_PIXELS))
        axis = normalize(obs.N[obs.mask].mean(axis=0))
        lights = np.concatenate([light0[None], hemisphere_directions(axis, N_DIRECTIONS)])
        sigmas = np.concatenate([[sigma0], SIGMA_GRID])
        with threadpool_limits(limits=1, user_api="blas"):  # small matrices: see robust_fit
            won = global_stage(N[sub], I[sub], view, lights, sigmas, light0, sigma0)
        lw, sw, ks_start, free = won["light_direction"], won["sigma"], won["ks"], [0, 1, 2, 3, 4, 5]
    timings["global"] = time.perf_counter() - clock
    clock = time.perf_counter()

    weight = 0.0 if one_alpha else ANCHOR_WEIGHT * float(np.max(I))
    model = DistantModel(N, I, view, lw, weight=weight, sigma_anchor=sw)
    ks_start = np.where(np.asarray(ks_start) > 0, ks_start, 1e-12 * float(np.max(I)))
    full_x = np.concatenate([[0.0, 0.0], ks_start, [sw]])

    def expand(xf: np.ndarray) -> np.ndarray:
        x = full_x.copy()
        x[free] = xf
        return x

    typical = np.concatenate([[0.1, 0.1], np.abs(ks_start) + 1e-12, [sw]])[free]
    lower = np.concatenate([[-np.inf, -np.inf], np.zeros(3), [1e-4]])[free]
    upper = np.concatenate([[np.inf, np.inf], np.full(3, np.inf), [np.pi / 2]])[free]
    rows = slice(None) if weight > 0 else slice(0, 3 * len(N))
    fit = robust_fit(lambda xf: model.residuals(expand(xf))[rows], full_x[free], typical=typical, lower=lower,
                     upper=upper, loss=loss, jac=lambda xf: model.jacobian(expand(xf))[rows][:, free],
                     f_floor=1e-4 * float(np.max(I)))
    x = expand(fit["x"])
    direction = model.light(x)
    lamp = obs.peak_point + obs.scale * direction
    timings["fit"] = time.perf_counter() - clock
    return Estimate(
        method="distant",
        lamp_position=lamp,
        ks=x[2:5],
        sigma=x[5],
        stages={
            "init": {"light_direction": light0, "ks": ks0, "sigma": sigma0},
            "global": won,
            "fit": {"light_direction": direction, "ks": x[2:5], "sigma": x[5], "n_pixels": int(use.sum()),
                    **{k: fit[k] for k in ("f_scale", "cost", "nfev", "status", "rms")}},
        },
        diagnostics={"peak_pixel": list(obs.peak), "n_specular_pixels": int(obs.mask.sum()),
                     "undetermined": ["light_direction", "sigma"] if one_alpha else []},
        timings=timings,
        light_model={"type": "distant", "light_direction": direction, "view_direction": view},
    )
