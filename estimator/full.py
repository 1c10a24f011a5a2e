"""Method ``full``: nonlinear least squares over the lamp's 3-D position, the specular colour and roughness.

The paper's first stage puts the lamp on the ray from the peak pixel along
the mirror direction, but the peak pixel is not the mirror point: the
``1/cos θr`` and ``1/r²`` factors move the intensity peak away from α = 0,
and pixels quantise it. So ``full`` starts from the paper's first stage
(``paper-init``'s, on a lattice of the specular pixels: :func:`start_observation`) and fits the
closed-form specular radiance of docs/physics.md, ``I_s = colour · F / r²``
(``I_lamp = 1``: the colour absorbs the lamp intensity), with ``F`` the lobe
of one family (:mod:`~nearlight.estimator.lobes`: the paper's
Torrance–Sparrow ``F = exp(−α² / 2σ²) / cos θr``, Ward, GGX, Beckmann;
chosen automatically by default), to the specular image over all seven
parameters ``(x, y, z, colour_R, colour_G, colour_B, roughness)``, with a
robust loss and a sandwich covariance (see
:func:`~nearlight.estimator.fitting.robust_fit`).

The fit uses only pixels with range (finite ``P``); a range hole on the
highlight takes its pixels out of the fit but not out of the start, whose
ray begins at the hole's filled point
(:func:`~nearlight.estimator.observation.fill_range_holes`).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field

from ..capture import Capture
from ..errors import UserError
from .fitting import log_regression
from .lobes import FAMILIES, log_derivatives, radiance
from .observation import THRESHOLD, Observation, observe
from .options import Choice, Count, CountOrZero, Positive, forwards
from .paper import RaySearch, ray_stage, stage_one
from .separation import SEPARATION_METHODS
from .several import (MAX_LAMPS, best_short_fit, final_fit, loss_floor, several_estimate,
                      short_fit)
from .pixels import weighted_fit_pixels
from .result import Estimate
from ..physics.reflectance import LOBES, finite, normalize, peak_shape, roughness_for_ts_sigma, shading_geometry, ts_sigma

LOSSES = ("huber", "soft_l1", "linear", "cauchy", "arctan")


def _lobe_choice(value: str) -> str:
    """``auto``, one family, or several joined by ``+`` (automatic choice among those)."""
    names = [v.strip() for v in value.split("+")]
    if value != "auto" and not (names and all(n in FAMILIES for n in names) and len(set(names)) == len(names)):
        raise ValueError(f"expected auto, one of {', '.join(FAMILIES)}, or several of them joined by +")
    return value


#: Families whose evidence against the subset's best is below this are fitted on every pixel before
#: the choice (a difference of −2 log-likelihood: 50 is decisive on the subset, and a close call
#: on ~2000 pixels is settled by ten times as many).
REFIT_EVIDENCE = 50.0

#: Least ``stages["full"]["specular_evidence"]`` (−2 log-likelihood of the fitted lobe against no
#: specular, ``Ks = 0``) of a fit whose data show a highlight; below it ``full`` warns that the data do
#: not determine the lamp (issue 42). Measured at 160×120, 4 angles, the 12-bit ``real_camera`` of
#: suites/paper-v1.yaml: the cylinder, whose mirror point is off the object (half-angle ≥ 24.9°, 4.8 σ;
#: peak specular 3e-5, ~1 electron, total SNR 0.06, CRLB 524 m), 7.6–24 over seeds 0–7 (pure noise
#: fitted by seven parameters); every other paper scene ≥ 1.7e6 (seeds 0, 1), noise-free ≥ 2e9.
SPECULAR_EVIDENCE = 100.0

#: ``full``'s ``lobe`` option.
LobeChoice = Annotated[str, AfterValidator(_lobe_choice)]
#: ``full``'s ``lamps`` option: a number of lamps, or ``auto``.
LampCount = Annotated[int, Field(ge=1, le=MAX_LAMPS)] | Literal["auto"]
#: Pixel-weight models of ``full``'s ``noise`` option.
NOISE_MODELS = ("none", "auto")


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


#: About how many pixels the multi-start's short fits use (every k-th of the fitted pixels).
TRIAL_PIXELS = 500
#: About how many specular pixels the start's t search and regressions use (:func:`start_observation`).
START_PIXELS = 2000


def start_observation(obs: Observation, n_pixels: int = START_PIXELS) -> Observation:
    """``obs`` with its specular mask thinned to a square lattice of about ``n_pixels`` pixels, for the start.

    The lattice's step is ``⌊√(n_mask / n_pixels)⌋`` pixels (1: the mask as
    it is) and it passes through the peak pixel, so the thinned mask does not
    depend on the order of the pixels and moves with the image only where
    the mask's own edge moves. The start's E_p(t) and regressions
    (:func:`~nearlight.estimator.paper.ray_stage`, :func:`peak_ray_starts`) on the
    lattice cost ``1/step²`` of the whole mask's; the start only has to land
    in the minimum's basin, which the multi-start and the short fits then
    settle (see :func:`full_estimate`'s "Speed").

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
    0.39–1.5 ×) and :func:`~nearlight.estimator.several.best_short_fit` stops
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


def _chi2(model: PointLampModel, x: np.ndarray) -> float:
    """Sum of squared (weighted) residuals at ``x``."""
    return float(np.sum(np.square(model.residuals(x))))


def _chi2_none(model: PointLampModel) -> float:
    """Sum of squared (weighted) residuals of no specular at all (``Ks = 0``): the observed specular's own."""
    return float(np.sum(np.square(model._weigh(model.observed))))


def _specular_evidence(chi2_none: float, chi2_fit: float, s2: float) -> float:
    """``(χ²(Ks = 0) − χ²(fit)) / s²``: how much better the fitted lobe explains the pixels than no specular.

    A difference of −2 log-likelihood, as the lobe evidence (``s²`` the fit's
    residual variance per value); +inf for a fit with no residual at all.
    """
    gain = max(chi2_none - chi2_fit, 0.0)
    if s2 > 0:
        return gain / s2
    return float("inf") if gain > 0 else 0.0


def no_specular_warning(evidence: float) -> str | None:
    """The warning of a fit whose lobe explains the pixels hardly better than no specular (else None)."""
    if evidence >= SPECULAR_EVIDENCE:
        return None
    return (f"no specular highlight above the camera noise (specular evidence {evidence:.3g} < "
            f"{SPECULAR_EVIDENCE:g}): the lamp, Ks and sigma are not determined by this capture")


@forwards(stage_one, fixed={"strict_t_max"})
def full_estimate(
    capture: Capture,
    *,
    lobe: LobeChoice = "auto",
    noise: Choice(NOISE_MODELS) = "auto",
    loss: Choice(LOSSES) = "huber",
    f_scale: Positive | None = None,
    max_pixels: Count = 20000,
    saturation: Positive | None = None,
    n_starts: CountOrZero = 6,
    separation: Choice(SEPARATION_METHODS) = "projected",
    lamps: LampCount = 1,
    **init_options,
) -> Estimate:
    """Method ``full``: ``paper-init``, then a weighted robust fit of lamp position, Ks and roughness.

    Lands on the same minimum for inputs that differ by float rounding
    wherever that minimum is unique: the multi-start
    (:func:`peak_ray_starts`) makes the answer independent of which start wins when
    several reach the same minimum, and of the peak pixel ``paper-init``
    picks (a symmetric board's two mirror-image peaks give the same lamp).
    Stability (``tests/test_estimator_stability.py``): a ±1-ulp float32
    change of every image (stack, P, N) moves the lamp by at most 3e-5 of
    the camera–highlight distance and σ and Ks by at most 1e-4 relative.
    Where the data hold two minima of equal cost to the last bits, the
    lower-cost start wins and the answer can flip between them; no shipped
    scene has shown one.

    Speed (issue 14; ``benchmarks/bench_estimator.py``): the start is the
    first stage on a lattice of ~:data:`START_PIXELS` specular pixels rather
    than on all of them (~53 000 on the 640×480 board), the multi-start's
    short fits run on ~:data:`TRIAL_PIXELS` of the fitted pixels, until two
    agree, by variable projection (the colour solved linearly at every step, the
    solver moving lamp and roughness only:
    :func:`~nearlight.estimator.several.short_fit`), and the model
    evaluates its geometry once per lamp and roughness for the residuals,
    the Jacobian and the solved colour. Only the final fit sees every fitted pixel
    (``max_pixels``), as before; it lands on the same minimum as the
    whole-mask start did (analytic 640×480 board and sphere: the lamp
    within 1e-14 m, σ within 1e-14 relative; 160×120 with camera noise:
    within 1e-9 m).

    The lobe family (``lobe``): one named, or ``auto``: every family of
    :data:`~nearlight.estimator.lobes.FAMILIES` is fitted from the same
    start on every k-th of the fitted pixels (at most ~2000); every family
    within :data:`REFIT_EVIDENCE` of the best there is fitted on every pixel,
    and the one with the smallest weighted sum of squares wins (all have
    seven parameters, so this is the Akaike and the Bayesian information
    criterion alike). ``stages["full"]["lobe_evidence"]`` holds each family's
    ``Δχ² / s²`` to the subset's best, ``s²`` that fit's residual variance (a
    difference of −2 log-likelihood: above ~10, the data decide), and
    ``lobe_evidence_all_pixels`` the same on every pixel for the families
    fitted there.

    Pixel weights (``noise``): ``auto`` (the default) weighs each pixel by
    ``1/std`` of its specular under the capture's Poisson–Gaussian camera
    (:mod:`~nearlight.estimator.noise`: stated in ``capture.sensor``, else
    measured from the analyzer stack's residuals; a stack of fewer than four
    angles, or a given specular image without a sensor, falls back to equal
    weights), so the loss and the lobe evidence are −2 log-likelihoods of
    that camera; ``none`` weighs all pixels alike. Measured
    (``benchmarks/bench_lobes.py``' captures, 12 seeds, Torrance–Sparrow
    fit), lamp RMSE weighted against equal: board with diffuse 0.56 against
    0.79 mm at low noise, 1.81 against 2.41 mm at high; sphere 3.34 against
    4.00 and 11.2 against 12.4 mm. On a noise-free capture the residuals
    measure no noise and every pixel gets the floor (equal weights). The
    weights choose the lobe better where families nearly coincide: on a
    low-noise sphere rendered with Ward, unweighted evidence named Beckmann in
    2 of 5 seeds (5 % lamp error each), weighted in 1 of 5. Dark pixels,
    whose readings the sensor may have clipped at zero
    (:func:`~nearlight.estimator.noise.censored_pixels`: their separated
    specular is biased and its variance wrong), are measured from their
    readings by a censored likelihood instead
    (:func:`~nearlight.estimator.censored.censored_specular`,
    :func:`~nearlight.estimator.pixels.weighted_fit_pixels`;
    ``stages["full"]["n_dark_measured"]``): on a GGX sphere at high noise,
    52 % of whose pixels are dark, the lamp RMSE is 1.07 × the Cramér–Rao
    bound over 200 seeds (1.14 with them left out, 2.0 with them fitted as
    separated). A black (``kd = 0``) board stays the weighted fit's weak
    case (RMSE / CRLB, 200 seeds: 2.03 at low noise, 2.36 at high, against
    1.82 and 2.63 with its dark pixels left out; coverage 0.68 and 0.065):
    its error is the highlight's own crossed-analyzer readings, near zero and
    clipped although the pixel is bright, not its dark pixels.

    Whether there is a highlight at all (issue 42): ``stages["full"]["specular_evidence"]`` is
    ``(χ²(Ks = 0) − χ²) / s²``, the −2 log-likelihood of the fitted lobe against no specular. Below
    :data:`SPECULAR_EVIDENCE` the specular is camera noise (seven parameters fitted to pure noise
    gain ~10–35) and ``diagnostics["warnings"]`` says that the capture does not determine the lamp:
    e.g. the paper-v1 cylinder with its 12-bit camera, whose mirror point is off the object (peak
    specular ~1 electron, lamp CRLB 524 m).

    Parameters
    ----------
    capture : Capture
    lobe : str
        ``"auto"`` (the default), one of ``"torrance_sparrow"``, ``"ward"``,
        ``"beckmann"``, ``"ggx"``, or several joined by ``+`` (automatic choice
        among those, e.g. ``"ward+ggx"``): the lobe family fitted (see above).
    noise : {"auto", "none"}
        Pixel weights (see above); default ``"auto"``.
    separation : {"projected", "fit", "maxmin"}
        Separation of an analyzer stack; default ``"projected"``, the one
        that is unbiased under noise (see :func:`~nearlight.estimator.separate`):
        with ``"fit"`` the faint-specular pixels come out biased upwards and
        the covariance no longer covers the error.
    loss : {"huber", "soft_l1", "linear", "cauchy", "arctan"}
        Robust loss of :func:`scipy.optimize.least_squares`, on the weighted
        residuals; with the default scale (3 × their MAD, ~3 standard
        deviations) Huber's weighs every pixel within it fully, so only
        outliers (saturation, glints) lose weight.
    f_scale : float, optional
        Loss scale in residual units (radiance / std); default from the
        residuals (3 × MAD, at least 1e-4 × the peak specular radiance
        unweighted).
    max_pixels : int
        Largest number of pixels fitted (the brightest, when the surface has more).
    saturation : float, optional
        Drop pixels whose specular reaches this value (clipped sensors).
    n_starts : int
        Extra starting distances along the peak ray (see :func:`peak_ray_starts`);
        the start with the lowest least-squares cost after a short fit (on
        at most ~:data:`TRIAL_PIXELS` of the fitted pixels) wins, the starts
        tried until two reach the same lowest cost
        (:func:`~nearlight.estimator.several.best_short_fit`; how many ran:
        ``stages["full"]["n_short_fits"]``).
    lamps : int or "auto"
        Number of point lamps fitted: 1 (the default: the fit above), K ≤
        :data:`~nearlight.estimator.several.MAX_LAMPS`, or ``"auto"`` (the count
        of least BIC); see :func:`~nearlight.estimator.several.several_estimate`.
        With one lamp, an image of several separate highlights gets a line in
        ``diagnostics["warnings"]`` from the rules every estimate passes
        (:func:`~nearlight.estimator.sanity.review`), as every one-lamp method does.
    **init_options
        Options of :func:`~nearlight.estimator.paper.stage_one`: ``threshold``
        for the observation, the others for its ray stage, which runs on
        the lattice of :func:`start_observation`.

    Returns
    -------
    Estimate
        ``ks`` and ``sigma`` of the Torrance–Sparrow lobe with the fitted
        lobe's peak and small-angle width (:func:`~nearlight.physics.reflectance.peak_shape`,
        :func:`~nearlight.physics.reflectance.ts_sigma`); the fitted family's
        own BSDF dict in ``stages["full"]["bsdf"]``. ``covariance``: 1-σ
        covariance of ``(x, y, z, σ)``; ``stages["full"]`` holds the 7 × 7
        covariance of ``(x, y, z, colour_r, colour_g, colour_b, roughness)``.
        ``diagnostics``: the start's (:func:`~nearlight.estimator.paper.ray_stage`
        on the lattice), with ``n_specular_pixels`` the whole mask's count and
        ``n_start_pixels`` the lattice's.
    """
    if loss not in LOSSES:
        raise UserError(f"option loss: expected one of {', '.join(LOSSES)}, got {loss!r}")
    if lamps != 1:
        return several_estimate(capture, lamps=lamps, lobe=lobe, noise=noise, loss=loss, f_scale=f_scale,
                                max_pixels=max_pixels, saturation=saturation, n_starts=n_starts,
                                separation=separation, **init_options)
    return one_lamp_fit(capture, lobe=lobe, noise=noise, loss=loss, f_scale=f_scale, max_pixels=max_pixels,
                        saturation=saturation, n_starts=n_starts, separation=separation, **init_options)[0]


def one_lamp_fit(capture: Capture, *, lobe: str, noise: str, loss: str, f_scale: float | None, max_pixels: int,
                 saturation: float | None, n_starts: int, separation: str,
                 **init_options) -> tuple[Estimate, Observation]:
    """:func:`full_estimate` with one lamp, and the observation it fitted (options as its, checked there).

    Returns
    -------
    Estimate
        ``full_estimate(capture, lamps=1, ...)``.
    Observation
        The capture's observation (:func:`~nearlight.estimator.observation.observe`), whole mask.
    """
    clock = time.perf_counter()
    obs = observe(capture, separation=separation, threshold=init_options.pop("threshold", THRESHOLD))
    seconds = time.perf_counter() - clock
    start = start_observation(obs)
    init = ray_stage(capture, start, strict_t_max=False, **init_options)
    init.timings = {"observe": seconds, **init.timings}
    clock = time.perf_counter()
    fit_px = weighted_fit_pixels(capture, obs, noise=noise, max_pixels=int(max_pixels), saturation=saturation)
    use, camera = fit_px.use, fit_px.camera
    std = None if camera is None else np.sqrt(fit_px.variance(capture, pixels=use))
    model = PointLampModel(obs.P[use], obs.N[use], obs.camera_position, fit_px.specular[use], std=std)
    coarse = model.subset(slice(None, None, max(1, len(model.P) // 2000)))
    trial = model.subset(slice(None, None, max(1, len(model.P) // TRIAL_PIXELS)))
    starts = peak_ray_starts(init, start, n_starts=int(n_starts))
    best, tried = best_short_fit(trial, starts, obs.scale)
    best = best["x"]
    floor = loss_floor(fit_px.specular[use], std)
    families = FAMILIES if lobe == "auto" else tuple(v.strip() for v in lobe.split("+"))
    shorts = {}
    for family in families:
        x0 = best.copy()
        x0[6] = roughness_for_ts_sigma(family, best[6])
        c = coarse.with_lobe(family)
        x0 = short_fit(c, x0, obs.scale)["x"]
        shorts[family] = (x0, _chi2(c, x0))
    first = min(shorts, key=lambda k: shorts[k][1])
    s2 = shorts[first][1] / max(3 * len(coarse.P) - 7, 1)
    evidence = {k: (v[1] - shorts[first][1]) / s2 for k, v in shorts.items()}
    fits = {}
    for family in (k for k, v in evidence.items() if v < REFIT_EVIDENCE):
        m = model.with_lobe(family)
        x0 = shorts[family][0]
        fits[family] = final_fit(m, x0, obs.scale, loss=loss, f_scale=f_scale, floor=floor)
        fits[family]["chi2"] = _chi2(m, fits[family]["x"])
    chosen = min(fits, key=lambda k: fits[k]["chi2"])
    fit = fits[chosen]
    s2_all = fit["chi2"] / max(3 * len(model.P) - 7, 1)
    refit = {k: (v["chi2"] - fit["chi2"]) / s2_all for k, v in fits.items()}
    evidence_specular = _specular_evidence(_chi2_none(model), fit["chi2"], s2_all)
    x, cov7 = fit["x"], fit["cov"]
    per_roughness = ts_sigma(chosen, 1.0)  # σ is linear in the family's roughness
    idx = [0, 1, 2, 6]
    scale = np.array([1.0, 1.0, 1.0, per_roughness])
    cov4 = cov7[np.ix_(idx, idx)] * scale[:, None] * scale[None, :]
    spec = LOBES[chosen]
    timings = {**init.timings, "full": time.perf_counter() - clock}
    stage = {
        "lamp_position": x[:3], "ks": x[3:6], "roughness": x[6], "covariance_7": cov7,
        "covariance_params_7": ["x", "y", "z", "colour_r", "colour_g", "colour_b", "roughness"],
        **{k: fit[k] for k in ("f_scale", "cost", "nfev", "status", "rms", "chi2")},
        "lobe": chosen, "bsdf": {"model": chosen, spec.colour_key: x[3:6], spec.roughness_key: x[6]},
        "lobe_evidence": evidence, "lobe_evidence_all_pixels": refit, "lobes_fitted": list(families),
        "specular_evidence": evidence_specular,
        "noise": None if camera is None else camera._asdict(),
        "loss": loss, "n_pixels": int(use.sum()), "n_dark_measured": int(fit_px.measured.sum()),
        "n_starts": len(starts), "n_short_fits": tried,
    }
    return Estimate(
        method="full",
        lamp_position=x[:3],
        ks=x[3:6] * peak_shape(chosen, x[6]),
        sigma=per_roughness * x[6],
        covariance=cov4,
        stages={"init": init.stages["init"], "full": stage},
        diagnostics={**init.diagnostics, "n_specular_pixels": int(obs.mask.sum()),
                     "n_start_pixels": int(start.mask.sum())},
        timings=timings,
    ).with_warning(no_specular_warning(evidence_specular)), obs
