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
(:func:`~nearlight.estimator.geometry.fill_range_holes`).
"""

from __future__ import annotations

import time
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field
from scipy.stats import chi2 as chi2_dist

from ..capture import Capture
from ..errors import UserError
from ..physics.reflectance import LOBES, peak_shape, roughness_for_ts_sigma, ts_sigma
from .first_stage import ray_stage, stage_one
from .fitting import LOSSES
from .joint_surface import fixed_surface_warning, joint_fit, split_refined, surface_fit_choice
from .lobes import FAMILIES
from .observation import THRESHOLD, Observation, observation_of
from .options import Choice, Count, CountOrZero, Positive, forwards
from .noise import std_floor
from .pixels import weighted_fit_pixels
from .pointlamp import (PointLampModel, best_short_fit, final_fit, loss_floor, peak_ray_starts, short_fit,
                        start_observation)
from .result import Estimate
from .separation import SEPARATION_METHODS
from .several import MAX_FITTED_LAMPS, several_estimate


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
#: not determine the lamp. Measured at 160×120, 4 angles, the 12-bit ``real_camera`` of
#: suites/paper-v1.yaml: the cylinder, whose mirror point is off the object (half-angle ≥ 24.9°, 4.8 σ;
#: peak specular 3e-5, ~1 electron, total SNR 0.06, CRLB 524 m), 7.6–24 over seeds 0–7 (pure noise
#: fitted by seven parameters); every other paper scene ≥ 1.7e6 (seeds 0, 1), noise-free ≥ 2e9.
SPECULAR_EVIDENCE = 100.0

#: ``full`` warns that its covariance leaves a misfit out when the fit's χ² rejects the camera-noise model
#: at this level (``χ²`` over ``3n − 7`` degrees of freedom, one-sided; 1 in 1000 captures whose model and
#: noise are right gets the warning). Measured on suites/core-v1.yaml with the 12-bit sensor's noise (160×120):
#: the ideal rig's 12 cases χ²/dof 0.86-1.00, log10 p ≥ −0.3 (the truth's squared Mahalanobis distance under
#: the covariance 1.6-8, one 162); the bench profile's 12 cases 1.06-1.43, log10 p −2.5 to −134 (distances
#: 290-11 000: the lamp's disc, the polarizers' leak, the calibration errors move the lamp far beyond the
#: camera noise's ellipsoid), 11 of them below 1e-3. The one above, the Torrance–Sparrow sphere with the lamp
#: at 0.8 m (1.058 over 4550, p = 3e-3), is masked by the sphere's noise model reading more noise than there
#: is (χ²/dof 0.86-0.89 on the ideal rig). The bench rig's torus of sweeps/bench_seeds/ at 640×480: χ²/dof 16.
MISFIT_P = 1e-3

#: ``full``'s ``lobe`` option.
LobeChoice = Annotated[str, AfterValidator(_lobe_choice)]
#: ``full``'s ``lamps`` option: a number of lamps, or ``auto``.
LampCount = Annotated[int, Field(ge=1, le=MAX_FITTED_LAMPS)] | Literal["auto"]
#: Pixel-weight models of ``full``'s ``noise`` option.
NOISE_MODELS = ("none", "auto")

#: ``full``'s ``surface`` option: the surface refined with the lamp or taken as given.
SURFACE_FITS = ("auto", "joint", "fixed")

#: About how many pixels the multi-start's short fits use (every k-th of the fitted pixels).
TRIAL_PIXELS = 500


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


def misfit_warning(chi2: float, dof: int, std: np.ndarray | None, floor: float) -> str | None:
    """The warning of a fit whose residuals the camera noise does not explain (:data:`MISFIT_P`), else None.

    ``std`` (n, 3) are the fit's per-value standard deviations (None: no camera model, the residuals are their
    own noise's measure) and ``floor`` their float-rounding floor (:func:`~nearlight.estimator.noise.std_floor`):
    where most sit on it the capture is noise-free, the weights the floor's and not a
    camera's, and a render's own last bits (the Mitsuba cylinder's residuals 1.27× the floor) are no misfit.
    """
    if std is None or np.mean(std <= floor * (1 + 1e-6)) > 0.5:
        return None
    if not chi2 > dof or chi2_dist.sf(chi2, dof) >= MISFIT_P:
        return None
    return (f"covariance: the camera noise's share only; the fit leaves {chi2 / dof:.3g} times the residual "
            f"variance the camera noise explains (chi2/dof over {dof} values, 1 ± {np.sqrt(2 / dof):.2g} for a "
            "model that explains the image): structure the lobe does not model (a lamp's size or beam, a "
            "polarizer's leak, a calibration error) moves the lamp beyond the stated ellipsoid")


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
    surface: Choice(SURFACE_FITS) = "auto",
    **init_options,
) -> Estimate:
    """Method ``full``: ``paper-init``, then a weighted robust fit of lamp position, Ks and roughness.

    Lands on the same minimum for inputs that differ by float rounding
    wherever that minimum is unique: the multi-start
    (:func:`peak_ray_starts`) makes the answer independent of which start wins when
    several reach the same minimum, and of the peak pixel ``paper-init``
    picks (a symmetric board's two mirror-image peaks give the same lamp).
    Stability (``tests/estimator/test_stability.py``): a ±1-ulp float32
    change of every image (stack, P, N) moves the lamp by at most 3e-5 of
    the camera–highlight distance and σ and Ks by at most 1e-4 relative.
    Where the data hold two minima of equal cost to the last bits, the
    lower-cost start wins and the answer can flip between them; no shipped
    scene has shown one.

    Speed (``benchmarks/bench_estimator.py``): the start is the first stage
    on a lattice of ~:data:`~nearlight.estimator.pointlamp.START_PIXELS`
    specular pixels rather than on all of them (~53 000 on the 640×480
    board), the multi-start's short fits run on ~:data:`TRIAL_PIXELS` of the
    fitted pixels, until two agree, by variable projection (the colour solved
    linearly at every step, the solver moving lamp and roughness only:
    :func:`~nearlight.estimator.pointlamp.short_fit`), and the model
    evaluates its geometry once per lamp and roughness for the residuals,
    the Jacobian and the solved colour. Only the final fit sees every fitted
    pixel (``max_pixels``); it lands on the minimum a start on the whole mask
    reaches (docs/measurements/estimator-choices.md, "full").

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
    that camera; ``none`` weighs all pixels alike. On a noise-free capture
    the residuals measure no noise and every pixel gets the floor (equal
    weights). Dark pixels, whose readings the sensor may have clipped at
    zero (:func:`~nearlight.estimator.noise.censored_pixels`: their separated
    specular is biased and its variance wrong), are measured from their
    readings by a censored likelihood instead
    (:func:`~nearlight.estimator.censored.censored_specular`,
    :func:`~nearlight.estimator.pixels.weighted_fit_pixels`;
    ``stages["full"]["n_dark_measured"]``). A black (``kd = 0``) board stays
    the weighted fit's weak case: its error is the highlight's own
    crossed-analyzer readings, near zero and clipped although the pixel is
    bright, not its dark pixels. What the weights and the censored pixels
    bring, measured against the Cramér–Rao bound:
    docs/measurements/estimator-choices.md, "full".

    Whether there is a highlight at all: ``stages["full"]["specular_evidence"]`` is
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
        (:func:`~nearlight.estimator.pointlamp.best_short_fit`; how many ran:
        ``stages["full"]["n_short_fits"]``).
    surface : {"auto", "joint", "fixed"}
        Whether a surface fitted to a noisy range is refined with the lamp
        (:mod:`~nearlight.estimator.joint_surface`: one plane or one sphere, its
        parameters fitted with the lamp, colour and roughness against the image
        and the range together; the covariance then holds the geometry's
        share): ``auto`` (the default) when the range's error is above
        :data:`~nearlight.estimator.joint_surface.JOINT_MIN_RANGE_M`, ``joint`` whenever the surface is a plane or a
        sphere, ``fixed`` never. Which ran, and why: ``stages["full"]["surface_fit"]``
        (``"joint"`` or ``"fixed"``) and ``surface_fit_reason``; the refined
        surface in ``surface_parameters``. With several lamps the chosen count's
        fit is refined with the surface they share.
    lamps : int or "auto"
        Number of point lamps fitted: 1 (the default: the fit above), K ≤
        :data:`~nearlight.estimator.several.MAX_FITTED_LAMPS`, or ``"auto"`` (the count
        of least BIC); see :func:`~nearlight.estimator.several.several_estimate`.
        With one lamp, an image of several separate highlights gets a line in
        ``diagnostics["warnings"]`` from the rules every estimate passes
        (:func:`~nearlight.estimator.sanity.review`), as every one-lamp method does.
    **init_options
        Options of :func:`~nearlight.estimator.first_stage.stage_one`: ``threshold``
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
        ``diagnostics``: the start's (:func:`~nearlight.estimator.first_stage.ray_stage`
        on the lattice), with ``n_specular_pixels`` the whole mask's count and
        ``n_start_pixels`` the lattice's.
    """
    if loss not in LOSSES:
        raise UserError(f"option loss: expected one of {', '.join(LOSSES)}, got {loss!r}")
    one, obs = one_lamp_fit(capture, lobe=lobe, noise=noise, loss=loss, f_scale=f_scale, max_pixels=max_pixels,
                            saturation=saturation, n_starts=n_starts, separation=separation, surface=surface,
                            **init_options)
    if lamps == 1:
        return one
    return several_estimate(capture, one, obs, lamps=lamps, lobe=lobe, noise=noise, loss=loss, f_scale=f_scale,
                            max_pixels=max_pixels, saturation=saturation, n_starts=n_starts, separation=separation,
                            surface=surface)


def one_lamp_fit(capture: Capture, *, lobe: str, noise: str, loss: str, f_scale: float | None, max_pixels: int,
                 saturation: float | None, n_starts: int, separation: str, surface: str = "fixed",
                 **init_options) -> tuple[Estimate, Observation]:
    """:func:`full_estimate` with one lamp, and the observation it fitted (options as its, checked there).

    Returns
    -------
    Estimate
        ``full_estimate(capture, lamps=1, ...)``.
    Observation
        The capture's observation (:func:`~nearlight.estimator.observation.observation_of`), whole mask.
    """
    clock = time.perf_counter()
    obs = observation_of(capture, separation=separation, threshold=init_options.pop("threshold", THRESHOLD))
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
    joint, why = surface_fit_choice(obs, surface)
    dof = max(3 * len(model.P) - 7, 1)
    refitted = [k for k, v in evidence.items() if v < REFIT_EVIDENCE]
    fits = {}
    for family in refitted:
        m = model.with_lobe(family)
        x0 = shorts[family][0]
        if joint and len(refitted) == 1:
            # one lobe to fit: the joint fit is the final fit, from the short fit as the image-only one would start
            # (the prior's scale from the start's residuals over every pixel: within ~0.1 % of the fit's)
            fits[family] = joint_fit(m, obs.geometry.parameters, x0, obs.scale, loss=loss, f_scale=f_scale,
                                     floor=floor, scale=float(np.sqrt(_chi2(m, x0) / dof)))
        else:
            fits[family] = final_fit(m, x0, obs.scale, loss=loss, f_scale=f_scale, floor=floor)
            fits[family]["chi2"] = _chi2(m, fits[family]["x"])
    chosen = min(fits, key=lambda k: fits[k]["chi2"])
    fit = fits[chosen]
    s2_all = fit["chi2"] / dof
    refit = {k: (v["chi2"] - fit["chi2"]) / s2_all for k, v in fits.items()}
    evidence_specular = _specular_evidence(_chi2_none(model), fit["chi2"], s2_all)
    refined = None
    if joint:
        if "prior_chi2" not in fit:  # several lobes fitted on the range's surface: the chosen one refined with it
            fit = joint_fit(model.with_lobe(chosen), obs.geometry.parameters, fit["x"], obs.scale, loss=loss,
                            f_scale=f_scale, floor=floor, scale=float(np.sqrt(s2_all)))
        fit, refined = split_refined(obs, fit, 7)
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
        "surface_fit": "joint" if joint else "fixed", "surface_fit_reason": why, "surface_parameters": refined,
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
    ).with_warning(no_specular_warning(evidence_specular)).with_warning(fixed_surface_warning(obs, joint)).with_warning(
        misfit_warning(fit["chi2"], dof, std, std_floor(fit_px.specular))), obs
