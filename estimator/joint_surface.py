"""``full``'s errors-in-variables fit: the lamp, colour and roughness refined together with the surface.

A surface fitted to a noisy range (:mod:`~nearlight.estimator.surfaces`) is
wrong by its fitting error, and taken as given that error goes into the lamp
unseen: a normal tilted by a fraction of a degree turns the mirror ray by
twice as much, and the image-only covariance knows nothing of it (measured:
``benchmarks/bench_range_bound.py``'s coverage column, 0.99 → 0.12 on the
board at 1 mm of range noise). The specular image knows the surface near the
highlight too: where the lobe's pixels fall fixes where the half-vector
meets the normal. So when the surface is one plane or one sphere
(:class:`~nearlight.estimator.whole_surface.SurfaceParameters`), its
parameters ``g`` join the fit:

* the image's residuals, each pixel's point and normal those of the surface
  ``g`` where the pixel's own direction from the camera meets it
  (:func:`~nearlight.estimator.whole_surface.on_rays`), weighted by the
  camera noise as in the image-only fit;
* the range's, as the range fit's information about ``g``: ``s·L(g − ĝ)`` with
  ``LᵀL = C_g⁻¹`` (``ĝ, C_g`` the range fit's), ``s`` the image residuals'
  scale (1 when the weights are the camera's, the residuals' RMS otherwise).

For a linear range model this quadratic is the range's whole log-likelihood
about ``g`` up to a constant (the range residuals' sufficient statistic), so
the fit is the one that stacks every range pixel beside every image pixel,
as the bound does (:mod:`nearlight.evaluation.scoring.range_bound`), at the
cost of a few more image evaluations. The covariance of ``(lamp, colour,
roughness, g)`` is the robust fit's sandwich over both; its lamp block now
holds the geometry's share. ``C_g`` is the range fit's own
(:mod:`~nearlight.estimator.whole_surface`): the plane's independent-noise
one (guarded by a block jackknife when the range states white noise), the
sphere's its weighted Gauss–Newton's; on a quantised range either plus the
staircase's simulated share (``staircase_cov``: a staircase's errors are one
sawtooth over each terrace).

With one lobe to fit this is ``full``'s final fit, from the short fit as the
image-only final fit would start; with several, those choose the lobe and
the chosen one is refined from its fit.

Several lamps share the one surface: the chosen count's fit is refined
with it the same way. A quadric and local windows keep their surface as
given (their parameters are not refined, yet), with a warning; so does a
capture whose range states no error.
"""

from __future__ import annotations

import numpy as np

from .fitting import robust_fit
from .observation import Observation
from .lampsum import SeveralLampModel
from .pointlamp import FINAL_TOL, PointLampModel, lamp_bounds, typical_scale
from .whole_surface import SurfaceParameters, on_rays

#: ``full``'s ``surface="auto"`` refines the surface with the lamp when the range's error (stated in
#: ``rig.range`` or measured) is above this, metres: far below any range sensor's (≥ 5e-5 m in every rig and
#: study here) and above float32 rounding of ``P`` (measured on exact analytic captures: 1.5e-9 m on the
#: board, 7.8e-8 m on the sphere), so an exact range costs nothing.
JOINT_MIN_RANGE_M = 1e-6

#: The surface's forward-difference step, in standard deviations of each parameter (``C_g``'s diagonal):
#: far above float rounding (the points move by ~1e-3 of the range noise, ≥ 1e-8 m) and far below the
#: parameters' curvature scale (the truncation error, ~step × curvature, is ~1e-3 of the derivative at most).
STEP_SD = 1e-3


class JointModel:
    """A lamp model with its surface as parameters: ``p = (x…, g…)``, ``x`` the image-only model's ``n_params``
    (one lamp's ``(x, y, z, colour_r, colour_g, colour_b, a)``, or K lamps' ``(l₁, c₁, …, l_K, c_K, a)``).

    Parameters
    ----------
    base : PointLampModel or SeveralLampModel
        The image-only model at the range fit's surface (its pixels, weights, lobe; ``P``, ``N``, ``camera`` and
        ``with_geometry``).
    surface : SurfaceParameters
        ``ĝ`` and ``C_g`` of the range fit.
    n_params : int
        Length of ``x``.
    scale : float
        The image residuals' scale ``s`` the prior is weighed with.
    """

    def __init__(self, base: PointLampModel | SeveralLampModel, surface: SurfaceParameters, *, n_params: int,
                 scale: float = 1.0):
        self.base, self.surface, self.n = base, surface, int(n_params)
        cam = np.asarray(base.camera, dtype=float)
        d = base.P - cam
        self.near = np.linalg.norm(d, axis=1)
        self.directions = d / self.near[:, None]
        vals, vecs = np.linalg.eigh(surface.cov)
        vals = np.maximum(vals, 1e-30 * max(float(vals.max()), 1e-300))
        self.sqrt_info = float(scale) * (vecs / np.sqrt(vals)).T  # s·L, LᵀL = C_g⁻¹
        self.step = STEP_SD * np.sqrt(np.maximum(np.diag(surface.cov), 1e-300))
        self.k = len(surface.g)
        self._models: dict[bytes, PointLampModel | SeveralLampModel] = {}

    def at(self, g: np.ndarray) -> PointLampModel | SeveralLampModel:
        """The image-only model on the surface ``g`` (the last few kept: the solver asks again at the same ``g``)."""
        key = np.asarray(g, dtype=float).tobytes()
        found = self._models.get(key)
        if found is None:
            cam = np.asarray(self.base.camera, dtype=float)
            t, n = on_rays(self.surface.kind, g, cam, self.directions, self.near)
            miss = ~np.isfinite(t)  # a grazing ray the moved sphere misses: the pixel stays where it was
            P = np.where(miss[:, None], self.base.P, cam + t[:, None] * self.directions)
            N = np.where(miss[:, None], self.base.N, n)  # unit: on_rays's and the base's
            found = self.base.with_geometry(P, N)
            if len(self._models) > self.k + 2:
                self._models.clear()
            self._models[key] = found
        return found

    def residuals(self, p: np.ndarray) -> np.ndarray:
        """Image residuals at ``(x, g)`` then the range's ``s·L(g − ĝ)``, shape ``(n·3 + k,)``."""
        x, g = p[: self.n], p[self.n :]
        return np.concatenate([self.at(g).residuals(x), self.sqrt_info @ (g - self.surface.g)])

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        """``∂ residuals / ∂ p``, shape ``(n·3 + k, n_params + k)``: the image's analytic in ``x``, forward
        differences in ``g`` (:data:`STEP_SD`), the prior's ``s·L``."""
        x, g = p[: self.n], p[self.n :]
        at = self.at(g)
        Jx = at.jacobian(x)
        r0 = at.residuals(x)
        Jg = np.empty((Jx.shape[0], self.k))
        for i, h in enumerate(self.step):
            e = np.zeros(self.k)
            e[i] = h
            Jg[:, i] = (self.at(g + e).residuals(x) - r0) / h
        top = np.hstack([Jx, Jg])
        bottom = np.hstack([np.zeros((self.k, self.n)), self.sqrt_info])
        return np.vstack([top, bottom])


def joint_fit(base: PointLampModel | SeveralLampModel, surface: SurfaceParameters, x0: np.ndarray, distance: float,
              *, loss: str, f_scale: float | None, floor: float, scale: float) -> dict:
    """The robust fit of :class:`JointModel` from the image-only fit ``x0`` and the range fit's surface.

    Parameters
    ----------
    base : PointLampModel or SeveralLampModel
        The image-only model (chosen lobe, every fit pixel).
    surface : SurfaceParameters
    x0 : ndarray, shape (n_params,)
        The image-only fit (or a short fit on a subset of its pixels).
    distance : float
        Camera–highlight distance (m), for the parameters' typical scales.
    loss, f_scale, floor
        As :func:`~nearlight.estimator.pointlamp.final_fit`'s.
    scale : float
        The image residuals' scale (see :class:`JointModel`).

    Returns
    -------
    dict
        :func:`~nearlight.estimator.fitting.robust_fit`'s result over ``n_params + k``
        parameters (``x``, ``cov``, …), with ``chi2`` the image residuals' sum of
        squares at the fit and ``prior_chi2`` the range term's ``|L(g − ĝ)|²``.
    """
    model = JointModel(base, surface, n_params=len(x0), scale=scale)
    lower, upper = lamp_bounds(len(x0))
    k = model.k
    p0 = np.concatenate([x0, surface.g])
    typical = np.concatenate([typical_scale(x0, distance), np.sqrt(np.maximum(np.diag(surface.cov), 1e-300))])
    fit = robust_fit(model.residuals, p0, typical=typical, lower=np.concatenate([lower, np.full(k, -np.inf)]),
                     upper=np.concatenate([upper, np.full(k, np.inf)]), loss=loss, f_scale=f_scale,
                     jac=model.jacobian, f_floor=floor, start_is_fit=True, tol=FINAL_TOL, prior_rows=k,
                     prior_var=scale**2)
    r = model.residuals(fit["x"])
    fit["chi2"] = float(np.sum(np.square(r[:-k])))
    fit["prior_chi2"] = float(np.sum(np.square(r[-k:]))) / scale**2
    return fit


def surface_fit_choice(obs: Observation, surface: str) -> tuple[bool, str]:
    """Whether ``full`` refines the surface with the lamps (``surface`` its option), and why, in a few words."""
    geometry = obs.geometry
    if surface == "fixed":
        return False, "surface=fixed"
    if geometry.parameters is None:
        kind = geometry.summary.get("surface")
        return False, ("the capture's own normals" if kind is None
                       else f"the range fitted a {kind} surface, whose parameters are not refined")
    sigma = geometry.range.equivalent_sigma_m
    if surface == "auto" and not sigma > JOINT_MIN_RANGE_M:
        return False, f"the range's error {sigma:.3g} m is below {JOINT_MIN_RANGE_M:g} m"
    return True, f"one {geometry.parameters.kind} fitted to a range with error {sigma:.3g} m"


def split_refined(obs: Observation, fit: dict, n_params: int) -> tuple[dict, dict]:
    """A :func:`joint_fit` result as the image-only fit's (``x`` and ``cov`` of the lamps' ``n_params``) and the
    refined surface's record (``stages["full"]["surface_parameters"]``)."""
    refined = {"kind": obs.geometry.parameters.kind, "g": fit["x"][n_params:],
               "covariance": fit["cov"][n_params:, n_params:], "range_fit_g": obs.geometry.parameters.g,
               "range_chi2": fit["prior_chi2"]}
    return {**fit, "x": fit["x"][:n_params], "cov": fit["cov"][:n_params, :n_params]}, refined


def fixed_surface_warning(obs: Observation, joint: bool) -> str | None:
    """The warning of a covariance that leaves out a noisy range's share (else None): the surface fitted to a range
    with an error above :data:`JOINT_MIN_RANGE_M` and taken as given (``joint`` False), so the ellipsoid is the
    image's alone and too small where the surface's error moves the lamp (its thinnest axis, the mirror ray's)."""
    model = obs.geometry.range
    if joint or model is None or not model.equivalent_sigma_m > JOINT_MIN_RANGE_M:
        return None
    return (f"covariance: the image's share only; the {obs.geometry.summary.get('surface', 'fitted')} surface fitted "
            f"to a range with error {model.equivalent_sigma_m:.3g} m was taken as given (its error moves the lamp "
            "beyond the stated ellipsoid)")
