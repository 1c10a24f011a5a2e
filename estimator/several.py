"""Several lamps: ``full``'s joint fit of K point lamps, one start per highlight (:mod:`~nearlight.estimator.highlights`).

Radiance is linear in the lamps (docs/physics.md, "lamps add"), so the
specular image of K lamps over one surface is the sum of K single-lamp
images: ``I_s = Σₖ colourₖ · F(lₖ; a) / rₖ²``, each lamp its own position
and colour (the colour absorbs its intensity and Ks), one roughness ``a`` and
one lobe family (the surface is one). :class:`SeveralLampModel` composes
:class:`~nearlight.estimator.full.PointLampModel` (its residuals and analytic
Jacobian, one per lamp) rather than restating its formulas.

How many lamps: :func:`segment_highlights` splits the smoothed specular
image into highlights (local maxima that a dip of at least
:data:`HIGHLIGHT_DIP` of their height separates from every brighter one);
each highlight gives a start (the paper's peak ray and t search on that
highlight's pixels, then ``full``'s multi-start along it). ``lamps="auto"``
fits K = 1 … min(highlights + 1, :data:`MAX_LAMPS`) and keeps the K of the
smallest Bayesian information criterion (:func:`lamp_count_evidence`).

Starts that do not need the K − 1 fit to be right: where two lamps' lobes
overlap, the count's segmentation sees one highlight and the one-lamp fit
lands between the lamps; a start carried from it, or fitted on a
half-lobe region, fails. So every K ≥ 2 also starts from lamps on the mirror
rays of the smoothed image's peaks under a far smaller dip
(:func:`ray_starts`) and from the K − 1 fit's brightest lamp split in two
(:func:`split_starts`); all starts are screened on ~:data:`SCREEN_PIXELS`
pixels (:func:`screened_starts`) and the best go on to every family.

The sum assumes the separated specular of several lamps is the sum of theirs:
true where their highlights do not overlap or their light is polarized alike
(docs/capture-format.md, "Several lamps": Stokes vectors add, so where
differently polarized highlights overlap ``Imax − Imin`` is less than the sum).

Measured (``benchmarks/bench_several_lamps.py``, 160 × 120 analytic captures,
5 seeds per noise level): the count was right on every capture, two equal
lamps 30° apart (and a second lamp at a quarter of the intensity) and one
lamp on a board, a near board and a sphere, noise-free, low and high noise;
two-lamp errors (% of each lamp's distance from its highlight point) median
0.12 % / worst 0.15 % at low noise, 0.26 % / 0.50 % at high, 1e-6 % noise-free;
the Mitsuba render of scenes/two_lamps.yaml, 0.19 % each. The ray and split
starts left every one of those numbers as it was and found both lamps where
the highlights merge: analytic, two equal lamps 25° and 16° apart noise-free
(one lamp before; tests/test_estimator_several_lamps.py), and the cached
Mitsuba renders of ``sweeps/two_lamps.yaml``'s equal lamps at 16° and 25°
(noise-free, low and high noise, 2 seeds), 10 of 10 (4 of 10 before), errors
0.11–0.25 % at 16°, 0.77–1.12 % at 25° (the one run found before: 1.04–1.12 %);
over all 8 separations of equal lamps, 39 of 40 (33 before; the miss, 4° at
high noise seed 0, as before: its residual shows no lobe, so K stops at 1),
and 12° noise-free 0.26 % against 2.11 % before.
Run time: the bench's 75 fits 161 s against 242 s before (the first stage
no longer runs twice, and only the two best screened starts go on to the four
families); one row slower, the noise-free near board (5.7 against 1.6 s: its
two-lamp fit of two coincident lamps, refused by :data:`LAMP_SEPARATION`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import nnls

from ..capture import Capture
from ..errors import UserError
from ..physics.polarization import specular_aolp
from ..physics.reflectance import LOBES, peak_shape, roughness_for_ts_sigma, ts_sigma
from .fitting import log_regression, robust_fit
from .highlights import HIGHLIGHT_FLOOR, Highlights, highlights_of, segment_highlights
from .lobes import FAMILIES
from .observation import Observation
from .paper import RaySearch, fast_search, t_search_defaults
from .pixels import FitPixels, weighted_fit_pixels
from .separation import specular_phase
from .result import Estimate

#: Most lamps ``lamps="auto"`` tries (the issue's bound: K ≤ min(highlights + 1, 4)).
MAX_LAMPS = 4
#: Closest two lamps of one fit, fraction of their mean distance from the observation's peak point:
#: nearer, they are one lamp (the issue's accuracy, 1 % of the distance, cannot tell them apart). On
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
#: Two short fits whose costs are this close (relative) found the same minimum (:func:`best_short_fit`):
#: well above the spread of one minimum's cost from different starts (≤ 2e-9 relative over the
#: sensitivity study's 240 one-lamp captures) and far below the next minimum's (> 1e-3 there).
SAME_MINIMUM = 1e-6



class LampPhases(NamedTuple):
    """What weighs each lamp of a several-lamp model by its polarization angle (:class:`SeveralLampModel`).

    Attributes
    ----------
    measured : ndarray, shape (n,)
        β̂ per pixel, radians: the phase the separation measured the specular
        along (:func:`~nearlight.estimator.separation.specular_phase`).
    camera_up : ndarray, shape (3,)
        The camera's up vector (``camera.to_world``'s second column).
    axis, aim : ndarray, shape (3,)
        Every lamp's filter (``rig.lamp_filter``).
    """

    measured: np.ndarray
    camera_up: np.ndarray
    axis: np.ndarray
    aim: np.ndarray

    def subset(self, rows: slice | np.ndarray) -> LampPhases:
        return self._replace(measured=np.ascontiguousarray(self.measured[rows]))


def lamp_phases(capture: Capture, use: np.ndarray, separation: str,
                fit_px: FitPixels | None = None) -> LampPhases | None:
    """:class:`LampPhases` of the fitted pixels ``use``, or None where the capture cannot give them.

    Needs the lamps' filter (``rig.lamp_filter``), the camera's orientation
    (``camera.to_world``) and a separation that measures a phase (``fit``,
    ``projected``) of an analyzer stack. The dark pixels measured from their
    readings (``fit_px.measured``, :func:`~nearlight.estimator.pixels.weighted_fit_pixels`) take the phase
    they were measured along.
    """
    filt, to_world = capture.rig.lamp_filter, capture.camera.to_world
    phase = None if filt is None or to_world is None else specular_phase(capture, method=separation)
    if phase is None:
        return None
    if fit_px is not None:
        phase[fit_px.measured] = fit_px.measured_phase
    return LampPhases(np.ascontiguousarray(phase[use]), np.asarray(to_world, float)[:3, 1],
                      np.asarray(filt.axis, float), np.asarray(filt.aim, float))


class SeveralLampModel:
    """Specular radiance of K point lamps over one surface, with its Jacobian.

    Parameters ``x = (l₁, c₁, …, l_K, c_K, a)``, shape ``(6K + 1,)``: each
    lamp's position (m) and colour (its intensity times Ks per channel), then
    the lobe family's roughness, shared. Residuals are
    ``(Σₖ w_k model_k − observed) / std``, flattened pixel-major ``[n · 3]``,
    ``model_k`` :class:`~nearlight.estimator.full.PointLampModel`'s for lamp
    k and ``w_k = 1``, or, with ``phases``, ``w_k = cos 2(β_k − β̂)``: the
    separated specular of lamps polarized at different angles ``β_k``
    (:func:`~nearlight.physics.polarization.specular_aolp`) is the sum of
    their polarized parts measured along β̂, not the sum of their radiances.
    Measured on the two-lamp study's 30°-apart capture (low noise), where the
    two lamps' β differ by up to 22° over their highlights: the true lamps'
    χ² 81 372 (plain sum) → 26 679 (weighted) for 26 826 values, and the
    noise-free separation matched to 1.3e-5 of the peak, against 2.7 %.

    Parameters
    ----------
    lamp : PointLampModel
        The pixels, observed specular, lobe family and weights.
    k : int
        Number of lamps.
    phases : LampPhases, optional
        The pixels' β̂ and the lamps' filter; None: ``w_k = 1``.
    """

    def __init__(self, lamp: Any, k: int, phases: LampPhases | None = None):
        self.lamp, self.k, self.phases = lamp, k, phases
        # the same model with nothing observed: its residuals are one lamp's weighted radiance
        self._one = type(lamp)(lamp.P, lamp.N, lamp.camera, np.zeros_like(lamp.observed), lobe=lamp.lobe, std=lamp.std)
        self._observed = self._one._weigh(lamp.observed).ravel()
        self._phases_at: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def n_params(self) -> int:
        return 6 * self.k + 1

    def subset(self, rows: slice | np.ndarray) -> SeveralLampModel:
        """The same model on some of its pixels."""
        return SeveralLampModel(self.lamp.subset(rows), self.k, None if self.phases is None else self.phases.subset(rows))

    def with_lobe(self, lobe: str) -> SeveralLampModel:
        """The same pixels and weights with another lobe family."""
        return SeveralLampModel(self.lamp.with_lobe(lobe), self.k, self.phases)

    def lamp_params(self, x: np.ndarray, i: int) -> np.ndarray:
        """Lamp ``i``'s single-lamp parameters ``(x, y, z, c_R, c_G, c_B, a)``, shape (7,)."""
        return np.concatenate([x[6 * i : 6 * i + 6], x[-1:]])

    def _beta(self, position: np.ndarray) -> np.ndarray:
        ph = self.phases
        return specular_aolp(self.lamp.P, self.lamp.camera, ph.camera_up, position, ph.axis, ph.aim)

    def _phase_at(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """β and ``w = cos 2(β − β̂)`` of a lamp at ``position``, shape (n,) each, kept for the solver's
        last few points (the residuals, the Jacobian and the solved colours at one point share them)."""
        key = np.asarray(position, float).tobytes()
        if key not in self._phases_at:
            if len(self._phases_at) > 4 * self.k:
                self._phases_at.clear()
            beta = self._beta(position)
            self._phases_at[key] = (beta, np.cos(2.0 * (beta - self.phases.measured)))
        return self._phases_at[key]

    def weight(self, position: np.ndarray) -> np.ndarray:
        """``w = cos 2(β − β̂)`` of a lamp at ``position``, shape (n,) (ones without ``phases``)."""
        if self.phases is None:
            return np.ones(len(self.lamp.P))
        return self._phase_at(position)[1]

    def _weight_gradient(self, position: np.ndarray) -> np.ndarray:
        """``∂w/∂l``, shape (n, 3): central differences of β (steps 1e-6 of the lamp's distance)."""
        beta = self._phase_at(position)[0]
        step = 1e-6 * float(np.linalg.norm(position - self.lamp.P[0]))
        out = np.empty((len(beta), 3))
        for j in range(3):
            e = np.zeros(3)
            e[j] = step
            d = self._beta(position + e) - self._beta(position - e)
            d = (d + np.pi / 2) % np.pi - np.pi / 2  # β is an axis: modulo π
            out[:, j] = d / (2 * step)
        return -2.0 * np.sin(2.0 * (beta - self.phases.measured))[:, None] * out

    def residuals(self, x: np.ndarray) -> np.ndarray:
        if self.phases is None:
            return sum(self._one.residuals(self.lamp_params(x, i)) for i in range(self.k)) - self._observed
        return sum((self._one.residuals(self.lamp_params(x, i)).reshape(-1, 3)
                    * self.weight(x[6 * i : 6 * i + 3])[:, None]).ravel() for i in range(self.k)) - self._observed

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Analytic ``∂ residuals / ∂ x``, shape ``(n · 3, 6K + 1)``: each lamp's block, roughness columns summed.

        With ``phases``, lamp k's block is ``w_k J_k`` plus, in its position
        columns, its weighted radiance times ``∂w_k/∂l_k``.
        """
        J = np.zeros((len(self._observed), self.n_params))
        for i in range(self.k):
            p = self.lamp_params(x, i)
            Ji = self._one.jacobian(p)
            if self.phases is not None:
                Ji = Ji * np.repeat(self.weight(p[:3]), 3)[:, None]
                radiance = self._one.residuals(p).reshape(-1, 3)
                Ji[:, :3] += (radiance[:, :, None] * self._weight_gradient(p[:3])[:, None, :]).reshape(-1, 3)
            J[:, 6 * i : 6 * i + 6] = Ji[:, :6]
            J[:, -1] += Ji[:, 6]
        return J

    def linear_colours(self, x: np.ndarray) -> np.ndarray:
        """``x`` with the non-negative least-squares colours for its lamps and roughness (per channel, NNLS)."""
        ones = np.ones(3)
        D = np.stack([self._one.residuals(np.concatenate([x[6 * i : 6 * i + 3], ones, x[-1:]])).reshape(-1, 3)
                      * self.weight(x[6 * i : 6 * i + 3])[:, None]
                      for i in range(self.k)], axis=-1)  # (n, 3, K): weighted radiance per unit colour
        obs = self._observed.reshape(-1, 3)
        out = x.copy()
        for m in range(3):
            colour, _ = nnls(D[:, m, :], obs[:, m])
            out[[6 * i + 3 + m for i in range(self.k)]] = colour
        return out

    def lamp_peaks(self, x: np.ndarray) -> np.ndarray:
        """Each lamp's largest radiance over the pixels (weighted, if the model is), mean over channels, shape (K,)."""
        return np.array([np.max(self._one.residuals(self.lamp_params(x, i)).reshape(-1, 3).mean(axis=-1))
                         for i in range(self.k)])

    def chi2(self, x: np.ndarray) -> float:
        """Sum of squared (weighted) residuals at ``x``."""
        return float(np.sum(np.square(self.residuals(x))))


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


def _region_start(obs: Observation, region: np.ndarray, std: np.ndarray | None, *, n_starts: int,
                  starts: Any) -> np.ndarray | None:
    """A single-lamp start ``(x, y, z, c_R, c_G, c_B, σ)`` (Torrance–Sparrow) from one highlight's pixels.

    The paper's first stage on ``region`` (the peak ray from its brightest
    pixel, E_p(t) over its specular pixels, the regression for Ks and σ),
    then ``full``'s starts along that ray (``starts``:
    :func:`~nearlight.estimator.full.peak_ray_starts`), each shortly fitted to the
    region's pixels (at most ~2000); the lowest cost wins.

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
    from .full import PointLampModel

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
    return best_short_fit(model, starts(init, sub, n_starts=n_starts), obs.scale)[0]["x"]


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
    colours' columns projected out). Measured against the plain fit of
    all 6K + 1 parameters from the same starts (640×480 analytic board and
    sphere, noise-free and noisy): every one of the seven one-lamp starts
    reached the optimum, where the plain fit left three or four of them
    far off after its 30 evaluations, in about half the evaluations.
    Budget: 30 evaluations for one lamp, 100 for several (a two-lamp start
    from a dim lamp's residual was still 10⁹ times the optimum's χ² after
    30 of the plain fit, and another family's, stuck nearer, won the choice).

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


def best_short_fit(model: Any, starts: Iterable[np.ndarray], scale: float) -> tuple[dict, int]:
    """The lowest-cost :func:`short_fit` over ``starts``, tried in order until two reach the same lowest cost.

    A multi-start search that stops once its best minimum has been found
    twice (costs within :data:`SAME_MINIMUM` of each other): a second start
    landing on it says that its basin is the wide one the starts were spread
    to find, and the remaining starts are there for when the first ones
    disagree. With ``full``'s starts tried middle distance first
    (:func:`~nearlight.estimator.full.peak_ray_starts`) it stops after two
    on nearly every capture: over the 240 one-lamp captures of the
    sensitivity study, every start fitted (at 953a9fa), the first stage's
    start reached the best of all seven on 236, each of the three middle
    distances on all 240, the nearest (0.1 ×) on 226.

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


def several_estimate(capture: Capture, *, lamps: int | str, lobe: str, noise: str, loss: str,
                     f_scale: float | None, max_pixels: int, saturation: float | None, n_starts: int,
                     separation: str, **init_options) -> Estimate:
    """Method ``full`` with ``lamps`` = K > 1 or ``"auto"``: a joint fit of K lamps, or the K of least BIC.

    K = 1 is ``full``'s one-lamp fit (``lamps=1``), bit for bit. Each further
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
    lamps : int or "auto"
        K, or ``"auto"``: K = 1 … min(highlights + 1, :data:`MAX_LAMPS`),
        chosen by :func:`lamp_count_evidence`.
    lobe, noise, loss, f_scale, max_pixels, saturation, n_starts, separation, **init_options
        As :func:`~nearlight.estimator.full.full_estimate`'s.

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
    from .full import PointLampModel, one_lamp_fit, peak_ray_starts  # full dispatches here: import at call time

    one, obs = one_lamp_fit(capture, lobe=lobe, noise=noise, loss=loss, f_scale=f_scale, max_pixels=max_pixels,
                            saturation=saturation, n_starts=n_starts, separation=separation, **init_options)
    clock = time.perf_counter()
    found = highlights_of(obs)
    fit_px = weighted_fit_pixels(capture, obs, noise=noise, max_pixels=int(max_pixels), saturation=saturation)
    use = fit_px.use
    obs = dataclasses.replace(obs, specular=fit_px.specular)  # the dark fitted pixels measured from their readings
    std_img = None if fit_px.camera is None else np.sqrt(fit_px.variance(capture))
    std = None if std_img is None else std_img[use]
    base = PointLampModel(obs.P[use], obs.N[use], obs.camera_position, obs.specular[use], std=std)
    phases = lamp_phases(capture, use, separation, fit_px)
    k_max = min(len(found.peaks) + 1, MAX_LAMPS) if lamps == "auto" else int(lamps)
    families = FAMILIES if lobe == "auto" else tuple(v.strip() for v in lobe.split("+"))
    stride = max(1, len(base.P) // 2000)
    floor = loss_floor(obs.specular[use], std)

    s1 = one.stages["full"]
    x1 = np.concatenate([s1["lamp_position"], s1["ks"], [s1["roughness"]]])
    fits = {1: {"x": x1, "lobe": s1["lobe"], "chi2": s1["chi2"]}}  # K = 1 is returned as ``one`` itself
    regional: dict[int, np.ndarray | None] = {}

    def highlight_start(i: int) -> np.ndarray | None:
        if i not in regional:
            regional[i] = _region_start(obs, found.labels == i + 1, std_img, n_starts=int(n_starts), starts=peak_ray_starts)
        return regional[i]

    def residual_start(x: np.ndarray, family: str) -> np.ndarray | None:
        """A start at the brightest highlight of what the lamps of ``x`` (in ``family``) leave unexplained."""
        unweighted = SeveralLampModel(PointLampModel(obs.P[use], obs.N[use], obs.camera_position, obs.specular[use],
                                                     lobe=family), (len(x) - 1) // 6, phases)
        left = np.zeros_like(obs.specular)
        left[use] = -unweighted.residuals(x).reshape(-1, 3)
        return _region_start(dataclasses.replace(obs, specular=left), segment_highlights(left, use).labels == 1,
                             std_img, n_starts=int(n_starts), starts=peak_ray_starts)

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
    }
    if lamps == "auto":
        stage["lamps_evidence"] = evidence
    perm = [j for i in order for j in range(6 * i, 6 * i + 6)] + [6 * k]  # rows in the lamps' brightness order
    stage["covariance"] = cov[np.ix_(perm, perm)]
    return Estimate(
        method="full",
        lamp_position=stage["lamp_position"],
        lamp_positions=np.array([x[6 * i : 6 * i + 3] for i in order]),  # scored by evaluation.matching
        ks=colour * peak_shape(family, x[-1]),
        sigma=per_roughness * x[-1],
        covariance=cov4,
        stages={"init": one.stages["init"], "full": stage},
        diagnostics=_diagnostics(one, found),
        timings={**one.timings, "several": time.perf_counter() - clock},
    )


def _diagnostics(one: Estimate, found: Highlights) -> dict:
    """The one-lamp fit's diagnostics without its several-highlights warning (this fit counts), and the highlights."""
    out = {k: v for k, v in one.diagnostics.items() if k != "warnings"}
    out["highlights"] = {"peak_pixels": [list(p) for p in found.peaks], "heights": found.heights.tolist()}
    return out


def _with_count(one: Estimate, evidence: dict, found: Highlights) -> Estimate:
    """The one-lamp estimate of ``lamps=auto`` when one lamp wins, with the evidence and its lamp list."""
    s = one.stages["full"]
    stage = {**s, "n_lamps": 1, "lamps_option": "auto", "lamps_evidence": evidence,
             "lamps": [{"position": np.asarray(s["lamp_position"]).tolist(), "colour": np.asarray(s["ks"]).tolist()}]}
    return dataclasses.replace(one, stages={**one.stages, "full": stage},
                               diagnostics=_diagnostics(one, found))
