"""The paper's second stage (Hara et al. 2002, §3.4): method ``paper``, the alternating minimisation of eq. 18.

From the first stage's lamp on the peak ray, Ks and σ
(:mod:`~nearlight.estimator.first_stage`, method ``paper-init``), the
alternating minimisation (AM) of eq. 18,
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

Step 6 searches ``{t − Δt, t, t + Δt}``, keeping t on ties. The AM runs
fast (:func:`alternating_minimisation`) and walks exactly the steps of its
plain transcription (:func:`alternating_minimisation_reference`). E_energy
uses only pixels with range (a range hole's filled pixels are the first
stage's, for the ray's origin only).

Option beyond the printed paper, named for what it is: ``am``, ``printed``
(default) or ``bounded`` (a DEPARTURE: E re-measured at every t, t by a
bounded 1-D search of the profile energy, which cannot stall on ±Δt steps;
:func:`bounded_minimisation`). The first stage's options (``origin`` among
them) are the method's too.

Discontinuous by design, as the first stage: t moves on the Δt grid, and an
image change that reorders two grid values of E_energy in step 6 moves the
lamp to another grid point; with the first stage's peak pixel and t and
every step's choice unchanged, a ±1-ulp float32 change of every image moves
the lamp by at most 1e-5 of the camera–highlight distance and σ and Ks by at
most 1e-4 relative (``tests/estimator/test_stability.py``).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import minimize_scalar
from threadpoolctl import threadpool_limits

from ..capture import Capture
from ..errors import UserError
from ..physics.reflectance import normalize, shading_geometry
from .first_stage import stage_one
from .observation import Observation
from .options import Choice, Count, Positive, forwards
from .result import Estimate

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
    and Ks, σ to rounding (``tests/estimator/test_paper_fidelity.py``). What makes it
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
