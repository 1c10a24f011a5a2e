"""Several lamps: ``full``'s joint fit of K point lamps, one start per highlight (:mod:`~nearlight.estimator.highlights`).

The model is :class:`~nearlight.estimator.lampsum.SeveralLampModel`, K point
lamps over one surface, fitted by the short and final fits of
:mod:`~nearlight.estimator.pointlamp`; K = 1 is ``full``'s one-lamp fit
(:func:`~nearlight.estimator.full.one_lamp_fit`), which this method receives.

How many lamps: :func:`~nearlight.estimator.highlights.segment_highlights`
splits the smoothed specular image into highlights (local maxima that a dip
of at least :data:`~nearlight.estimator.highlights.HIGHLIGHT_DIP` of their
height separates from every brighter one); each highlight gives a start (the
paper's peak ray and t search on that highlight's pixels, then ``full``'s
multi-start along it). ``lamps="auto"`` fits K = 1 … min(highlights + 1,
:data:`MAX_FITTED_LAMPS`) and keeps the K of the smallest Bayesian
information criterion (:func:`lamp_count_evidence`).

Starts that do not need the K − 1 fit to be right: where two lamps' lobes
overlap, the count's segmentation sees one highlight and the one-lamp fit
lands between the lamps; a start carried from it, or fitted on a
half-lobe region, fails. So every K ≥ 2 also starts from lamps on the mirror
rays of the smoothed image's peaks under a far smaller dip
(:func:`ray_starts`) and from the K − 1 fit's brightest lamp split in two
(:func:`split_starts`); all starts are screened on ~:data:`SCREEN_PIXELS`
pixels (:func:`screened_starts`) and the best go on to every family.

How well this counts and places lamps, measured on analytic and rendered
two-lamp captures: docs/measurements/estimator-choices.md, "Several lamps".
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..capture import Capture
from ..errors import UserError
from ..physics.reflectance import LOBES, peak_shape, roughness_for_ts_sigma, ts_sigma
from .first_stage import RaySearch, fast_search, t_search_defaults
from .fitting import log_regression
from .highlights import HIGHLIGHT_FLOOR, Highlights, highlights_of, segment_highlights
from .joint_surface import fixed_surface_warning, joint_fit, split_refined, surface_fit_choice
from .lampsum import SeveralLampModel, lamp_phases
from .lobes import FAMILIES
from .observation import Observation
from .pixels import weighted_fit_pixels
from .pointlamp import PointLampModel, best_short_fit, final_fit, loss_floor, peak_ray_starts, short_fit
from .result import Estimate

#: Most lamps ``full`` fits (``lamps`` ≤ it; ``lamps="auto"`` tries K ≤ min(highlights + 1, it)); a
#: scene may hold more (:data:`nearlight.generator.scene.MAX_LAMPS`).
MAX_FITTED_LAMPS = 4
#: Closest two lamps of one fit, fraction of their mean distance from the observation's peak point:
#: nearer, they are one lamp (the benchmark's accuracy, 1 % of the distance, cannot tell them apart). On
#: noise-free one-lamp captures, a split start made two lamps 2e-5 of the distance apart whose χ² of
#: float32 rounding was 0.2–1 % below one lamp's, enough for BIC.
LAMP_SEPARATION = 0.01
#: Dips that separate the peaks of the K-lamp starts (:func:`ray_starts`): far smaller than the
#: count's, since a spurious peak only costs a start. Two equal lamps 25° apart over the board of
#: scenes/two_lamps.yaml dip by 22 % raw, under HIGHLIGHT_DIP smoothed; the absolute part, 2 % of
#: the brightest, is still ~3 standard deviations of the smoothed high-noise specular (see above).
START_DIP = 0.03
START_DIP_ABS = 0.02
#: Distances along each peak's mirror ray of the ray starts, × the camera–highlight distance.
START_DISTANCES = (0.3, 0.55, 1.0, 2.0)
#: Torrance–Sparrow σ of the ray starts (rad): narrow to broad lobes.
START_SIGMAS = (0.05, 0.1, 0.2)
#: Split starts: the brightest lamp of the K − 1 fit moved this fraction of its distance from the
#: peak's surface point either way, across that line (two directions), its σ × 1 and × 1/2.
SPLIT_OFFSETS = (0.1, 0.25)
#: Pixels (about) of the starts' screening fits, and how many screened starts join the others.
SCREEN_PIXELS = 500
SCREENED = 2


def lamp_count_evidence(chi2: dict[int, float], faintest: dict[int, float], closest: dict[int, float],
                        n_values: int, s2_floor: float = 0.0) -> dict[int, dict]:
    """Bayesian information criterion of each lamp count, from its weighted χ².

    ``BIC_K = χ²_K / s² + p_K ln n`` with ``p_K = 6K + 1`` parameters and
    ``n`` values (pixels × 3), ``s²`` the residual variance of the largest K
    (``χ²_K / (n − p_K)``, the least biased by a missing lamp). Dividing by
    ``s²`` makes ``χ²/s²`` a −2 log-likelihood whether or not the pixel
    weights are the camera's (a noise-free capture's are a floor), and with
    one ``s²`` for all K the differences compare like with like. BIC rather
    than AIC: its penalty (ln n ≈ 11 per parameter for ~20 000 pixels, 66 per
    lamp) grows with the data, so a lamp is added only when it explains far
    more than noise would, and it picks the true count with probability → 1
    as pixels grow; AIC's 2 per parameter adds lamps that absorb small model
    errors.

    A count is admissible only when each of its lamps is a highlight one
    could see: its own peak radiance at least :data:`HIGHLIGHT_FLOOR` of the
    brightest lamp's (the observation's specular threshold). On a noise-free
    one-lamp board, a second lamp of colour 3e-9 lowered the χ² of float32
    rounding by enough to pass BIC; no noise level is that small otherwise.
    And its lamps must be apart: no two closer than :data:`LAMP_SEPARATION`
    of their distance (two coincident lamps are one lamp with more freedom
    to fit float32 rounding).

    ``s²`` is at least ``s2_floor``: a capture that measures no camera noise
    (noise-free) has no noise scale, its ``s²`` is the model's own misfit,
    and any lamp that explains 0.12 % of that passes (6 parameters × ln n ≈
    66 against ``(n − p)`` × the relative drop). The caller's floor is the
    fit's own (one pixel weight, 1e-4 of the peak unweighted): the model is
    not trusted below it. Measured on the sensitivity study's noise-free
    renders where a faint satellite lamp (5–10 % of the brightness, 2–5 % of
    the distance away) had passed, the drop it brought was below 0.04 of
    the floor; on the noise-free two-lamp study (4°–30° apart) a true second
    lamp's was above 10⁴ of it.

    Parameters
    ----------
    chi2 : dict of int to float
        Weighted χ² of the best fit with K lamps.
    faintest : dict of int to float
        Per K, the faintest lamp's peak radiance over the brightest's.
    closest : dict of int to float
        Per K, the closest two lamps' separation over their distance (inf for one lamp).
    n_values : int
        Number of fitted values (pixels × 3 channels).

    Returns
    -------
    dict of int to dict
        Per K: ``chi2``, ``n_params``, ``bic``, ``delta_bic`` (to the smallest
        admissible), ``faintest``, ``closest`` and ``admissible``.
    """
    kmax = max(chi2)
    s2 = chi2[kmax] / max(n_values - (6 * kmax + 1), 1)
    s2 = max(s2, s2_floor) if max(s2, s2_floor) > 0 else 1.0
    bic = {k: c / s2 + (6 * k + 1) * np.log(n_values) for k, c in chi2.items()}
    admissible = {k: bool(faintest[k] >= HIGHLIGHT_FLOOR and closest[k] >= LAMP_SEPARATION) for k in chi2}
    best = min(b for k, b in bic.items() if admissible[k])
    return {k: {"chi2": chi2[k], "n_params": 6 * k + 1, "bic": float(bic[k]), "delta_bic": float(bic[k] - best),
                "faintest": float(faintest[k]), "closest": float(closest[k]), "admissible": admissible[k]}
            for k in sorted(chi2)}


def closest_pair(x: np.ndarray, point: np.ndarray) -> float:
    """The closest two lamps of ``x`` (K lamps): their separation over their mean distance from ``point``.

    Parameters
    ----------
    x : ndarray, shape (6K + 1,)
    point : ndarray, shape (3,)
        A surface point (m), e.g. the observation's peak pixel's.

    Returns
    -------
    float
        inf for one lamp.
    """
    lamps = [x[6 * i : 6 * i + 3] for i in range((len(x) - 1) // 6)]
    return min((float(np.linalg.norm(a - b) / np.mean([np.linalg.norm(a - point), np.linalg.norm(b - point)]))
                for i, a in enumerate(lamps) for b in lamps[i + 1 :]), default=np.inf)


def chosen_count(evidence: dict[int, dict]) -> int:
    """The admissible lamp count of least BIC (:func:`lamp_count_evidence`)."""
    return min((k for k, v in evidence.items() if v["admissible"]), key=lambda k: evidence[k]["bic"])



def _region_start(obs: Observation, region: np.ndarray, std: np.ndarray | None, *,
                  n_starts: int) -> np.ndarray | None:
    """A single-lamp start ``(x, y, z, c_R, c_G, c_B, σ)`` (Torrance–Sparrow) from one highlight's pixels.

    The paper's first stage on ``region`` (the peak ray from its brightest
    pixel, E_p(t) over its specular pixels, the regression for Ks and σ),
    then ``full``'s starts along that ray
    (:func:`~nearlight.estimator.pointlamp.peak_ray_starts`), each shortly fitted
    to the region's pixels (at most ~2000); the lowest cost wins.

    Parameters
    ----------
    obs : Observation
        Its ``specular`` is what the lamp is to explain (the capture's, or a residual).
    region : ndarray, shape (H, W), bool
        The highlight's pixels.
    std : ndarray, shape (H, W, 3), optional
        Pixel standard deviations (radiance); None: equal weights.

    Returns
    -------
    ndarray, shape (7,), or None
        None when the region holds no lobe (fewer than 10 positive pixels, or
        a regression slope that is not negative).
    """
    mask = region & obs.surface & np.all(obs.specular > 0, axis=-1)
    if mask.sum() < 10:
        return None
    lum = np.where(mask, obs.specular.mean(axis=-1), -np.inf)
    peak = np.unravel_index(int(np.argmax(lum)), lum.shape)
    sub = dataclasses.replace(obs, mask=mask, peak=(int(peak[0]), int(peak[1])))
    ray = RaySearch(sub)
    t_max, dt = t_search_defaults(sub, None, None)
    t = fast_search(ray.ep, t_max=t_max, dt=dt)["t"]
    X, Y = ray.xy(np.array([t]))
    try:
        ks, sigma, _ = log_regression(X[0], Y[0])
    except UserError:
        return None
    init = Estimate(method="paper-init", lamp_position=ray.lamp(t), ks=ks, sigma=sigma)
    rows = np.flatnonzero(mask.ravel())[:: max(1, int(mask.sum()) // 2000)]
    model = PointLampModel(obs.P.reshape(-1, 3)[rows], obs.N.reshape(-1, 3)[rows], obs.camera_position,
                           obs.specular.reshape(-1, 3)[rows], std=None if std is None else std.reshape(-1, 3)[rows])
    return best_short_fit(model, peak_ray_starts(init, sub, n_starts=n_starts), obs.scale)[0]["x"]


def _perpendiculars(d: np.ndarray) -> np.ndarray:
    """Two unit vectors perpendicular to ``d`` and to each other, shape (2, 3)."""
    d = d / np.linalg.norm(d)
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    u = np.cross(d, a)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(d, u)])


def ray_starts(obs: Observation, k: int) -> list[np.ndarray]:
    """K-lamp Torrance–Sparrow starts, lamp i on the mirror ray of start peak i (colours 1: solve them after).

    The peaks are the smoothed specular's local maxima that a dip of
    :data:`START_DIP` separates (:func:`segment_highlights`), brightest first;
    the K brightest get a lamp each, all at one distance of
    :data:`START_DISTANCES` and one σ of :data:`START_SIGMAS`. Unlike a fit on
    each highlight's region, this needs no lobe's worth of pixels per
    highlight: a peak's ray passes near its lamp however much of the lobe
    the other lamp's overlaps.

    Parameters
    ----------
    obs : Observation
    k : int
        Number of lamps.

    Returns
    -------
    list of ndarray, shape (6k + 1,)
        Empty when fewer than ``k`` peaks.
    """
    peaks = segment_highlights(obs.specular, obs.located, dip=START_DIP, dip_abs=START_DIP_ABS).peaks[:k]
    if len(peaks) < k:
        return []
    rays = [RaySearch(dataclasses.replace(obs, peak=p)) for p in peaks]
    return [np.concatenate([*(np.r_[ray.lamp(t * obs.scale), np.ones(3)] for ray in rays), [sigma]])
            for t in START_DISTANCES for sigma in START_SIGMAS]


def split_starts(obs: Observation, x: np.ndarray) -> list[np.ndarray]:
    """(K + 1)-lamp starts from a K-lamp fit ``x`` (Torrance–Sparrow): its brightest lamp split in two.

    Two lamps whose highlights merge are fitted by one lamp between them
    with a broader lobe; the pair is put back either side of it (see
    :data:`SPLIT_OFFSETS`), colours halved.

    Parameters
    ----------
    obs : Observation
        Its peak pixel's surface point is where the distance is measured from.
    x : ndarray, shape (6K + 1,)

    Returns
    -------
    list of ndarray, shape (6K + 7,)
    """
    k = (len(x) - 1) // 6
    j = max(range(k), key=lambda i: float(np.mean(x[6 * i + 3 : 6 * i + 6])))
    lamp, colour = x[6 * j : 6 * j + 3], x[6 * j + 3 : 6 * j + 6] / 2
    arm = lamp - obs.P[obs.peak]
    others = [x[6 * i : 6 * i + 6] for i in range(k) if i != j]
    offsets = [f * np.linalg.norm(arm) * u for u in _perpendiculars(arm) for f in SPLIT_OFFSETS]
    return [np.concatenate([*others, lamp + d, colour, lamp - d, colour, [x[-1] * r]])
            for d in offsets for r in (1.0, 0.5)]


def screened_starts(model: SeveralLampModel, starts: list[np.ndarray], scale: float) -> list[np.ndarray]:
    """The :data:`SCREENED` best of ``starts`` after colours by NNLS and a short fit on ~:data:`SCREEN_PIXELS` pixels.

    Parameters
    ----------
    model : SeveralLampModel
        Torrance–Sparrow, K lamps, the fitted pixels.
    starts : list of ndarray, shape (6K + 1,)
    scale : float
        Camera–highlight distance (m).

    Returns
    -------
    list of ndarray, shape (6K + 1,)
        Fitted on the subset, lowest χ² first.
    """
    if not starts:
        return []
    small = model.subset(slice(None, None, max(1, len(model.lamp.P) // SCREEN_PIXELS)))
    solved = sorted((small.linear_colours(x) for x in starts), key=small.chi2)[: 2 * SCREENED]
    fitted = [short_fit(small, x, scale)["x"] for x in solved]
    return sorted(fitted, key=small.chi2)[:SCREENED]


def _convert_roughness(x: np.ndarray, src: str, dst: str) -> np.ndarray:
    """``x`` with its roughness moved from family ``src`` to the ``dst`` of the same small-angle σ."""
    out = x.copy()
    out[-1] = roughness_for_ts_sigma(dst, ts_sigma(src, x[-1]))
    return out



def several_estimate(capture: Capture, one: Estimate, obs: Observation, *, lamps: int | str, lobe: str, noise: str,
                     loss: str, f_scale: float | None, max_pixels: int, saturation: float | None, n_starts: int,
                     separation: str, surface: str = "fixed") -> Estimate:
    """Method ``full`` with ``lamps`` = K > 1 or ``"auto"``: a joint fit of K lamps, or the K of least BIC.

    K = 1 is ``one``, ``full``'s one-lamp fit (``lamps=1``), bit for bit. Each further
    lamp starts at the next highlight of :func:`segment_highlights` (brightest
    first; :func:`_region_start`), or, past the last highlight, at the
    brightest highlight of the previous fit's positive residual (no such
    highlight: K stops there); the K lamps start from the previous K − 1 and
    the new one, from every highlight's own start, from :func:`ray_starts`
    and from :func:`split_starts`; the :data:`SCREENED` best of these
    (:func:`screened_starts`) are refitted jointly (colours re-solved by
    NNLS) in each lobe family of ``lobe`` on the short fits' pixel subset,
    and the family of least χ² there gets the final robust fit on every
    pixel (:func:`~nearlight.estimator.fitting.robust_fit`, ``full``'s loss
    and weights). With the lamps' filter in the capture (``rig.lamp_filter``)
    and a separation that measures a phase, the K ≥ 2 fits after the
    screening weigh each lamp by its polarization angle (:func:`lamp_phases`,
    :class:`SeveralLampModel`; ``stages["full"]["lamp_phases"]``).

    Parameters
    ----------
    capture : Capture
    one : Estimate
        ``full``'s one-lamp estimate of the capture with the same options
        (:func:`~nearlight.estimator.full.one_lamp_fit`).
    obs : Observation
        The observation it fitted (whole mask).
    lamps : int or "auto"
        K, or ``"auto"``: K = 1 … min(highlights + 1, :data:`MAX_FITTED_LAMPS`),
        chosen by :func:`lamp_count_evidence`.
    lobe, noise, loss, f_scale, max_pixels, saturation, n_starts, separation, surface
        As :func:`~nearlight.estimator.full.full_estimate`'s. With the surface refined
        (:func:`~nearlight.estimator.joint_surface.surface_fit_choice`), the chosen K's fit is refined with the
        one surface all its highlights lie on (:func:`~nearlight.estimator.joint_surface.joint_fit`); the fits
        that chose K took it as given.

    Returns
    -------
    Estimate
        The brightest lamp (largest mean colour) in ``lamp_position``, ``ks``
        (its colour times the lobe's peak shape), the shared ``sigma`` and the
        ``(x, y, z, σ)`` covariance of that lamp; ``stages["full"]["lamps"]``
        every lamp, brightest first, ``{"position": [x, y, z], "colour": [r, g, b]}``
        (colour: the fitted family's, as ``stages["full"]["bsdf"]``), and
        ``stages["full"]["lamps_evidence"]`` per K tried (``lamps="auto"``).
    """
    clock = time.perf_counter()
    found = highlights_of(obs)
    fit_px = weighted_fit_pixels(capture, obs, noise=noise, max_pixels=int(max_pixels), saturation=saturation)
    use = fit_px.use
    obs = dataclasses.replace(obs, specular=fit_px.specular)  # the dark fitted pixels measured from their readings
    std_img = None if fit_px.camera is None else np.sqrt(fit_px.variance(capture))
    std = None if std_img is None else std_img[use]
    base = PointLampModel(obs.P[use], obs.N[use], obs.camera_position, obs.specular[use], std=std)
    phases = lamp_phases(capture, use, separation, fit_px)
    k_max = min(len(found.peaks) + 1, MAX_FITTED_LAMPS) if lamps == "auto" else int(lamps)
    families = FAMILIES if lobe == "auto" else tuple(v.strip() for v in lobe.split("+"))
    stride = max(1, len(base.P) // 2000)
    floor = loss_floor(obs.specular[use], std)

    s1 = one.stages["full"]
    x1 = np.concatenate([s1["lamp_position"], s1["ks"], [s1["roughness"]]])
    fits = {1: {"x": x1, "lobe": s1["lobe"], "chi2": s1["chi2"]}}  # K = 1 is returned as ``one`` itself
    regional: dict[int, np.ndarray | None] = {}

    def highlight_start(i: int) -> np.ndarray | None:
        if i not in regional:
            regional[i] = _region_start(obs, found.labels == i + 1, std_img, n_starts=int(n_starts))
        return regional[i]

    def residual_start(x: np.ndarray, family: str) -> np.ndarray | None:
        """A start at the brightest highlight of what the lamps of ``x`` (in ``family``) leave unexplained."""
        unweighted = SeveralLampModel(PointLampModel(obs.P[use], obs.N[use], obs.camera_position, obs.specular[use],
                                                     lobe=family), (len(x) - 1) // 6, phases)
        left = np.zeros_like(obs.specular)
        left[use] = -unweighted.residuals(x).reshape(-1, 3)
        return _region_start(dataclasses.replace(obs, specular=left), segment_highlights(left, use).labels == 1,
                             std_img, n_starts=int(n_starts))

    # Torrance–Sparrow starts are carried from two fits of k − 1 lamps: the chosen family's, and the
    # Torrance–Sparrow short fit's (when one lamp too few is fitted, the chosen family can be one whose
    # lobe widened to cover the missing lamp's highlight, and its residual then shows no lobe)
    ts = {1: (highlight_start(0), "torrance_sparrow")} if "torrance_sparrow" in families else {}
    for k in range(2, k_max + 1):
        carriers = [(fits[k - 1]["x"], fits[k - 1]["lobe"])] + ([ts[k - 1]] if k - 1 in ts else [])
        candidates = []
        for x, family in carriers:
            if x is None:
                continue
            new = highlight_start(k - 1) if k <= len(found.peaks) else residual_start(x, family)
            if new is not None:
                carried = _convert_roughness(x, family, "torrance_sparrow")
                candidates.append(np.concatenate([carried[:-1], new[:6], carried[-1:]]))
        own = [highlight_start(i) for i in range(k)] if k <= len(found.peaks) else []
        if own and all(o is not None for o in own):  # every highlight's own start
            candidates.append(np.concatenate([*(o[:6] for o in own), own[0][-1:]]))
        if not candidates:  # no highlight nor residual lobe left for another lamp
            break
        # and starts that need no right K − 1 fit nor a lobe per highlight: lamps on the start peaks' rays,
        # and the K − 1 fit's brightest lamp split in two (highlights merged into one); the best few of all
        # go on to every family
        previous = _convert_roughness(fits[k - 1]["x"], fits[k - 1]["lobe"], "torrance_sparrow")
        # screened without the lamps' polarization angles: weighted by them, most starts of the 20°-apart equal
        # lamps (two-lamp study, one merged highlight) ran to lamps on the board with the broadest lobe; the
        # plain sum's basin is the weighted one's (its minimum is off by millimetres), the weighted fits follow
        candidates = screened_starts(SeveralLampModel(base, k),
                                     candidates + ray_starts(obs, k) + split_starts(obs, previous), obs.scale)
        shorts = {}
        for fam in families:
            m = SeveralLampModel(base.with_lobe(fam), k, phases).subset(slice(None, None, stride))
            for x0 in candidates:
                xf = short_fit(m, _convert_roughness(x0, "torrance_sparrow", fam), obs.scale)["x"]
                c = m.chi2(xf)
                if fam not in shorts or c < shorts[fam][1]:
                    shorts[fam] = (xf, c)
        if "torrance_sparrow" in shorts:
            ts[k] = (shorts["torrance_sparrow"][0], "torrance_sparrow")
        fam = min(shorts, key=lambda f: shorts[f][1])
        model = SeveralLampModel(base.with_lobe(fam), k, phases)
        xs = shorts[fam][0]
        fit = final_fit(model, xs, obs.scale, loss=loss, f_scale=f_scale, floor=floor)
        fits[k] = {**fit, "lobe": fam, "chi2": model.chi2(fit["x"])}
    if lamps != "auto" and int(lamps) not in fits:
        raise UserError(f"{capture.name}: option lamps={lamps}: found starts for only {max(fits)} lamps "
                        f"({len(found.peaks)} separate highlights, and no lobe left in the residual)")
    peaks = SeveralLampModel(PointLampModel(obs.P[use], obs.N[use], obs.camera_position, obs.specular[use]), 1)
    faintest = {}
    for k, fit in fits.items():
        peaks_k = SeveralLampModel(peaks.lamp.with_lobe(fit["lobe"]), k).lamp_peaks(fit["x"])
        faintest[k] = float(peaks_k.min() / peaks_k.max()) if peaks_k.max() > 0 else 0.0
    closest = {k: closest_pair(fit["x"], obs.P[obs.peak]) for k, fit in fits.items()}
    evidence = lamp_count_evidence({k: v["chi2"] for k, v in fits.items()}, faintest, closest, 3 * int(use.sum()),
                                    s2_floor=floor**2)
    k = chosen_count(evidence) if lamps == "auto" else int(lamps)
    if lamps == "auto" and k == 1:
        return _with_count(one, evidence, found)
    fit, family = fits[k], fits[k]["lobe"]
    joint, why = surface_fit_choice(obs, surface)
    refined = None
    if joint:
        n_params = len(fit["x"])
        fit = joint_fit(SeveralLampModel(base.with_lobe(family), k, phases), obs.geometry.parameters, fit["x"],
                        obs.scale, loss=loss, f_scale=f_scale, floor=floor,
                        scale=float(np.sqrt(fit["chi2"] / max(3 * int(use.sum()) - n_params, 1))))
        fit, refined = split_refined(obs, fit, n_params)
    x, cov = fit["x"], fit["cov"]
    order = sorted(range(k), key=lambda i: -float(np.mean(x[6 * i + 3 : 6 * i + 6])))
    brightest = order[0]
    per_roughness = ts_sigma(family, 1.0)
    idx = [6 * brightest, 6 * brightest + 1, 6 * brightest + 2, 6 * k]
    scale = np.array([1.0, 1.0, 1.0, per_roughness])
    cov4 = cov[np.ix_(idx, idx)] * scale[:, None] * scale[None, :]
    spec = LOBES[family]
    colour = x[6 * brightest + 3 : 6 * brightest + 6]
    stage = {
        "lamp_position": x[6 * brightest : 6 * brightest + 3], "ks": colour, "roughness": x[-1],
        "lamps": [{"position": x[6 * i : 6 * i + 3].tolist(), "colour": x[6 * i + 3 : 6 * i + 6].tolist()}
                  for i in order],
        "n_lamps": k, "lamps_option": lamps,
        "covariance_params": [f"{p}{j}" for j in range(k) for p in ("x", "y", "z", "colour_r", "colour_g", "colour_b")]
        + ["roughness"],
        **{key: fit[key] for key in ("f_scale", "cost", "nfev", "status", "rms", "chi2")},
        "lobe": family, "bsdf": {"model": family, spec.colour_key: colour, spec.roughness_key: x[-1]},
        "lobes_fitted": list(families), "noise": None if fit_px.camera is None else fit_px.camera._asdict(),
        "loss": loss, "n_pixels": int(use.sum()), "n_dark_measured": int(fit_px.measured.sum()),
        "lamp_phases": phases is not None,
        "surface_fit": "joint" if joint else "fixed", "surface_fit_reason": why, "surface_parameters": refined,
    }
    if lamps == "auto":
        stage["lamps_evidence"] = evidence
    perm = [j for i in order for j in range(6 * i, 6 * i + 6)] + [6 * k]  # rows in the lamps' brightness order
    stage["covariance"] = cov[np.ix_(perm, perm)]
    return Estimate(
        method="full",
        lamp_position=stage["lamp_position"],
        lamp_positions=np.array([x[6 * i : 6 * i + 3] for i in order]),  # scored by evaluation.scoring.matching
        ks=colour * peak_shape(family, x[-1]),
        sigma=per_roughness * x[-1],
        covariance=cov4,
        stages={"init": one.stages["init"], "full": stage},
        diagnostics=_diagnostics(one, found),
        timings={**one.timings, "several": time.perf_counter() - clock},
    ).with_warning(fixed_surface_warning(obs, joint))


def _diagnostics(one: Estimate, found: Highlights) -> dict:
    """The one-lamp fit's diagnostics without its warnings (they are about its fit; this fit counts the
    highlights), and the highlights."""
    out = {k: v for k, v in one.diagnostics.items() if k != "warnings"}
    out["highlights"] = {"peak_pixels": [list(p) for p in found.peaks], "heights": found.heights.tolist()}
    return out


def _with_count(one: Estimate, evidence: dict, found: Highlights) -> Estimate:
    """The one-lamp estimate of ``lamps=auto`` when one lamp wins, with the evidence and its lamp list."""
    s = one.stages["full"]
    stage = {**s, "n_lamps": 1, "lamps_option": "auto", "lamps_evidence": evidence,
             "lamps": [{"position": np.asarray(s["lamp_position"]).tolist(), "colour": np.asarray(s["ks"]).tolist()}]}
    kept = {"warnings": one.diagnostics["warnings"]} if one.diagnostics.get("warnings") else {}  # its own fit's
    return dataclasses.replace(one, stages={**one.stages, "full": stage}, diagnostics={**_diagnostics(one, found), **kept})
