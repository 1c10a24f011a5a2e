"""The paper's two-stage method (Hara et al. 2002, §3): ``paper-init`` and ``paper``.

Stage 1 (§3.2–3.3, ``paper-init``): the lamp lies on the ray ``L = P + t·Lp``
(eq. 9) from the peak pixel's surface point along the mirror direction ``Lp``
(eq. 8). For each t, every specular pixel gives a point ``(X, Y_m)`` with
``X = α(t)²/2`` and ``Y_m = ln E_m + ln cos θr`` (eq. 12–13), where
``E_m = I_s,m · r(t)² / I_lamp`` (eq. 6–7; ``I_lamp = 1``, so Ks absorbs the
lamp intensity). ``t*`` minimises ``E_p(t) = Σ_m r_XY_m`` (eq. 14–15), the sum
of the correlation coefficients; Ks and σ come from the regression line
(eq. 16–17), σ the mean over channels.

Eq. 8 as printed, ``N + (N, V) N − V``, is the mirror direction only when
``N·V = 1``; we use the exact mirror ``2 (N·V) N − V``
(:func:`nearlight.physics.reflectance.mirror_direction`).

Stage 2 (§3.4, ``paper``): alternating minimisation (AM) of eq. 18,
``E_energy(Ks, σ, t) = Σ_m Σ_k (E_k,m − Ks,m / cos θr,k · exp(−α_k(t)² / 2σ²))²``
over the surface pixels, steps 1–6 with thresholds ε1–ε4. As printed only α
depends on t: E is "measured" once, with r at the first stage's t*
(``energy="ratio"``, default); ``energy="ratio-t"`` re-measures E with r(t)
and ``energy="radiance"`` fits the image itself (see :class:`Energy`). Two
steps are implemented as what they are meant to do rather than as printed:

* step 2: the printed Ks update ``Σ E / Σ g`` (g the lobe) minimises
  E_energy only when g is constant; we use the exact minimiser over Ks,
  ``Σ E g / Σ g²``, so the step cannot increase E_energy;
* step 4-2 (garbled in print: a squared residual and a mix of ``I_s``,
  ``t*`` and ``t^(n)``): steepest descent on ``κ = 1/σ`` with the gradient
  ``∂E_energy/∂κ = 2 Σ_m Σ_k ρ_k,m · Ks,m α_k² κ g_k``, ``ρ`` the residual.
  The step γ defaults to the inverse Gauss–Newton curvature
  ``1 / (2 Σ (Ks α² κ g)²)`` at each step (so the scale comes from the
  capture), and a step that would increase E_energy is halved until it does
  not (so E_energy never increases).

A range hole on the highlight (no ``P`` at the brightest pixels,
``nuisances.range.holes_shiny_above``) does not move the peak or the ray:
the hole's surface points and normals come from a quadric fitted to the
range around it (:func:`~nearlight.estimator.observation.fill_range_holes`),
for every origin; E_p, the regression and the AM use only pixels with
range, so t* moves with the pixels the hole takes away
(``tests/test_estimator_holes.py``).

Step 6 searches ``{t − Δt, t, t + Δt}``, keeping t on ties. The AM runs
fast (:func:`alternating_minimisation`) and walks exactly the steps of its
plain transcription (:func:`alternating_minimisation_reference`).

Options beyond the printed paper (issue 11), each named for what it is:

* ``origin`` (both methods): where the ray of eq. 9 starts. ``peak`` (the
  default, the printed paper), ``subpixel``, ``model`` (a DEPARTURE: the
  brightest pixel corrected by the offset δ ∝ σ² the model predicts, since
  1/r² and 1/cos θr move the intensity maximum away from the mirror point),
  and the ORACLE ``mirror-oracle`` (the true mirror point, read from the
  capture's truth; with ``origin_shift`` s, the point ``m + s·δ``), which
  separates the method's error from its origin's;
* ``am`` (``paper``): ``printed`` (default) or ``bounded`` (a DEPARTURE: E
  re-measured at every t, t by a bounded 1-D search of the profile energy,
  which cannot stall on ±Δt steps; :func:`bounded_minimisation`).

Both methods are discontinuous by design: they pick the brightest specular
pixel (the peak) and a t on the Δt grid, and an image change that reorders
two pixels' brightness, or two grid values of E_p (or of E_energy in step
6), moves the lamp to another ray or grid point. Float rounding alone does
not move the peak: pixels within 2⁻¹⁹ (16 float32 ulps) of the brightest
are tied and resolved by position (:data:`~nearlight.estimator.observation.PEAK_TIE`),
so a symmetric scene's two mirror-image peaks give the same ray on every
machine; a larger difference between them picks the brighter one, and the
lamp jumps to the mirror-image ray (σ, Ks and t stay). What stays put: with
the same peak pixel and t, a ±1-ulp float32 change of every image (stack,
P, N) moves the lamp by at most 1e-5 of the camera–highlight distance (it
moves only with the ray) and σ and Ks by at most 1e-4 relative (measured on
analytic captures: ≤ 1e-7 and ≤ 3e-6, with or without camera noise;
``tests/test_estimator_stability.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Annotated

import numpy as np
from pydantic import Field
from scipy.optimize import minimize, minimize_scalar
from threadpoolctl import threadpool_limits

from ..capture import Capture
from ..errors import UserError
from .fitting import log_regression
from .highlights import several_highlights_warning
from .observation import THRESHOLD, Observation, observe, subpixel_peak, surface_at
from .options import Choice, Count, Fraction, Positive, forwards
from .separation import SEPARATION_METHODS
from .result import Estimate
from ..physics.reflectance import channel_sum, mirror_direction, normalize, shading_geometry

#: A finite real number (may be negative or zero).
Real = Annotated[float, Field(allow_inf_nan=False)]

#: Largest number of (t, pixel) pairs evaluated at once.
_CHUNK = 2_000_000


class RaySearch:
    """E_p(t) for the lamp on the ray ``P + t·Lp`` of one observation.

    Parameters
    ----------
    obs : Observation
    point : tuple of ndarray, optional
        ``(P, N)``: the ray's surface point and unit normal; default the
        peak pixel's (the paper's).
    """

    def __init__(self, obs: Observation, point: tuple[np.ndarray, np.ndarray] | None = None):
        if point is None:
            i, j = obs.peak
            self.origin = obs.P[i, j]
            self.direction = mirror_direction(obs.N[i, j], obs.V[i, j])
        else:
            self.origin = np.asarray(point[0], dtype=float)
            self.direction = mirror_direction(np.asarray(point[1], dtype=float),
                                              normalize(obs.camera_position - self.origin))
        m = obs.mask
        self.P, self.N = obs.P[m], obs.N[m]
        self.camera = obs.camera_position
        # Y_m = ln I_s + ln cos θr + 2 ln r(t): the t-free part.
        self.Y0 = np.log(obs.specular[m]) + np.log(obs.cos_r[m])[:, None]
        self.evaluations = 0

    def lamp(self, t: float) -> np.ndarray:
        """Lamp position at distance t (m), shape (3,)."""
        return self.origin + t * self.direction

    def xy(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``X [T, n]`` and ``Y [T, n, 3]`` of eq. 12–13 for distances t (m), shape (T,)."""
        L = self.origin + np.asarray(t, dtype=float)[:, None] * self.direction
        g = shading_geometry(self.P[None], self.N[None], self.camera, L[:, None, :])
        return 0.5 * g.alpha**2, self.Y0[None] + 2.0 * np.log(g.r)[..., None]

    def ep(self, t: np.ndarray) -> np.ndarray:
        """E_p(t) of eq. 15 for each t (m), shape (T,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.empty(t.shape)
        step = max(1, _CHUNK // max(len(self.P), 1))
        for a in range(0, len(t), step):
            X, Y = self.xy(t[a : a + step])
            xc = X - X.mean(axis=1, keepdims=True)
            yc = Y - Y.mean(axis=1, keepdims=True)
            with np.errstate(invalid="ignore", divide="ignore"):
                r = np.einsum("tn,tnm->tm", xc, yc) / np.sqrt(
                    np.einsum("tn,tn->t", xc, xc)[:, None] * np.einsum("tnm,tnm->tm", yc, yc)
                )
            out[a : a + step] = np.nan_to_num(r, nan=0.0).sum(axis=1)
        self.evaluations += len(t)
        return out


def scan_search(ep: Callable[[np.ndarray], np.ndarray], *, t_max: float, dt: float) -> dict:
    """The paper's plain scan: E_p at every ``k·Δt`` in (0, t_max], one step at a time.

    Returns
    -------
    dict
        ``t`` (the grid minimiser, m), ``k`` (its index, 1-based), ``t_grid``,
        ``ep`` (the whole curve), ``k_max``.
    """
    k_max = int(np.floor(t_max / dt + 1e-9))
    ks = np.arange(1, k_max + 1)
    values = np.array([ep(np.array([k * dt]))[0] for k in ks])
    k = int(ks[int(np.argmin(values))])
    return {"t": k * dt, "k": k, "t_grid": ks * dt, "ep": values, "k_max": k_max}


def fast_search(ep: Callable[[np.ndarray], np.ndarray], *, t_max: float, dt: float, n_coarse: int = 48) -> dict:
    """The same grid minimiser as :func:`scan_search`, from far fewer evaluations.

    A log-spaced coarse grid of ``n_coarse`` points on the Δt grid brackets
    the minimum, a bounded Brent search refines it to Δt/4, and the Δt-grid
    points around the result are compared directly. It returns the scan's
    answer whenever E_p is unimodal between the coarse neighbours of the
    coarse minimum.
    """
    k_max = int(np.floor(t_max / dt + 1e-9))
    kc = np.unique(np.round(np.geomspace(1, k_max, n_coarse)).astype(int))
    vc = ep(kc * dt)
    i = int(np.argmin(vc))
    lo, hi = kc[max(i - 1, 0)], kc[min(i + 1, len(kc) - 1)]
    seen = dict(zip(kc.tolist(), vc.tolist()))
    if hi - lo > 2:
        res = minimize_scalar(
            lambda t: float(ep(np.array([t]))[0]), bounds=(lo * dt, hi * dt), method="bounded",
            options={"xatol": dt / 4},
        )
        centre = int(round(res.x / dt))
    else:
        centre = int(kc[i])
    near = np.array([k for k in range(centre - 2, centre + 3) if lo <= k <= hi and k not in seen], dtype=int)
    if len(near):
        seen.update(zip(near.tolist(), ep(near * dt).tolist()))
    k = min((k for k in seen if lo <= k <= hi), key=lambda k: (seen[k], k))
    grid = np.array(sorted(seen))
    return {"t": k * dt, "k": k, "t_grid": grid * dt, "ep": np.array([seen[g] for g in grid]), "k_max": k_max}


#: t searches by name.
SEARCHES = {"fast": fast_search, "scan": scan_search}


def t_search_defaults(obs: Observation, t_max: float | None, dt: float | None) -> tuple[float, float]:
    """``t_max`` = 10 × the camera–highlight distance; ``Δt`` = 1 mm (the paper's), or scale/1000 if larger."""
    dt = max(1e-3, obs.scale / 1000.0) if dt is None else float(dt)
    t_max = 10.0 * obs.scale if t_max is None else float(t_max)
    if not (dt > 0 and t_max > 2 * dt):
        raise UserError(f"options: need 0 < dt and t_max > 2·dt, got dt={dt}, t_max={t_max}")
    return t_max, dt


#: Ray origins of the first stage (option ``origin``). ``peak``: the brightest
#: pixel (the printed paper). ``subpixel``: a log-Gaussian sub-pixel peak.
#: ``mirror-oracle``: ORACLE, the exact mirror point of the capture's true
#: lamp (reads ``capture.truth``; a study of the method, not an estimator).
#: ``model``: DEPARTURE from the printed paper, the sub-pixel peak corrected
#: by the offset the Torrance–Sparrow model predicts for the current t and σ,
#: iterated with t (:func:`model_origin`).
ORIGINS = ("peak", "subpixel", "mirror-oracle", "model")
#: ``origin: model``: most fixed-point iterations, and the move (px) that ends them.
MODEL_ORIGIN_ITERATIONS = 20
MODEL_ORIGIN_TOLERANCE_PX = 0.001


def _brightness(obs: Observation) -> np.ndarray:
    """Mean specular over the channels, ``[H, W]``."""
    return channel_sum(obs.specular) / 3  # obs.specular.mean(axis=-1), bit for bit


def _alpha2_at(obs: Observation, rc: np.ndarray, lamp: np.ndarray) -> float:
    P, N = surface_at(obs, rc)
    return float(shading_geometry(P, N, obs.camera_position, lamp).alpha ** 2)


def mirror_oracle_pixel(capture: Capture, obs: Observation) -> np.ndarray:
    """ORACLE: the sub-pixel ``(row, column)`` of the exact mirror point of the capture's TRUE lamp.

    Reads ``capture.truth["lamp_position"]`` (the only place in the
    estimators that does): α of the true lamp is smallest at the mirror
    point; the located pixel (measured or filled) of least α, refined over
    interpolated P, N (:func:`~nearlight.estimator.observation.surface_at`)
    to 1e-4 px.

    Raises
    ------
    UserError
        The capture has no truth (a real capture): the oracle cannot run.
    """
    truth = capture.truth if isinstance(capture.truth, dict) else {}
    if truth.get("lamp_position") is None:
        raise UserError(f"{capture.name}: option origin=mirror-oracle: the capture has no truth.lamp_position "
                        "(the oracle needs the true lamp; use origin=peak, subpixel or model)")
    lamp = np.asarray(truth["lamp_position"], dtype=float)
    s = obs.located
    alpha = shading_geometry(obs.P[s], obs.N[s], obs.camera_position, lamp).alpha
    start = np.argwhere(s)[int(np.argmin(alpha))].astype(float)
    res = minimize(lambda rc: _alpha2_at(obs, rc, lamp), start, method="Nelder-Mead",
                   options={"xatol": 1e-4, "fatol": 0.0, "initial_simplex": start + [[0, 0], [0.5, 0], [0, 0.5]]})
    return np.asarray(res.x, dtype=float)


def model_peak_pixel(obs: Observation, lamp: np.ndarray, sigma: float) -> np.ndarray:
    """Sub-pixel peak ``(row, column)`` the Torrance–Sparrow model predicts for a lamp and σ.

    The model image ``exp(−α²/2σ²) / (cos θr r²)`` on the located pixels
    (measured or filled: the data's peak may sit in a range hole; Ks only
    scales it), its brightest pixel off the border, and the same
    log-Gaussian refinement as the data's (:func:`subpixel_peak`), so that
    the estimator's own bias cancels between the two.
    """
    s = obs.located
    g = shading_geometry(obs.P[s], obs.N[s], obs.camera_position, lamp)
    img = np.zeros(s.shape)
    img[s] = np.exp(-0.5 * (g.alpha / sigma) ** 2) / (obs.cos_r[s] * g.r**2)
    img[[0, -1], :] = 0.0
    img[:, [0, -1]] = 0.0
    peak = np.unravel_index(int(np.argmax(img)), img.shape)
    return subpixel_peak(img, s, (int(peak[0]), int(peak[1])))


def origin_pixel(capture: Capture, obs: Observation, origin: str, origin_shift: float) -> np.ndarray | None:
    """Continuous ``(row, column)`` of the ray's origin for ``origin`` (None: the peak pixel itself).

    ``origin_shift`` s (``mirror-oracle`` only): the origin moves from the
    mirror point m towards the brightest pixel p, ``m + s·(p − m)`` (s = 0
    the mirror point, s = 1 the brightest pixel), for the t*(s) study.
    """
    if origin_shift != 0.0 and origin != "mirror-oracle":
        raise UserError(f"option origin_shift: only with origin=mirror-oracle (got origin={origin})")
    if origin == "peak":
        return None
    if origin == "mirror-oracle":
        m = mirror_oracle_pixel(capture, obs)
        return m + origin_shift * (np.asarray(obs.peak, dtype=float) - m)
    return subpixel_peak(_brightness(obs), obs.located, obs.peak)


def model_origin(obs: Observation, search: Callable[[RaySearch], dict], start: np.ndarray,
                 where: str) -> tuple[RaySearch, dict, list[list[float]]]:
    """``origin: model`` (a DEPARTURE from the printed paper): the ray from a model-predicted mirror point.

    The brightest pixel is not the mirror point: 1/r² and 1/cos θr move the
    intensity maximum by δ ∝ σ² towards the lamp. From the sub-pixel peak
    p_obs, iterate: search t on the ray from the current origin p, fit σ
    (eq. 16–17), predict the model's own peak p_model for that lamp and σ
    (:func:`model_peak_pixel`; its mirror point is p by construction), and
    move the origin to ``p_obs − (p_model − p)``; stop when it moves by less
    than :data:`MODEL_ORIGIN_TOLERANCE_PX` or after
    :data:`MODEL_ORIGIN_ITERATIONS`.

    Returns
    -------
    ray, found, path
        The last ray, its search result, and the origins visited (px).
    """
    p, path = np.array(start, dtype=float), []
    for _ in range(MODEL_ORIGIN_ITERATIONS):
        path.append(p.tolist())
        ray = RaySearch(obs, surface_at(obs, p))
        found = search(ray)
        X, Y = ray.xy(np.array([found["t"]]))
        sigma = log_regression(X[0], Y[0], where=where)[1]
        p_new = start - (model_peak_pixel(obs, ray.lamp(found["t"]), sigma) - p)
        moved = float(np.linalg.norm(p_new - p))
        p = p_new
        if moved < MODEL_ORIGIN_TOLERANCE_PX:
            break
    return ray, found, path


def stage_one(
    capture: Capture,
    *,
    separation: Choice(SEPARATION_METHODS) = "fit",
    threshold: Fraction = THRESHOLD,
    t_max: Positive | None = None,
    dt: Positive | None = None,
    search: Choice(SEARCHES) = "fast",
    n_coarse: Count = 48,
    strict_t_max: bool = True,
    origin: Choice(ORIGINS) = "peak",
    origin_shift: Real = 0.0,
) -> tuple[Estimate, Observation]:
    """The paper's first stage (§3.2–3.3): the estimate and the observation it used.

    Parameters
    ----------
    capture : Capture
    separation : {"fit", "projected", "maxmin"}
        Separation of an analyzer stack (see :func:`~nearlight.estimator.separate`).
    threshold : float
        Specular mask threshold, fraction of the peak pixel's mean specular.
    t_max : float, optional
        Upper bound of the lamp distance t, metres; default 10 × the distance
        from the camera to the highlight.
    dt : float, optional
        Step Δt of t, metres; default 1 mm (the paper's), or 1/1000 of that
        distance when larger.
    search : {"fast", "scan"}
        ``"scan"``: the paper's plain per-step scan; ``"fast"`` (default):
        coarse grid and Brent refinement, same t to within Δt.
    n_coarse : int
        Coarse grid size of the fast search.
    strict_t_max : bool
        Raise when E_p is smallest at t_max (default); ``full`` turns this
        off because its multi-start does not rely on t*.
    origin : {"peak", "subpixel", "mirror-oracle", "model"}
        Where the ray of eq. 9 starts (:data:`ORIGINS`): ``"peak"`` (default,
        the printed paper) the brightest pixel; ``"subpixel"`` a log-Gaussian
        sub-pixel peak; ``"mirror-oracle"`` ORACLE, the exact mirror point of
        the capture's true lamp (reads the truth; refused without one);
        ``"model"`` DEPARTURE from the paper, the peak corrected by the
        model's predicted offset, iterated with t (:func:`model_origin`).
    origin_shift : float
        With ``origin="mirror-oracle"`` only: start at ``m + s·(p − m)``, m the
        mirror point, p the brightest pixel (0: m, 1: p).

    Raises
    ------
    UserError
        Bad input (see :func:`~nearlight.estimator.observation.observe`) or a
        ``t_max`` that cannot reach the lamp (E_p minimal at t_max).
    """
    clock = time.perf_counter()
    obs = observe(capture, separation=separation, threshold=threshold)
    seconds = time.perf_counter() - clock
    init = ray_stage(capture, obs, t_max=t_max, dt=dt, search=search, n_coarse=n_coarse, strict_t_max=strict_t_max,
                     origin=origin, origin_shift=origin_shift)
    init.timings = {"observe": seconds, **init.timings}
    return init, obs


def ray_stage(
    capture: Capture,
    obs: Observation,
    *,
    t_max: float | None = None,
    dt: float | None = None,
    search: str = "fast",
    n_coarse: int = 48,
    strict_t_max: bool = True,
    origin: str = "peak",
    origin_shift: float = 0.0,
) -> Estimate:
    """:func:`stage_one` after :func:`~nearlight.estimator.observation.observe`: the ray, its t search and the regression.

    E_p and the regression run over ``obs.mask``'s pixels (``full`` passes
    an observation whose mask is thinned, :func:`~nearlight.estimator.full.start_observation`).
    Options and errors as :func:`stage_one`; ``timings`` holds ``t_search``
    and ``regression`` (seconds).
    """
    t_max, dt = t_search_defaults(obs, t_max, dt)
    timings = {}
    clock = time.perf_counter()
    if search not in SEARCHES:
        raise UserError(f"option search: expected one of {', '.join(SEARCHES)}, got {search!r}")
    if origin not in ORIGINS:
        raise UserError(f"option origin: expected one of {', '.join(ORIGINS)}, got {origin!r}")
    kwargs = {"n_coarse": int(n_coarse)} if search == "fast" else {}

    def run(ray: RaySearch) -> dict:
        return SEARCHES[search](ray.ep, t_max=t_max, dt=dt, **kwargs)

    start = origin_pixel(capture, obs, origin, float(origin_shift))
    extra: dict = {}
    if origin == "model":
        ray, found, path = model_origin(obs, run, start, f"{capture.name}: specular")
        extra = {"origin": origin, "ray_origin_pixel": path[-1], "origin_path": path}
    else:
        ray = RaySearch(obs, None if start is None else surface_at(obs, start))
        found = run(ray)
        if start is not None:
            extra = {"origin": origin, "ray_origin_pixel": start.tolist(), "origin_shift": float(origin_shift)}
    if strict_t_max and found["k"] >= found["k_max"]:
        several = several_highlights_warning(obs)
        if several is not None:  # the likelier cause: the peak ray of one lamp's highlight misses another's lamp
            raise UserError(f"{capture.name}: specular: {several.split(':')[0]}, one lamp each, and this method "
                            "fits one: E_p(t) along the peak ray has no minimum before t_max; use --method full "
                            "--set lamps=auto")
        raise UserError(
            f"{capture.name}: option t_max = {t_max:.4g} m cannot reach the lamp: E_p(t) is smallest at t_max "
            "(the lamp is farther, or the peak ray misses it); raise it with --set t_max=... or use --method full"
        )
    timings["t_search"] = time.perf_counter() - clock
    clock = time.perf_counter()
    t = found["t"]
    X, Y = ray.xy(np.array([t]))
    ks, sigma, sigma_rgb = log_regression(X[0], Y[0], where=f"{capture.name}: specular")
    timings["regression"] = time.perf_counter() - clock
    lamp = ray.lamp(t)
    stage = {"t": t, "lamp_position": lamp, "ks": ks, "sigma": sigma, "sigma_rgb": sigma_rgb}
    return Estimate(
        method="paper-init",
        lamp_position=lamp,
        ks=ks,
        sigma=sigma,
        stages={"init": stage},
        diagnostics={
            "peak_pixel": list(obs.peak),
            "ray_origin": ray.origin,
            "ray_direction": ray.direction,
            "n_specular_pixels": int(obs.mask.sum()),
            "t_max": t_max,
            "dt": dt,
            "search": search,
            "ep_evaluations": ray.evaluations,
            "t_grid": found["t_grid"],
            "ep": found["ep"],
            **extra,
        },
        timings=timings,
    )



@forwards(stage_one)
def initial_estimate(capture: Capture, **options) -> Estimate:
    """Method ``paper-init``: the paper's first stage (§3.2–3.3); options as :func:`stage_one`.

    Discontinuous by design (the peak pixel, t on the Δt grid); with both
    unchanged, stable under float rounding to 1e-5 of the camera–highlight
    distance (lamp) and 1e-4 relative (σ, Ks): see the module docstring.
    """
    return stage_one(capture, **options)[0]


class Energy:
    """E_energy of eq. 18 for the lamp on the peak ray: ``Σ (target − Ks · base · exp(−α² κ² / 2))²``.

    Parameters
    ----------
    obs : Observation
    origin, direction : ndarray, shape (3,)
        The ray ``P + t·Lp``.
    pixels : {"surface", "specular"}
        The paper's "N_k surface points": every surface pixel, or the specular mask.
    space : {"ratio", "ratio-t", "radiance"}
        ``"ratio"`` (default; eq. 18 as printed, where only α carries a
        ``(t)``): residuals of the measured ratio ``E = I_s r²``, computed once
        with the lamp at ``t_ref`` (the first stage's t*), against
        ``Ks/cos θr · exp(−α(t)²/2σ²)``. ``"ratio-t"``: E recomputed with
        ``r(t)`` at every t; since E then shrinks as the lamp approaches the
        surface, the AM drifts towards t → 0 whenever the peak ray misses the
        lamp. ``"radiance"``: residuals of ``I_s`` against
        ``Ks/(cos θr r(t)²) · exp(…)``, the same model in image space.
    t_ref : float
        Lamp distance at which ``"ratio"`` measures E, metres.
    """

    SPACES = ("ratio", "ratio-t", "radiance")
    PIXELS = ("surface", "specular")

    def __init__(
        self, obs: Observation, origin: np.ndarray, direction: np.ndarray, *, pixels: str = "surface",
        space: str = "ratio", t_ref: float | None = None,
    ):
        if pixels not in self.PIXELS:
            raise UserError(f"option pixels: expected 'surface' or 'specular', got {pixels!r}")
        if space not in self.SPACES:
            raise UserError(f"option energy: expected one of {', '.join(self.SPACES)}, got {space!r}")
        s = obs.mask if pixels == "specular" else obs.surface
        self.P, self.N, self.I = obs.P[s], obs.N[s], obs.specular[s]
        self.cos_r = obs.cos_r[s]
        self.camera, self.origin, self.direction = obs.camera_position, origin, direction
        self.space = space
        if space == "ratio":
            if t_ref is None:
                raise ValueError("space='ratio' needs t_ref")
            r = np.linalg.norm(self.origin + t_ref * self.direction - self.P, axis=-1)
            self.E_ref = self.I * (r**2)[:, None]
        # t-free per-pixel terms of :meth:`columns`
        V = normalize(self.camera - self.P)
        w = self.origin - self.P
        D = np.asarray(self.direction, dtype=float)
        self._coef = {
            "ww": np.einsum("nk,nk->n", w, w), "wd": w @ D, "dd": float(D @ D), "nw": np.einsum("nk,nk->n", self.N, w),
            "nd": self.N @ D, "vw": np.einsum("nk,nk->n", V, w), "vd": V @ D, "nv": np.einsum("nk,nk->n", self.N, V),
            "vv1": 1.0 + np.einsum("nk,nk->n", V, V),
        }
        self._I_cols = np.ascontiguousarray(self.I.T)
        self._E_cols = np.ascontiguousarray(self.E_ref.T) if space == "ratio" else None
        self._base = 1.0 / self.cos_r
        self._memo: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``target [n, 3]``, ``α² [n]`` and ``base [n]`` for the lamp at distance t (m)."""
        g = shading_geometry(self.P, self.N, self.camera, self.origin + t * self.direction)
        r2 = g.r**2
        if self.space == "ratio":
            return self.E_ref, g.alpha**2, 1.0 / self.cos_r
        if self.space == "ratio-t":
            return self.I * r2[:, None], g.alpha**2, 1.0 / self.cos_r
        return self.I, g.alpha**2, 1.0 / (self.cos_r * r2)

    def columns(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`at` for the fast AM: ``target`` channel-major ``[3, n]``, ``α² [n]``, ``base [n]``.

        Equal to :meth:`at` to rounding (about 1e-16 relative in cos α, so
        1e-16 absolute in α²), from per-pixel scalars that do not depend on
        t: with ``w = origin − P`` and the ray direction D, ``r² = w·w +
        2t w·D + t² D·D``, ``N·l = (N·w + t N·D)/r``, ``V·l = (V·w + t V·D)/r``
        and ``cos α = (N·l + N·V) / |l + V|``, ``|l + V|² = 1 + 2 V·l + V·V``.
        The last few t are remembered (the walk revisits them).
        """
        hit = self._memo.get(t)
        if hit is not None:
            return hit
        c = self._coef
        r2 = c["ww"] + t * (2.0 * c["wd"] + t * c["dd"])
        r = np.sqrt(r2)
        nl = c["nd"] * t
        nl += c["nw"]
        nl /= r
        vl = c["vd"] * t
        vl += c["vw"]
        vl /= r
        vl *= 2.0
        vl += c["vv1"]
        np.sqrt(vl, out=vl)
        nl += c["nv"]
        nl /= vl
        np.clip(nl, -1.0, 1.0, out=nl)
        a2 = np.arccos(nl, out=nl)
        a2 *= a2
        if self.space == "ratio":
            out = (self._E_cols, a2, self._base)
        elif self.space == "ratio-t":
            out = (self._I_cols * r2, a2, self._base)
        else:
            out = (self._I_cols, a2, self._base / r2)
        if len(self._memo) >= 4:
            self._memo.pop(next(iter(self._memo)))
        self._memo[t] = out
        return out

    @staticmethod
    def lobe(a2: np.ndarray, base: np.ndarray, kappa: float) -> np.ndarray:
        """``base · exp(−α² κ² / 2)``, shape (n,)."""
        return base * np.exp(-0.5 * a2 * kappa**2)

    @staticmethod
    def value(target: np.ndarray, ks: np.ndarray, g: np.ndarray) -> float:
        """E_energy for the residuals ``target − Ks g``."""
        return float(np.sum((target - g[:, None] * ks) ** 2))


def alternating_minimisation(
    energy: Energy,
    *,
    ks: np.ndarray,
    sigma: float,
    t: float,
    dt: float,
    gamma: float | None = None,
    eps1: float | None = None,
    eps2: float | None = None,
    eps3: float | None = None,
    eps4: float | None = None,
    max_outer: int = 2000,
    max_inner: int = 200,
) -> dict:
    """Steps 1–6 of §3.4 from ``(ks, sigma, t)``: the AM as printed, fast.

    The same steps, tests and order as :func:`alternating_minimisation_reference`
    (the plain transcription), so the same walk: every t, every step count,
    and Ks, σ to rounding (``tests/test_paper_fidelity.py``). What makes it
    fast, none of it changing a step: α² at each t from per-pixel scalars
    that do not depend on t (:meth:`Energy.columns`), remembered for the t
    the walk revisits; channel-major arrays whose sums are single-threaded
    BLAS dot products; the residual of an accepted trial kept for the next
    gradient, and a step-6 candidate's lobe kept for the next Ks.

    Defaults: ``ε1 = ε3 = 1e-6 σ*``, ``ε2 = 1e-6 max Ks*``, ``ε4 = Δt/2``
    (t moves by Δt, so any move continues). ``gamma=None`` (default) takes
    at each step the inverse Gauss–Newton curvature in κ,
    ``1 / (2 Σ (∂ρ/∂κ)²)``; a number fixes γ. Either way a step that would
    increase E_energy is halved until it does not.

    Returns
    -------
    dict
        ``ks``, ``sigma``, ``t``, ``energy`` (E_energy after each outer
        iteration, starting with the initial value), ``outer``, ``inner``
        (total inner steps), ``halvings``, ``gamma``, ``eps``, ``converged``.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _am_fast(energy, ks=ks, sigma=sigma, t=t, dt=dt, gamma=gamma, eps=(eps1, eps2, eps3, eps4),
                        max_outer=max_outer, max_inner=max_inner)


def _am_eps(ks: np.ndarray, sigma: float, dt: float, eps: tuple) -> tuple[float, float, float, float]:
    """ε1–ε4 with the defaults of :func:`alternating_minimisation` for those that are None."""
    eps1, eps2, eps3, eps4 = eps
    return (1e-6 * sigma if eps1 is None else eps1, 1e-6 * float(np.max(np.abs(ks))) if eps2 is None else eps2,
            1e-6 * sigma if eps3 is None else eps3, dt / 2 if eps4 is None else eps4)


def _am_done(ks_new: np.ndarray, ks: np.ndarray, sigma_new: float, sigma_old: float, t_new: float, t: float,
             eps: tuple[float, float, float, float]) -> bool:
    """Step 7's test: Ks, σ and t each moved by at most ε2, ε3, ε4."""
    return (float(np.max(np.abs(ks_new - ks))) <= eps[1] and abs(sigma_new - sigma_old) <= eps[2]
            and abs(t_new - t) <= eps[3])


def _am_result(ks: np.ndarray, kappa: float, t: float, history: list, counts: tuple[int, int, int, bool],
               gamma: float | None, eps: tuple) -> dict:
    """The AM's result dict (see :func:`alternating_minimisation`); counts: outer, inner, halvings, converged."""
    outer, inner, halvings, converged = counts
    return {
        "ks": ks, "sigma": 1.0 / kappa, "t": t, "energy": np.array(history), "outer": outer,
        "inner": inner, "halvings": halvings, "gamma": "gauss-newton" if gamma is None else gamma,
        "eps": list(eps), "converged": converged,
    }


def _am_fast(energy: Energy, *, ks, sigma, t, dt, gamma, eps, max_outer, max_inner) -> dict:
    ks = np.asarray(ks, dtype=float).copy()
    eps = _am_eps(ks, sigma, dt, eps)
    eps1 = eps[0]
    lobe = energy.lobe

    def residual(E: np.ndarray, k: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, float]:
        R = np.multiply(k[:, None], g)
        np.subtract(E, R, out=R)
        flat = R.reshape(-1)
        return R, float(flat @ flat)

    E, a2, base = energy.columns(t)
    kappa = 1.0 / sigma
    g = lobe(a2, base, kappa)
    history = [residual(E, ks, g)[1]]
    inner_total = halvings = 0
    for outer in range(1, max_outer + 1):
        # step 2: exact least-squares Ks for fixed σ, t
        ks_new = (E @ g) / float(g @ g)
        # steps 3-5: steepest descent on κ = 1/σ
        sigma_old = 1.0 / kappa
        R, current = residual(E, ks_new, g)
        kk = float(ks_new @ ks_new)
        for _ in range(max_inner):
            inner_total += 1
            q = a2 * g  # ∂ρ_m/∂κ = κ q Ks,m
            grad = 2.0 * kappa * float(ks_new @ (R @ q))
            step = (gamma if gamma is not None else 1.0 / (2.0 * kappa * kappa * kk * float(q @ q))) * grad
            for _ in range(60):
                trial = kappa - step
                g_trial = lobe(a2, base, trial)
                R_trial, value = residual(E, ks_new, g_trial)
                if trial > 0 and value <= current:
                    break
                step /= 2.0
                halvings += 1
            else:
                trial, g_trial, value, R_trial = kappa, g, current, R
            moved = abs(1.0 / trial - 1.0 / kappa)
            kappa, g, current, R = trial, g_trial, value, R_trial
            if moved <= eps1:
                break
        # step 6: t among {t − Δt, t, t + Δt}
        best = (current, t, E, a2, base, g)
        for tc in (t - dt, t + dt):
            if tc <= 0:
                continue
            Ec, a2c, bc = energy.columns(tc)
            gc = lobe(a2c, bc, kappa)
            vc = residual(Ec, ks_new, gc)[1]
            if vc < best[0]:
                best = (vc, tc, Ec, a2c, bc, gc)
        current, t_new, E, a2, base, g = best
        history.append(current)
        converged = _am_done(ks_new, ks, 1.0 / kappa, sigma_old, t_new, t, eps)
        ks, t = ks_new, t_new
        if converged:
            break
    return _am_result(ks, kappa, t, history, (outer, inner_total, halvings, converged), gamma, eps)


def alternating_minimisation_reference(
    energy: Energy, *, ks: np.ndarray, sigma: float, t: float, dt: float, gamma: float | None = None,
    eps: tuple = (None, None, None, None), max_outer: int = 2000, max_inner: int = 200,
) -> dict:
    """Steps 1–6 of §3.4, transcribed plainly: what :func:`alternating_minimisation` must agree with.

    The same options (``eps`` = ``(eps1, eps2, eps3, eps4)``) and result;
    the same steps, t and counts, Ks and σ to rounding. Slow: on a 640×480
    capture whose t walks 1.4 m in 1-mm steps, about 3.5 minutes.
    """
    ks = np.asarray(ks, dtype=float).copy()
    eps = _am_eps(ks, sigma, dt, eps)
    eps1 = eps[0]
    E, a2, base = energy.at(t)
    kappa = 1.0 / sigma
    history = [energy.value(E, ks, energy.lobe(a2, base, kappa))]
    inner_total = halvings = 0
    for outer in range(1, max_outer + 1):
        # step 2: exact least-squares Ks for fixed σ, t
        g = energy.lobe(a2, base, kappa)
        ks_new = (E * g[:, None]).sum(axis=0) / float(g @ g)
        # steps 3-5: steepest descent on κ = 1/σ
        sigma_old = 1.0 / kappa
        current = energy.value(E, ks_new, g)
        for _ in range(max_inner):
            inner_total += 1
            rho = E - g[:, None] * ks_new
            d_rho = (a2 * kappa * g)[:, None] * ks_new  # ∂ρ/∂κ
            grad = 2.0 * float(np.sum(rho * d_rho))
            step = (gamma if gamma is not None else 1.0 / (2.0 * float(np.sum(d_rho * d_rho)))) * grad
            for _ in range(60):
                trial = kappa - step
                g_trial = energy.lobe(a2, base, trial)
                value = energy.value(E, ks_new, g_trial)
                if trial > 0 and value <= current:
                    break
                step /= 2.0
                halvings += 1
            else:
                trial, g_trial, value = kappa, g, current
            moved = abs(1.0 / trial - 1.0 / kappa)
            kappa, g, current = trial, g_trial, value
            if moved <= eps1:
                break
        # step 6: t among {t − Δt, t, t + Δt}
        best = (current, t, E, a2, base)
        for tc in (t - dt, t + dt):
            if tc <= 0:
                continue
            Ec, a2c, bc = energy.at(tc)
            vc = energy.value(Ec, ks_new, energy.lobe(a2c, bc, kappa))
            if vc < best[0]:
                best = (vc, tc, Ec, a2c, bc)
        current, t_new, E, a2, base = best
        history.append(current)
        converged = _am_done(ks_new, ks, 1.0 / kappa, sigma_old, t_new, t, eps)
        ks, t = ks_new, t_new
        if converged:
            break
    return _am_result(ks, kappa, t, history, (outer, inner_total, halvings, converged), gamma, eps)


#: Refinements of stage 2 (option ``am``): ``printed`` (§3.4 as printed, ±Δt
#: steps of t) and ``bounded`` (a DEPARTURE from the printed paper:
#: :func:`bounded_minimisation`).
AMS = ("printed", "bounded")


def bounded_minimisation(energy: Energy, *, ks: np.ndarray, sigma: float, t: float, t_max: float, dt: float,
                         n_coarse: int = 24, span: float = 4.0) -> dict:
    """Stage 2 with E re-measured at every t and a proper 1-D search over t (a DEPARTURE from §3.4).

    The printed AM moves t by ±Δt per outer iteration and stops where both
    neighbours cost energy with Ks, σ fitted to the current t: a
    coordinate-wise minimum, short of the minimum along the ray. Here t
    minimises the profile ``min over Ks, σ of E_energy(Ks, σ, t)`` (Ks
    exact least squares for each σ; σ by a bounded Brent search on ln σ
    within a factor 10 of the first stage's), first on ``n_coarse``
    log-spaced t in ``[t*/span, min(span·t*, t_max)]``, then by a bounded
    Brent search between the coarse minimum's neighbours to Δt/10.
    ``energy`` should re-measure E at each t (``radiance`` or ``ratio-t``).

    Returns
    -------
    dict
        ``ks``, ``sigma``, ``t``, ``energy`` (the profile at the coarse t,
        then at the result), ``t_coarse``, ``evaluations`` (profile
        evaluations), ``converged``.
    """
    bounds = (np.log(sigma) - np.log(10.0), np.log(sigma) + np.log(10.0))
    calls = [0]

    def profile(tc: float) -> tuple[float, np.ndarray, float]:
        calls[0] += 1
        E, a2, base = energy.at(tc)

        def fit(log_sigma: float) -> tuple[float, np.ndarray]:
            g = energy.lobe(a2, base, float(np.exp(-log_sigma)))
            gg = float(g @ g)
            if not gg > 0:
                return np.inf, np.zeros(3)
            k = (E * g[:, None]).sum(axis=0) / gg
            return energy.value(E, k, g), k

        res = minimize_scalar(lambda x: fit(x)[0], bounds=bounds, method="bounded", options={"xatol": 1e-7})
        value, k = fit(float(res.x))
        return value, k, float(np.exp(res.x))

    lo, hi = t / span, min(span * t, t_max)
    grid = np.geomspace(lo, hi, n_coarse)
    values = np.array([profile(tc)[0] for tc in grid])
    i = int(np.argmin(values))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, n_coarse - 1)]
    res = minimize_scalar(lambda tc: profile(tc)[0], bounds=(a, b), method="bounded", options={"xatol": dt / 10})
    t_best = float(res.x) if res.fun <= values[i] else float(grid[i])
    value, ks_best, sigma_best = profile(t_best)
    return {
        "ks": ks_best, "sigma": sigma_best, "t": t_best, "energy": np.append(values, value),
        "t_coarse": grid, "evaluations": calls[0], "converged": bool(res.success),
    }


@forwards(stage_one)
def paper_estimate(
    capture: Capture,
    *,
    gamma: Positive | None = None,
    eps1: Positive | None = None,
    eps2: Positive | None = None,
    eps3: Positive | None = None,
    eps4: Positive | None = None,
    max_outer: Count = 2000,
    pixels: Choice(Energy.PIXELS) = "surface",
    energy: Choice(Energy.SPACES) | None = None,
    am: Choice(AMS) = "printed",
    **init_options,
) -> Estimate:
    """Method ``paper``: ``paper-init`` followed by the AM refinement of eq. 18 (§3.4).

    Discontinuous by design, like ``paper-init`` (the peak pixel, and t on
    the Δt grid, in the first stage and in step 6); with those choices
    unchanged, stable under float rounding to 1e-5 of the camera–highlight
    distance (lamp) and 1e-4 relative (σ, Ks): see the module docstring.

    Parameters
    ----------
    capture : Capture
    gamma, eps1, eps2, eps3, eps4, max_outer :
        AM options; see :func:`alternating_minimisation` for defaults.
    pixels : {"surface", "specular"}
        Pixels of E_energy (default every surface pixel, as the paper's N_k).
    energy : {"ratio", "ratio-t", "radiance"}, optional
        ``"ratio"`` (default of the printed AM): eq. 18 as printed, E measured
        once at t*; ``"ratio-t"``: E re-measured at every t; ``"radiance"``
        (default of ``am="bounded"``): image-space residuals; see
        :class:`Energy`. ``am="bounded"`` re-measures E at every t, so it
        refuses ``"ratio"`` (a one-line error, not a silent substitution).
    am : {"printed", "bounded"}
        ``"printed"`` (default): the AM of §3.4 (t in ±Δt steps);
        ``"bounded"``: DEPARTURE from the printed paper, t by a 1-D search
        of the profile energy (:func:`bounded_minimisation`).
    **init_options
        Options of :func:`stage_one` (``separation``, ``threshold``,
        ``t_max``, ``dt``, ``search``, ``n_coarse``).
    """
    init, obs = stage_one(capture, **init_options)
    clock = time.perf_counter()
    d = init.diagnostics
    if am == "bounded" and energy == "ratio":
        raise UserError("option energy=ratio measures E once, at t*; am=bounded re-measures it at every t: "
                        "use energy=radiance (its default) or ratio-t")
    energy = energy or ("radiance" if am == "bounded" else "ratio")
    objective = Energy(obs, np.asarray(d["ray_origin"]), np.asarray(d["ray_direction"]), pixels=pixels, space=energy,
                       t_ref=init.stages["init"]["t"])
    if am == "bounded":
        am = bounded_minimisation(objective, ks=init.ks, sigma=init.sigma, t=init.stages["init"]["t"],
                                  t_max=d["t_max"], dt=d["dt"])
        am["am"], am["space"] = "bounded", energy
    else:
        am = alternating_minimisation(
            objective, ks=init.ks, sigma=init.sigma, t=init.stages["init"]["t"], dt=d["dt"], gamma=gamma,
            eps1=eps1, eps2=eps2, eps3=eps3, eps4=eps4, max_outer=max_outer,
        )
    lamp = objective.origin + am["t"] * objective.direction
    timings = {**init.timings, "am": time.perf_counter() - clock}
    stage = {k: v for k, v in am.items() if k != "energy"}
    return Estimate(
        method="paper",
        lamp_position=lamp,
        ks=am["ks"],
        sigma=am["sigma"],
        stages={"init": init.stages["init"], "am": {**stage, "lamp_position": lamp}},
        diagnostics={**d, "energy": am["energy"]},
        timings=timings,
    )
