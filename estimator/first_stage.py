"""The paper's first stage (Hara et al. 2002, §3.2–3.3), method ``paper-init``: the lamp on the peak's mirror ray.

The lamp lies on the ray ``L = P + t·Lp`` (eq. 9) from the peak pixel's
surface point along the mirror direction ``Lp`` (eq. 8). For each t, every
specular pixel gives a point ``(X, Y_m)`` with ``X = α(t)²/2`` and
``Y_m = ln E_m + ln cos θr`` (eq. 12–13), where ``E_m = I_s,m · r(t)² /
I_lamp`` (eq. 6–7; ``I_lamp = 1``, so Ks absorbs the lamp intensity).
``t*`` minimises ``E_p(t) = Σ_m r_XY_m`` (eq. 14–15), the sum of the
correlation coefficients (:class:`RaySearch`, searched by :data:`SEARCHES`);
Ks and σ come from the regression line (eq. 16–17), σ the mean over channels.

Eq. 8 as printed, ``N + (N, V) N − V``, is the mirror direction only when
``N·V = 1``; we use the exact mirror ``2 (N·V) N − V``
(:func:`nearlight.physics.reflectance.mirror_direction`).

This stage is method ``paper-init`` (:func:`initial_estimate`), the start of
method ``paper`` (:mod:`~nearlight.estimator.paper`, the alternating
minimisation of §3.4), and the start of ``full``
(:mod:`~nearlight.estimator.full`, on a lattice of the specular pixels) and of
``render-compare`` (:mod:`nearlight.rendercompare.method`).

A range hole on the highlight (no ``P`` at the brightest pixels,
``nuisances.range.holes_shiny_above``) does not move the peak or the ray:
the hole's surface points and normals come from a quadric fitted to the
range around it (:func:`~nearlight.estimator.geometry.fill_range_holes`),
for every origin; E_p and the regression use only pixels with range, so t*
moves with the pixels the hole takes away (``tests/estimator/test_holes.py``).

Option beyond the printed paper, named for what it is: ``origin``, where the
ray of eq. 9 starts (:data:`ORIGINS`). ``peak`` (the default, the printed
paper), ``subpixel``, ``model`` (a DEPARTURE: the brightest pixel corrected
by the offset δ ∝ σ² the model predicts, since 1/r² and 1/cos θr move the
intensity maximum away from the mirror point), and the ORACLE
``mirror-oracle`` (the true mirror point, read from the capture's truth; with
``origin_shift`` s, the point ``m + s·δ``), which separates the method's error
from its origin's.

Discontinuous by design: the stage picks the brightest specular pixel (the
peak) and a t on the Δt grid, and an image change that reorders two pixels'
brightness, or two grid values of E_p, moves the lamp to another ray or grid
point. Float rounding alone does not move the peak: pixels within 2⁻¹⁹ (16
float32 ulps) of the brightest are tied and resolved by position
(:data:`~nearlight.estimator.observation.PEAK_TIE`), so a symmetric scene's
two mirror-image peaks give the same ray on every machine; a larger
difference between them picks the brighter one, and the lamp jumps to the
mirror-image ray (σ, Ks and t stay). What stays put: with the same peak pixel
and t, a ±1-ulp float32 change of every image (stack, P, N) moves the lamp by
at most 1e-5 of the camera–highlight distance (it moves only with the ray)
and σ and Ks by at most 1e-4 relative (``tests/estimator/test_stability.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Annotated

import numpy as np
from pydantic import Field
from scipy.optimize import minimize, minimize_scalar

from ..capture import Capture
from ..errors import UserError
from ..physics.reflectance import channel_sum, mirror_direction, normalize, shading_geometry
from .fitting import log_regression
from .highlights import several_highlights_warning
from .observation import THRESHOLD, Observation, observation_of, subpixel_peak, surface_at
from .options import Choice, Count, Fraction, Positive, forwards
from .result import Estimate
from .separation import SEPARATION_METHODS

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
        Bad input (see :func:`~nearlight.estimator.observation.observation_of`) or a
        ``t_max`` that cannot reach the lamp (E_p minimal at t_max).
    """
    clock = time.perf_counter()
    obs = observation_of(capture, separation=separation, threshold=threshold)
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
    """:func:`stage_one` after :func:`~nearlight.estimator.observation.observation_of`: the ray, its t search and the regression.

    E_p and the regression run over ``obs.mask``'s pixels (``full`` passes
    an observation whose mask is thinned, :func:`~nearlight.estimator.pointlamp.start_observation`).
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
