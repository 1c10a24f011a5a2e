"""The rules every estimate passes before it is reported: what the data can support.

:func:`nearlight.estimator.estimate` runs :func:`check` on the result of every
method, built-in or plug-in. An estimate that breaks a rule is not a number:
:meth:`~nearlight.estimator.Estimate.refused` turns it into a failure
(``status="failed"``, NaN lamp, Ks and σ, the rule and its reason in
``diagnostics["failure"]``, the refused numbers in ``diagnostics["refused"]``),
which ``nearlight estimate`` reports with exit status 1 and sweeps and
scorecards count as a failed row.

The rules, their thresholds, and why (docs/physics.md, "What an estimate must
satisfy"):

``finite``
    Lamp, Ks and σ finite, Ks ≥ 0, σ > 0.
``roughness-range``
    The reported (Torrance–Sparrow) σ strictly inside (0.0001, π/2) rad: a
    spread of facet angles beyond π/2 means nothing, and 0.0001 is the floor of
    ``full``'s roughness (:func:`~nearlight.estimator.pointlamp.lamp_bounds`); a
    σ at either end is a fit out of room (or the paper's regression line
    gone flat), not a measurement.
``determined``
    The method's own fit determines the light: an estimate whose
    ``diagnostics["undetermined"]`` names ``light_direction`` (``distant`` on
    a plane, where one constant per channel fits every direction and σ
    alike) reports a placeholder, not an answer. Its lamp may still land
    near the truth (``distant``'s placeholder is the mirror direction at the
    peak, set at the camera's distance by convention: 2.8–4.2 % off on five
    rows of the GSA screening whose lamp stood within 4 % of the camera's
    distance), which is the convention's luck, not the data's support.
``reach``
    The lamp within :data:`REACH` × the camera–highlight distance of the
    highlight's peak point (or within the method's own ``t_max`` option when
    larger): the volume the paper's ray search scans (its default ``t_max``,
    :func:`~nearlight.estimator.first_stage.t_search_defaults`). Farther than that
    a near-light capture cannot tell the lamp from a distant light; a method
    that answers farther is extrapolating.
``in-front``
    The lamp above the tangent plane of its highlight: at least
    :data:`IN_FRONT_MIN` of the highlight's specular energy (the observation's
    mask, weighted by specular luminance) at pixels where ``N · (L − P) > 0``.
    A specular lobe lit from behind its surface is zero, so a lamp behind the
    highlight cannot have made it.
``explains``
    The estimate's re-synthesised specular (:func:`~nearlight.estimator.render_specular`,
    the estimator's own forward model) explains at least :data:`EXPLAINED_MIN`
    of the observed highlight: ``1 − Σ(S − Ŝ)² / Σ S²`` over the highlight's
    pixels and channels, less those with a reading at the sensor's saturation
    (:func:`clipped`). Zero means the estimate predicts no highlight (e.g.
    Ks ≈ 0), negative one far brighter than observed. When Ks alone breaks
    it (the re-synthesis with Ks rescaled per channel explains at least
    :data:`EXPLAINED_MIN` of the highlight's variation about its mean,
    :func:`ks_scaled_fraction`), only Ks is refused
    (rule ``ks-scale``: Ks NaN, lamp and σ kept, status ``ok``;
    :meth:`~nearlight.estimator.Estimate.without_ks`). With several separate
    highlights, a one-lamp estimate is held to the one it explains best
    (:func:`own_highlight`), for this rule and ``in-front``.
``evident``
    The capture has a highlight: its peak stands at least
    :data:`SIGNIFICANCE_MIN` noise deviations high
    (:func:`highlight_significance`, the camera's noise stated or measured
    from the stack; not checked when the capture says nothing of its noise).
    A rule of the data, not of the estimate: below it, any method fits noise
    (e.g. the paper-v1 cylinder, whose mirror point is off the object: its
    specular is about one electron deep).
``located``
    When the method gives a covariance: finite, positive semi-definite to
    rounding, and the lamp's largest 1-σ position uncertainty at most
    :data:`LOCATED_MAX` × the lamp–highlight distance. A lamp the data place
    anywhere within ±100 % of its distance is not located.

Several-lamp estimates (``lamp_positions`` with more than one row) get the
``finite``, ``roughness-range``, ``determined``, ``reach`` and ``located`` rules, each lamp
checked for ``finite`` and ``reach``; ``in-front`` and ``explains`` need the
lamp each highlight pixel belongs to, which the estimate does not state.

A method that states the lamp alone (``diagnostics["undetermined"]`` names ``ks`` and ``sigma``:
``lambertian-plane``, ``mirror-spheres``) reads no highlight: it is held to
``finite`` on its lamp and ``located`` (its distance from the camera) only
(:data:`LAMP_ONLY`), and refuses itself what its own data do not support.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from ..capture import Capture
from ..errors import UserError
from .highlights import segment_highlights, several_highlights_warning
from .noise import camera_noise, specular_variance
from .observation import Observation, observation_of
from .prediction import specular_at
from .pointlamp import ROUGHNESS_RANGE
from .result import Estimate

#: ``reach``: lamp–highlight distance over the camera–highlight distance (the paper stage's default ``t_max``).
REACH = 10.0
#: ``in-front``: the least fraction of the highlight's specular energy lit from the front.
IN_FRONT_MIN = 0.5
#: ``explains``: the least fraction of the observed highlight's energy the re-synthesis explains.
EXPLAINED_MIN = 0.5
#: ``evident``: the least peak of the observed highlight in noise deviations (:func:`highlight_significance`):
#: twice what pure noise reached (the paper-v1 cylinder, 2.2–3.0 over 4 seeds); a non-linear camera response
#: inflates the measured noise (the realism study's gamma 1.5 board: 8.97, `full` 2.3 % off), so not higher.
#: Measured values in docs/physics.md, "What an estimate must satisfy".
SIGNIFICANCE_MIN = 6.0
#: ``located``: the largest 1-σ lamp uncertainty over the lamp–highlight distance.
LOCATED_MAX = 1.0
#: Relative closeness to a bound of ``ROUGHNESS_RANGE`` that counts as at it (the fit's own tolerance is 1e-8).
AT_BOUND = 1e-6


class UnsupportedEstimate(Exception):
    """Raised where a refused estimate must not go on as a number (a sweep's task, a scorecard's case)."""

    def __init__(self, est: Estimate):
        failure = est.diagnostics["failure"]
        super().__init__(f"{failure['rule']}: {failure['reason']}")
        self.estimate = est


class Failure(NamedTuple):
    """A broken rule: its name (see the module docstring) and a one-line reason with the numbers."""

    rule: str
    reason: str


def _finite(est: Estimate) -> Failure | None:
    lamps = est.found_lamps()
    if not (np.all(np.isfinite(lamps)) and np.all(np.isfinite(est.ks)) and np.isfinite(est.sigma)):
        return Failure("finite", f"not finite: lamp {_vec(est.lamp_position)}, Ks {_vec(est.ks)}, σ {est.sigma:.4g}")
    if np.any(est.ks < 0) or not est.sigma > 0:
        return Failure("finite", f"Ks {_vec(est.ks)} negative or σ {est.sigma:.4g} not positive")
    return None


def _roughness(est: Estimate) -> Failure | None:
    lo, hi = ROUGHNESS_RANGE
    if est.sigma <= lo * (1 + AT_BOUND) or est.sigma >= hi * (1 - AT_BOUND):
        return Failure("roughness-range", f"σ {est.sigma:.6g} rad at a bound of its range ({lo:g}, π/2): "
                                          "the fit ran out of room")
    return None


def _determined(est: Estimate) -> Failure | None:
    undetermined = list(est.diagnostics.get("undetermined", ()))
    if "light_direction" in undetermined:
        return Failure("determined", f"the method's own fit leaves {', '.join(undetermined)} undetermined on this "
                                     "capture (every value fits alike, as distant's on a plane), so its lamp is a "
                                     "placeholder, not an estimate")
    return None


def _reach(est: Estimate, obs: Observation, options: Mapping[str, Any]) -> Failure | None:
    anchor = obs.P[obs.peak]
    t_max = options.get("t_max")
    reach = max(REACH * obs.scale, float(t_max) if isinstance(t_max, (int, float)) else 0.0)
    for lamp in est.found_lamps():
        d = float(np.linalg.norm(lamp - anchor))
        if d > reach:
            return Failure("reach", f"lamp {_vec(lamp)} m is {d:.4g} m from the highlight, beyond {reach:.4g} m "
                                    f"({REACH:g} x the camera's {obs.scale:.4g} m, or t_max): the capture cannot "
                                    "tell a lamp that far from a distant light")
    return None


def _in_front(est: Estimate, obs: Observation, region: np.ndarray) -> Failure | None:
    P, N = obs.P[region], obs.N[region]
    w = obs.specular[region].mean(axis=-1)
    lit = np.einsum("ij,ij->i", N, est.lamp_position - P) > 0
    frac = float(w[lit].sum() / w.sum())
    if frac < IN_FRONT_MIN:
        return Failure("in-front", f"lamp {_vec(est.lamp_position)} m is behind the surface at {1 - frac:.0%} of "
                                   "the highlight (a lamp behind a surface lights no highlight on it)")
    return None


def explained_fraction(capture: Capture, est: Estimate, obs: Observation, region: np.ndarray | None = None, *,
                       predicted: np.ndarray | None = None) -> float:
    """``1 − Σ(S − Ŝ)² / Σ S²`` over the highlight's pixels and channels.

    Parameters
    ----------
    capture : Capture
    est : Estimate
        A one-lamp estimate (its re-synthesis Ŝ, :func:`~nearlight.estimator.render_specular`).
    obs : Observation
        The observed specular ``S``.
    region : ndarray, shape (H, W), bool, optional
        The highlight's pixels; default the observation's mask.
    predicted : ndarray, shape (H, W, 3), optional
        Ŝ, when already rendered (:func:`predicted_specular`).

    Returns
    -------
    float
        1 for a perfect re-synthesis, 0 for none (Ŝ = 0), negative when Ŝ is
        farther from S than 0 is.
    """
    region = obs.mask if region is None else region
    predicted = predicted_specular(est, obs) if predicted is None else predicted
    observed = obs.specular[region]
    return float(1.0 - np.sum((observed - predicted[region]) ** 2) / np.sum(observed**2))


def clipped(capture: Capture) -> np.ndarray:
    """Pixels with an analyzer reading at the stated saturation (``sensor.saturation``), shape (H, W), bool.

    All False for a capture with no stack or no stated saturation.
    """
    sensor = getattr(capture, "sensor", None)
    saturation = getattr(sensor, "saturation", None)
    if capture.stack is None or not saturation:
        return np.zeros((capture.height, capture.width), bool)
    return np.any(np.asarray(capture.stack) >= (1 - 1e-6) * float(saturation), axis=(0, 3))


def predicted_specular(est: Estimate, obs: Observation) -> np.ndarray:
    """The estimate's re-synthesised specular Ŝ over the observation's mask (0 elsewhere), shape (H, W, 3):
    :func:`~nearlight.estimator.render_specular`'s model at those pixels only."""
    out = np.zeros(obs.specular.shape)
    out[obs.mask] = specular_at(obs.P[obs.mask], obs.N[obs.mask], obs.camera_position, est)
    return out


def own_highlight(capture: Capture, est: Estimate, obs: Observation, *,
                  predicted: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The highlight a one-lamp estimate answers for, and the fraction of it that it explains.

    The observation's mask less its :func:`clipped` pixels (their specular
    is cut, so a right estimate predicts more there); with several separate highlights
    (:func:`~nearlight.estimator.highlights.segment_highlights`), the mask's
    part in the one the estimate explains best: a one-lamp method on a
    several-lamp capture answers for one lamp, and is held to that one's
    highlight (it also carries the several-highlights warning).

    Returns
    -------
    region : ndarray, shape (H, W), bool
    explained : float
        :func:`explained_fraction` over ``region``; NaN when every pixel of
        the highlight is clipped (then ``in-front`` and ``explains`` are not checked).
    """
    predicted = predicted_specular(est, obs) if predicted is None else predicted
    mask = obs.mask & ~clipped(capture)
    several = several_highlights_warning(obs) is not None  # made once per estimate (observation.shared)
    labels = segment_highlights(obs.specular, obs.located).labels if several else np.zeros(mask.shape, int)
    regions = [mask & (labels == k) for k in range(1, int(labels.max()) + 1)] if labels.max() > 1 else []
    candidates = [r for r in regions if r.any()] or [mask]
    if not candidates[0].any():  # every highlight pixel clipped: nothing the re-synthesis can be held to
        return candidates[0], float("nan")
    scored = [(explained_fraction(capture, est, obs, r, predicted=predicted), i) for i, r in enumerate(candidates)]
    explained, best = max(scored)
    return candidates[best], explained


def highlight_significance(capture: Capture, obs: Observation) -> float | None:
    """The observed highlight's peak over its camera noise: the largest specular over its standard deviation
    among the peak pixel and its 8 neighbours (mean over channels).

    The camera's noise is stated by the capture's ``sensor`` block or measured
    from its stack (:func:`~nearlight.estimator.noise.camera_noise`); the
    specular's variance is :func:`~nearlight.estimator.noise.specular_variance`'s.
    Pure noise separates into a positive floor (an amplitude, about 1.25
    deviations, whose largest near the brightest pixel reached 2.2–3.0 on
    the paper-v1 cylinder), which
    a method can fit with a confident lamp (``distant`` on the paper-v1
    cylinder explains 0.77 of it); a highlight stands tens to thousands of
    deviations above it.

    Returns
    -------
    float or None
        None when the capture says nothing of its noise (no sensor block,
        and fewer than 4 analyzer angles or a separated specular only); inf
        when a reading near the peak is clipped at the sensor's saturation
        (:func:`clipped`: a highlight bright enough to saturate is evident,
        and its separated specular is cut).
    """
    camera = camera_noise(capture, surface=obs.surface)
    if camera is None:
        return None
    i, j = obs.peak
    window = np.zeros(obs.mask.shape, bool)
    window[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2] = True
    window &= obs.located
    if (window & clipped(capture)).any():
        return float("inf")
    sd = np.sqrt(specular_variance(capture, obs.specular, camera, pixels=window))
    return float(np.max(np.mean(obs.specular[window] / sd, axis=-1)))


def _evident(capture: Capture, obs: Observation) -> Failure | None:
    z = highlight_significance(capture, obs)
    if z is not None and not z >= SIGNIFICANCE_MIN:
        return Failure("evident", f"no highlight above the camera noise: its peak is {z:.3g} noise deviations "
                                  f"(at least {SIGNIFICANCE_MIN:g} needed; noise alone reaches about 3): the capture "
                                  "does not determine the lamp")
    return None


def _explains(est: Estimate, explained: float) -> Failure | None:
    if not explained >= EXPLAINED_MIN:
        return Failure("explains", f"its re-synthesised specular explains {explained:.3g} of the observed "
                                   f"highlight (at least {EXPLAINED_MIN:g} needed): Ks {_vec(est.ks)}, "
                                   f"σ {est.sigma:.4g} do not make this highlight")
    return None


def ks_scaled_fraction(obs: Observation, region: np.ndarray, predicted: np.ndarray) -> float:
    """The share of the highlight's variation the re-synthesis's shape explains, its Ks rescaled per channel:
    ``1 − Σ(S − k·Ŝ)² / Σ(S − S̄)²`` over ``region``, ``k = Σ S Ŝ / Σ Ŝ²`` (Ŝ is linear in Ks), ``S̄`` the
    highlight's mean per channel. Only the lamp and σ are held to it; a flat re-synthesis (``distant`` on a
    plane) explains none of the variation, whatever its scale."""
    S, S_hat = obs.specular[region], predicted[region]
    k = np.nan_to_num(np.sum(S * S_hat, axis=0) / np.sum(S_hat**2, axis=0))
    return float(1.0 - np.sum((S - k * S_hat) ** 2) / np.sum((S - S.mean(axis=0)) ** 2))


def _ks_only(est: Estimate, obs: Observation, region: np.ndarray, predicted: np.ndarray,
             explained: float) -> Failure | None:
    """``explains`` broken by Ks alone: with Ks rescaled the lamp and σ explain the highlight
    (:func:`ks_scaled_fraction`), so only Ks is refused (rule ``ks-scale``)."""
    scaled = ks_scaled_fraction(obs, region, predicted)
    if not scaled >= EXPLAINED_MIN:
        return None
    return Failure("ks-scale", f"Ks {_vec(est.ks)} re-synthesises {explained:.3g} of the observed highlight; "
                               f"rescaled, the lamp and σ explain {scaled:.3g} of its variation: Ks refused, lamp "
                               "and σ kept")


def _located(est: Estimate, origin: np.ndarray, what: str = "the highlight") -> Failure | None:
    """``located``: the lamp's largest 1-σ uncertainty within :data:`LOCATED_MAX` × its distance from ``origin``."""
    if est.covariance is None:
        return None
    pos = est.covariance[:3, :3]
    if not np.all(np.isfinite(pos)):
        return Failure("located", "the lamp's covariance is not finite: the fit's information is singular")
    eig = np.linalg.eigvalsh(0.5 * (pos + pos.T))
    if eig[0] < -1e-9 * max(abs(eig[-1]), 1e-300):
        return Failure("located", f"the lamp's covariance is not positive semi-definite (eigenvalue {eig[0]:.3g} m²)")
    sd = float(np.sqrt(max(eig[-1], 0.0)))
    d = float(np.linalg.norm(est.lamp_position - origin))
    if sd > LOCATED_MAX * d:
        return Failure("located", f"the lamp's 1-σ uncertainty {sd:.4g} m exceeds its {d:.4g} m distance from "
                                  f"{what}: the data do not locate it")
    return None


def observation(capture: Capture, options: Mapping[str, Any]) -> Observation:
    """The observation the rules hold an estimate to: :func:`~nearlight.estimator.observation.observation_of` with the
    method's ``separation`` and ``threshold`` options when it has them."""
    return observation_of(capture, **{k: options[k] for k in ("separation", "threshold") if k in options})


def check(capture: Capture, est: Estimate, obs: Observation,
          options: Mapping[str, Any] | None = None) -> Failure | None:
    """The first rule (module docstring) the estimate breaks, or None when it passes them all.

    Parameters
    ----------
    capture : Capture
        The capture the estimate was made from.
    est : Estimate
    obs : Observation
        The capture's observation (:func:`observation`).
    options : mapping, optional
        The method's options (``t_max`` widens ``reach``).

    Returns
    -------
    Failure or None
    """
    options = options or {}
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for failed in (_finite(est), _roughness(est), _evident(capture, obs), _determined(est),
                       _reach(est, obs, options)):
            if failed is not None:
                return failed
        if len(est.found_lamps()) == 1:
            predicted = predicted_specular(est, obs)
            region, explained = own_highlight(capture, est, obs, predicted=predicted)
            if region.any():
                if (failed := _in_front(est, obs, region)) is not None:
                    return failed
                if (failed := _explains(est, explained)) is not None:
                    return _ks_only(est, obs, region, predicted, explained) or failed
        return _located(est, obs.P[obs.peak])


#: What ``diagnostics["undetermined"]`` names for a method that states the lamp alone (a calibration target's, or
#: the diffuse fall-off's): it reads no highlight and fits no Ks or σ, so the highlight's rules say nothing of it;
#: its lamp must be finite and located, and the method refuses, with its reason, what its own data do not support.
LAMP_ONLY = ("ks", "sigma")


def review(capture: Capture, est: Estimate, options: Mapping[str, Any]) -> Estimate:
    """``est`` held to the rules: refused (:meth:`~nearlight.estimator.Estimate.refused`) when it breaks one,
    and, for a one-lamp estimate, with :func:`~nearlight.estimator.highlights.several_highlights_warning`.

    Parameters
    ----------
    capture : Capture
    est : Estimate
        A method's result (``status`` ``"ok"``).
    options : mapping
        The method's options.

    Returns
    -------
    Estimate
        ``est`` itself, or its refused copy. A capture whose highlight the
        rules cannot observe (:func:`observation` raises) refuses the estimate
        (rule ``observable``): nothing holds the method's answer to the data.
    """
    if set(LAMP_ONLY) <= set(est.diagnostics.get("undetermined", ())):  # no highlight read, no Ks or σ: the lamp is all it states
        if not np.all(np.isfinite(est.lamp_position)):
            return est.refused("finite", f"lamp {_vec(est.lamp_position)} not finite")
        failed = _located(est, np.asarray(capture.camera.position, float), "the camera")
        return est if failed is None else est.refused(*failed)
    try:
        obs = observation(capture, options)
    except UserError as exc:
        return est.refused("observable", f"the rules cannot observe the capture's highlight: {exc}")
    if len(est.found_lamps()) == 1:  # every one-lamp method says so on several highlights
        est = est.with_warning(several_highlights_warning(obs))
    failed = check(capture, est, obs, options)
    if failed is None:
        return est
    if failed.rule == "ks-scale":  # the lamp and σ stand; Ks alone is not supported
        return est.without_ks(*failed)
    return est.refused(*failed)


def _vec(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in np.asarray(v, dtype=float).ravel()) + ")"
