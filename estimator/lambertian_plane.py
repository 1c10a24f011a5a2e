"""Method ``lambertian-plane``: a near point lamp from the diffuse fall-off over a plane (Park et al., CVPR 2014).

A Lambertian plane lit by a near point lamp at ``L`` has, per pixel and
channel, the diffuse radiance

    D_c(P) = s_c · b(d) · max(0, n·(L − P)) / |L − P|³,

``n`` the plane's unit normal (towards the camera), ``d = (P − L)/|P − L|``
the light's propagation direction, ``s_c`` the albedo × intensity of channel
``c`` (not identifiable apart, not reported) and ``b`` the lamp's beam: 1
(``isotropic``) or ``max(0, d·a)^k`` (``cos-power``, the generator's beam,
:func:`nearlight.generator.closed_form.beam`, with unknowns ``k ≥ 0`` and the
unit axis ``a``).

The diffuse is the unpolarized part of the analyzer stack, ``S0 − |S_lin|``
(:func:`~nearlight.estimator.separation.separate_capture`, the rig's
extinction ratios corrected), or the capture's own ``diffuse`` image. The
plane is the range's (:func:`~nearlight.estimator.surfaces.fit_surface` over
the chosen pixels: the object's, or the first ``matte_card`` of
``rig.targets``), its points moved onto it along their rays.

Pixels: a lattice, every ``step``-th row and column of the plane's pixels,
``step`` the smallest that keeps ``max_pixels``; with the ``projected``
separation at least :data:`PROJECTED_STEP`, so that no fitted pixel lies in
another's phase window: its diffuse error then depends on its own readings
and on unfitted neighbours' only, and the fitted pixels' errors are
independent, as the covariance assumes. (On every pixel the shared phases
correlate neighbours' errors: on the analytic board at 64×48 the lamp's
scatter was 1.3× the stated, 95 % coverage 0.77–0.82 over 100 seeds.) The
``fit`` separation is per pixel but biased: its Rician amplitude lowers the
diffuse wherever the specular is faint (the same board: the lamp off by
20–25 of its standard deviations, 40 seeds). ``maxmin``'s variance is taken
as ``fit``'s.

The fit: weighted least squares (:func:`scipy.optimize.least_squares`), each
pixel and channel weighed by its standard deviation under the camera's noise
(:func:`~nearlight.estimator.noise.camera_noise`, propagated through the
separation: :func:`diffuse_variance`), ``s_c`` profiled out by linear least
squares inside the residual (variable projection, Kaufman's Jacobian). The
variances are taken at the measured diffuse for the starts, then at the
fitted model's and the fit repeated from its answer: weights from the
pixel's own reading favour its low draws and bias the fall-off (the lamp's
height by 0.35 of its standard deviation on the analytic board's given
diffuse, 100 seeds). The lamp is ``L = c + u e1 + v e2 + h n`` in the plane's frame (``c`` the points'
centroid), ``0 < h ≤`` :data:`MAX_HEIGHT` × the plane's extent. Starts
(deterministic): for an isotropic lamp ``D^(−2/3) ∝ |x − x0|² + h²`` over the
plane (``x0`` the lamp's foot point), a linear least-squares fit of a
paraboloid (:func:`paraboloid_start`, exact without noise), beside a grid of
foot points (the brightest pixel, the centroid, the centroid ± the extent
along the plane's axes: the foot may lie off the plane's visible part) times
:data:`START_HEIGHTS` × the extent; the :data:`N_REFINED` cheapest starts
are refined and the lowest cost wins. A ``cos-power`` beam is then fitted
from the isotropic lamp with :data:`BEAM_STARTS` exponents, its axis
towards the brightest pixel or against the normal.

Covariance: the Gauss–Newton ``(JᵀWJ)⁻¹`` at the fit with ``s_c`` profiled
(the Schur complement of the full normal matrix: exactly the marginal of
``(u, v, h)``; a pseudo-inverse, as a beam with ``k = 0`` leaves its axis
undetermined), rotated to world axes; multiplied by the reduced χ² when the
capture says nothing of its noise (unit weights). It is conditional on the
fitted plane: the range's error is not propagated.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from scipy.ndimage import binary_erosion
from scipy.optimize import least_squares

from ..capture import Capture
from ..errors import UserError
from ..physics.polarization import analyzer_matrix, aolp, linear_stokes
from ..physics.reflectance import channel_sum, every_channel, normalize, tangent_basis
from .fitting import single_threaded_blas
from .geometry import capture_rays, check_shapes
from .noise import VarianceModel, camera_noise, std_floor, stokes_weights, variance
from .options import Choice, Count, Positive
from .result import Estimate
from .separation import PHASE_WINDOW, SEPARATION_METHODS, separate_capture, specular_gain
from .surfaces import fit_surface

#: Surfaces the method reads: the object under study, or the rig's first matte card.
SURFACES = ("object", "card")
#: Beam models: ``b = 1``, or ``b = max(0, d·a)^k``.
BEAMS = ("isotropic", "cos-power")
#: Fewest plane pixels the fit accepts (9 unknowns at most: L, k, a, and s per channel).
MIN_PIXELS = 20
#: A fitted lamp farther than this × the plane's extent from it shows no fall-off: a lamp at infinity.
FAR = 100.0
#: Upper bound of the lamp's height over the plane, × the plane's extent (beyond :data:`FAR`: the fit may go there).
MAX_HEIGHT = 1000.0
#: Heights of the grid starts, × the plane's extent.
START_HEIGHTS = (0.25, 1.0, 4.0)
#: Starts refined by least squares (the cheapest by their starting cost).
N_REFINED = 3
#: Exponents k the ``cos-power`` fit starts from.
BEAM_STARTS = (1.0, 4.0, 16.0)
#: Upper bound of k (the scene files' own).
K_MAX = 1000.0
#: ``least_squares``' ``xtol``, ``ftol`` and ``gtol``.
TOL = 1e-12
#: Smallest lattice step with the ``projected`` separation: beyond the phase window's half-width, so that no fitted
#: pixel's reading enters another fitted pixel's phase.
PROJECTED_STEP = PHASE_WINDOW // 2 + 1


class PlaneLamp:
    """The shading ``g = b(d) · max(0, n·(L − P)) / |L − P|³`` at a plane's points, and its Jacobian.

    Parameters ``x = (u, v, h)`` (isotropic) or ``(u, v, h, k, p, q)``
    (cos-power): the lamp ``L = c + u e1 + v e2 + h n`` (metres) and the
    beam's axis ``a = (a0 + p f1 + q f2) / |…|``, ``(f1, f2)`` a tangent
    basis at the reference axis ``a0``.

    Parameters
    ----------
    P : ndarray, shape (m, 3)
        The plane's points, metres.
    normal, centre : ndarray, shape (3,)
        Its unit normal (towards the camera) and a point of it.
    axis0 : ndarray, shape (3,), optional
        ``a0``; None: an isotropic lamp.
    """

    def __init__(self, P: np.ndarray, normal: np.ndarray, centre: np.ndarray, axis0: np.ndarray | None = None):
        self.P, self.normal, self.centre, self.axis0 = P, normal, centre, axis0
        self.frame = np.column_stack([*tangent_basis(normal), normal])
        self.axis_basis = None if axis0 is None else tangent_basis(axis0)

    def lamp(self, x: np.ndarray) -> np.ndarray:
        """The lamp's world position, shape (3,), metres."""
        return self.centre + self.frame @ x[:3]

    def axis(self, x: np.ndarray) -> np.ndarray:
        """The beam's unit axis, shape (3,)."""
        f1, f2 = self.axis_basis
        return normalize(self.axis0 + x[4] * f1 + x[5] * f2)

    def shading(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``g`` (m,) and ``∂g/∂x`` (m, len(x)).

        With ``r = L − P``, ``ρ = |r|``, ``c = n·r``, ``t = d·a = −r·a/ρ``:
        ``∂(c/ρ³)/∂L = n/ρ³ − 3c r/ρ⁵``, ``∂t/∂L = −(a + t r/ρ)/ρ``,
        ``∂b/∂L = b k/t ∂t/∂L``, ``∂b/∂k = b ln t``, ``∂b/∂p = b k/t d·∂a/∂p``
        with ``∂a/∂p = (f1 − (f1·a) a)/|a0 + p f1 + q f2|`` (likewise q).
        """
        r = self.lamp(x) - self.P
        rho = np.sqrt(np.einsum("ij,ij->i", r, r))
        c = r @ self.normal
        lit = c > 0
        shade = np.where(lit, c, 0.0) / rho**3
        d_shade = np.where(lit[:, None], self.normal / rho[:, None] ** 3 - 3.0 * (c / rho**5)[:, None] * r, 0.0)
        if self.axis0 is None:
            return shade, d_shade @ self.frame
        a, k = self.axis(x), x[3]
        d = -r / rho[:, None]
        t = d @ a
        ahead = t > 0
        ts = np.where(ahead, t, 1.0)
        b = np.where(ahead, ts**k, 0.0)
        bk_t = b * k / ts  # ∂b/∂t
        dt_dL = -(a + t[:, None] * r / rho[:, None]) / rho[:, None]
        J = np.empty((len(r), 6))
        J[:, :3] = (b[:, None] * d_shade + (shade * bk_t)[:, None] * dt_dL) @ self.frame
        J[:, 3] = shade * b * np.log(ts)
        w = self.axis0 + x[4] * self.axis_basis[0] + x[5] * self.axis_basis[1]
        for j, f in enumerate(self.axis_basis):
            da = (f - (f @ a) * a) / np.linalg.norm(w)
            J[:, 4 + j] = shade * bk_t * (d @ da)
        return shade * b, J


class Profiled:
    """Weighted residuals ``(s_c g_i − D_ic) / σ_ic`` with ``s_c`` profiled out, and their Jacobian.

    Parameters
    ----------
    model : PlaneLamp
    D, sd : ndarray, shape (m, 3)
        Diffuse radiance and its standard deviation per pixel and channel.
    """

    def __init__(self, model: PlaneLamp, D: np.ndarray, sd: np.ndarray):
        self.model, self.inv_sd, self.Dw = model, 1.0 / sd, D / sd

    def scales(self, x: np.ndarray) -> np.ndarray:
        """``s_c`` (3,): the linear least-squares scale per channel at ``x``."""
        G = self.model.shading(x)[0][:, None] * self.inv_sd
        return _scales(G, self.Dw)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Shape (3m,), pixel-major."""
        G = self.model.shading(x)[0][:, None] * self.inv_sd
        return (_scales(G, self.Dw) * G - self.Dw).ravel()

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Kaufman's variable-projection Jacobian, shape (3m, len(x)): ``s_c ∂g/∂x / σ`` projected, per channel,
        off the column ``g/σ`` of ``s_c``. Its Gauss–Newton matrix is the Schur complement of the full one (in
        ``x`` and ``s``), so its inverse is the covariance of ``x`` with ``s`` free."""
        g, dg = self.model.shading(x)
        G = g[:, None] * self.inv_sd
        J = _scales(G, self.Dw)[None, :, None] * dg[:, None, :] * self.inv_sd[..., None]  # (m, 3, p)
        GG = np.maximum(np.sum(G * G, axis=0), 1e-300)
        J -= G[..., None] * (np.einsum("ic,icp->cp", G, J) / GG[:, None])[None]
        return J.reshape(-1, J.shape[-1])

    def cost(self, x: np.ndarray) -> float:
        """``½ Σ`` squared residuals."""
        r = self.residuals(x)
        return float(0.5 * r @ r)


def _scales(G: np.ndarray, Dw: np.ndarray) -> np.ndarray:
    """Per channel ``Σ G D / Σ G²`` (0 where ``G`` is 0 everywhere), shape (3,)."""
    GG = np.sum(G * G, axis=0)
    return np.sum(G * Dw, axis=0) / np.where(GG > 0, GG, 1.0)


def diffuse_image(capture: Capture, *, separation: str) -> np.ndarray:
    """The capture's diffuse radiance (H, W, 3): its ``diffuse`` image, else ``S0 − |S_lin|`` of its stack
    (the rig corrected: :func:`~nearlight.estimator.separation.separate_capture`)."""
    if capture.diffuse is not None:
        return np.asarray(capture.diffuse, dtype=float)
    if capture.stack is None:
        raise UserError(f"{capture.name}: lambertian-plane: no image: expected pol<k>.R/G/B or diffuse.R/G/B")
    return separate_capture(capture, method=separation)[1]


def diffuse_variance(capture: Capture, diffuse: np.ndarray, noise: VarianceModel, pixels: np.ndarray,
                     expected: np.ndarray | None = None) -> np.ndarray:
    """Variance of the diffuse at ``pixels`` (bool (H, W)), shape (m, 3), radiance².

    A separated diffuse is linear in the stack along the pixel's phase β:
    ``D = Σ_k (P_0k/(1 + k_a) − G w_k) I_k`` (``P_0`` the S0 row of the Stokes
    fit's pseudo-inverse, ``w_k`` the specular's weights,
    :func:`~nearlight.estimator.noise.stokes_weights`, ``k_a`` and ``G`` the
    rig correction's, :func:`~nearlight.estimator.separation.rig_correction`),
    so its variance is ``Σ_k (…)² var(I_k)``, each reading's variance at its
    Stokes fit's value; a given diffuse image is read as recorded. At least
    the noise module's floor, ``(FLOOR · peak)²``.

    Parameters
    ----------
    capture : Capture
    diffuse : ndarray, shape (H, W, 3)
        The measured diffuse.
    noise : VarianceModel
    pixels : ndarray of bool, shape (H, W)
    expected : ndarray, shape (m, 3), optional
        The diffuse a model expects at ``pixels``: each reading's variance is
        then taken with its diffuse part moved there (a reading holds
        ``(1 + k_a)/2`` of the diffuse).
    """
    measured = diffuse[pixels]
    floor = std_floor(measured) ** 2
    shift = 0.0 if expected is None else expected - measured
    if capture.diffuse is not None:
        return np.maximum(variance(measured + shift, noise), floor)
    angles = np.asarray(capture.analyzer_angles_deg, dtype=float)
    A = analyzer_matrix(angles)
    coef = linear_stokes(np.asarray(capture.stack[:, pixels], dtype=float), angles)  # (3, m, 3)
    rig = capture.rig
    ka = 0.0 if rig.analyzer_extinction_ratio is None else 1.0 / float(rig.analyzer_extinction_ratio)
    mu = np.tensordot(A, coef, axes=1) + 0.5 * (1.0 + ka) * shift  # (K, m, 3)
    gain = specular_gain(rig.analyzer_extinction_ratio, rig.lamp_polarizer_extinction_ratio)
    w = stokes_weights(angles, aolp(channel_sum(coef[1]), channel_sum(coef[2])))  # (K, m)
    c = np.linalg.pinv(A)[0][:, None] / (1.0 + ka) - gain * w
    return np.maximum(np.sum(c[..., None] ** 2 * variance(mu, noise), axis=0), floor)


def plane_pixels(capture: Capture, surface: str) -> tuple[Capture, np.ndarray]:
    """The capture as the method reads it and the pixels of its plane (bool (H, W)).

    ``"object"``: :meth:`~nearlight.capture.Capture.of_object` and its
    surface; ``"card"``: the whole capture and the pixels of the first
    ``matte_card`` of ``rig.targets`` with a range, less its edge: a pixel on
    the card's edge holds the card's light over the part of its area the card
    covers (a camera's pixel integrates), which the fall-off does not model
    (measured on ``sweeps/targets.yaml``'s card at 160×120: edge pixels down to
    a third of the interior's, and the lamp 0.32 m off with them).
    """
    if surface == "object":
        seen = capture.of_object()
        return seen, seen.surface_mask
    card = next((t for t in capture.rig.targets if t.type == "matte_card"), None)
    if card is None:
        raise UserError(f"{capture.name}: lambertian-plane: surface=card, but rig.targets has no matte_card")
    if capture.object_id is None or card.name not in capture.objects:
        raise UserError(f"{capture.name}: lambertian-plane: the matte card {card.name} has no pixels "
                        "(object_id and objects do not name it)")
    on = capture.object_id == capture.objects.index(card.name) + 1
    return capture, binary_erosion(on, iterations=1) & capture.surface_mask


def fitted_plane(capture: Capture, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The plane through the range at ``pixels``: points on it (H, W, 3; NaN elsewhere) and its unit normal
    towards the camera, shape (3,) (:func:`~nearlight.estimator.surfaces.fit_surface` over those pixels).

    Raises
    ------
    UserError
        No rays through the pixels, or the range there is not one plane.
    """
    rays = capture_rays(capture)
    P = np.where(pixels[..., None], np.asarray(capture.P, dtype=float), np.nan)
    fit = None if rays is None else fit_surface(P, np.asarray(capture.camera.position, float), rays, valid=pixels)
    if fit is None or not fit.plane:
        kind = "no surface" if fit is None else f"a {fit.kind} surface"
        raise UserError(f"{capture.name}: lambertian-plane: the range of its {int(pixels.sum())} pixels is not one "
                        f"plane (fitted: {kind})")
    return fit.P, fit.N[pixels][0]


def paraboloid_start(X: np.ndarray, D: np.ndarray) -> np.ndarray | None:
    """``(u, v, h)`` of an isotropic lamp from the fall-off, or None when it has no finite maximum.

    Over a plane ``D = s h / (|x − x0|² + h²)^{3/2}``, so ``D^(−2/3) =
    β (|x|² − 2 x·x0 + |x0|² + h²)``: linear in ``(β, β x0, β(|x0|² + h²))``.
    Least squares over the lit pixels, each row weighted by ``D^(5/3)`` (the
    inverse of ``D^(−2/3)``'s relative error growth); exact without noise.

    Parameters
    ----------
    X : ndarray, shape (m, 2)
        In-plane coordinates, metres.
    D : ndarray, shape (m,)
        Diffuse radiance (channels summed).
    """
    lit = D > 1e-3 * np.max(D)
    if lit.sum() < 4:
        return None
    x, d = X[lit], D[lit]
    w = d ** (5.0 / 3.0)
    A = np.column_stack([np.sum(x * x, axis=1), x, np.ones(len(x))]) * w[:, None]
    beta, b1, b2, gamma = np.linalg.lstsq(A, d ** (-2.0 / 3.0) * w, rcond=None)[0]
    if not beta > 0:
        return None
    foot = -np.array([b1, b2]) / (2.0 * beta)
    h2 = gamma / beta - foot @ foot
    return np.array([*foot, np.sqrt(h2)]) if h2 > 0 else None


def clipped(capture: Capture, saturation: float | None) -> np.ndarray:
    """Pixels (bool (H, W)) with a reading at or above ``saturation``: an analyzer image's, or the given diffuse's
    (all False when None)."""
    if saturation is None:
        return np.zeros((capture.height, capture.width), bool)
    readings = capture.diffuse[None] if capture.diffuse is not None else capture.stack
    return np.any(np.asarray(readings) >= saturation, axis=(0, 3))


def lattice(pixels: np.ndarray, *, max_pixels: int, min_step: int = 1) -> np.ndarray:
    """``pixels`` (bool (H, W)) on every ``step``-th row and column (from 0), ``step ≥ min_step`` the smallest that
    keeps at most ``max_pixels`` of them."""
    rows, cols = np.indices(pixels.shape)
    step = max(min_step, 1)
    while True:
        kept = pixels & (rows % step == 0) & (cols % step == 0)
        if kept.sum() <= max_pixels:
            return kept
        step += 1


def _bounds(model: PlaneLamp, extent: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower and upper bounds and typical magnitudes of ``model``'s parameters: ``0 < h ≤`` :data:`MAX_HEIGHT` ×
    ``extent``, ``0 ≤ k ≤`` :data:`K_MAX`."""
    lower, upper, typical = [-np.inf, -np.inf, 1e-9 * extent], [np.inf, np.inf, MAX_HEIGHT * extent], [extent] * 3
    if model.axis0 is not None:
        lower, upper = [*lower, 0.0, -np.inf, -np.inf], [*upper, K_MAX, np.inf, np.inf]
        typical = [*typical, 1.0, 0.1, 0.1]
    return np.array(lower), np.array(upper), np.array(typical, dtype=float)


def _refine(problem: Profiled, starts: Sequence[np.ndarray], extent: float) -> tuple[np.ndarray, float]:
    """The least-squares fit from the :data:`N_REFINED` cheapest ``starts`` (clipped into the bounds) with the lowest
    cost: its parameters and cost (ties: the earlier start)."""
    lower, upper, typical = _bounds(problem.model, extent)
    inside = [np.clip(x, lower + 1e-9 * typical, upper - 1e-9 * typical) for x in starts]
    order = sorted(range(len(inside)), key=lambda i: (problem.cost(inside[i]), i))
    best = None
    for i in order[:N_REFINED]:
        res = least_squares(problem.residuals, inside[i], jac=problem.jacobian, bounds=(lower, upper),
                            x_scale=typical, method="trf", xtol=TOL, ftol=TOL, gtol=TOL, max_nfev=200)
        if best is None or res.cost < best.cost:
            best = res
    return best.x, float(best.cost)


def isotropic_starts(X: np.ndarray, lum: np.ndarray, extent: float) -> list[np.ndarray]:
    """Starts ``(u, v, h)``: the paraboloid's (when it has one), then feet at the brightest pixel, the centroid
    and the centroid ± the extent along the plane's axes, at :data:`START_HEIGHTS` × the extent.

    Parameters
    ----------
    X : ndarray, shape (m, 2)
        The pixels' in-plane coordinates about the centroid, metres.
    lum : ndarray, shape (m,)
        Their diffuse, channels summed.
    extent : float
        The plane's extent, metres.
    """
    feet = [X[np.argmax(lum)], np.zeros(2), *(extent * np.array(e) for e in ((1, 0), (-1, 0), (0, 1), (0, -1)))]
    starts = [np.array([*foot, f * extent]) for foot in feet for f in START_HEIGHTS]
    first = paraboloid_start(X, lum)
    return starts if first is None else [first, *starts]


def fit_lamp(P: np.ndarray, normal: np.ndarray, centre: np.ndarray, extent: float, D: np.ndarray, sd: np.ndarray,
             beam: str) -> tuple[PlaneLamp, np.ndarray, int]:
    """The lamp (and beam) fitted from the starts: the model, its parameters, the number of starts.

    Isotropic from :func:`isotropic_starts`; a ``cos-power`` beam then from
    that lamp with each of :data:`BEAM_STARTS`, its axis towards the
    brightest pixel or against the normal (the lowest cost wins; ties: the
    earlier). Arguments as :class:`PlaneLamp` and :class:`Profiled`.
    """
    model = PlaneLamp(P, normal, centre)
    lum = channel_sum(D)
    starts = isotropic_starts((P - centre) @ model.frame[:, :2], lum, extent)
    x, _ = _refine(Profiled(model, D, sd), starts, extent)
    if beam == "isotropic":
        return model, x, len(starts)
    lamp = model.lamp(x)
    fits = []
    for a0 in (normalize(P[np.argmax(lum)] - lamp), -normal):
        beamed = PlaneLamp(P, normal, centre, a0)
        for k in BEAM_STARTS:
            xb, cost = _refine(Profiled(beamed, D, sd), [np.array([*x, k, 0.0, 0.0])], extent)
            fits.append((cost, len(fits), beamed, xb))
    _, _, model, x = min(fits, key=lambda f: f[:2])
    return model, x, len(starts) + len(fits)


def lambertian_plane_estimate(
    capture: Capture,
    *,
    surface: Choice(SURFACES) = "object",
    beam: Choice(BEAMS) = "isotropic",
    separation: Choice(SEPARATION_METHODS) = "projected",
    max_pixels: Count = 20000,
    saturation: Positive | None = None,
) -> Estimate:
    """Method ``lambertian-plane``: the lamp from the diffuse fall-off over a plane (see the module docstring).

    Parameters
    ----------
    capture : Capture
        The whole capture (the method picks its pixels: ``uses_targets``).
    surface : {"object", "card"}
        The plane: the object under study, or the first ``matte_card`` of ``rig.targets``.
    beam : {"isotropic", "cos-power"}
        The lamp's beam: ``b = 1``, or ``max(0, d·a)^k`` with ``k`` and ``a`` fitted.
    separation : {"projected", "fit", "maxmin"}
        How the stack is separated (:func:`~nearlight.estimator.separation.separate`); ``projected`` (the
        default) leaves the diffuse unbiased under noise, where ``fit``'s Rician amplitude lowers it.
    max_pixels : int
        Most pixels fitted: a lattice over the plane (see the module docstring).
    saturation : float, optional
        Pixels with a reading (analyzer image, or the given diffuse) at or above it are left out, radiance.

    Returns
    -------
    Estimate
        ``lamp_position``; ``ks`` and ``sigma`` NaN (not estimated); ``covariance`` with the lamp's
        ``(x, y, z)`` block (m²) and the σ row and column NaN. ``stages["fit"]``: the beam's ``k`` and
        ``axis`` (NaN when isotropic), the plane's ``normal``, the weighted residual ``rms`` and the reduced
        ``chi2``, ``n_pixels``, ``n_starts``, the ``noise`` model; ``diagnostics["undetermined"] = ["ks", "sigma"]`` (the lamp alone).

    Raises
    ------
    UserError
        No card (``surface="card"``), fewer than :data:`MIN_PIXELS` pixels, a range that is not one plane
        (or a degenerate one), or no fall-off: the fitted lamp farther than :data:`FAR` × the plane's extent
        (a lamp at infinity, e.g. a constant diffuse).
    """
    clock = time.perf_counter()
    check_shapes(capture)
    seen, pixels = plane_pixels(capture, surface)
    D_img = diffuse_image(seen, separation=separation)
    pixels = pixels & every_channel(np.isfinite(D_img)) & ~clipped(seen, saturation)
    projected = seen.diffuse is None and separation == "projected"
    use = lattice(pixels, max_pixels=int(max_pixels), min_step=PROJECTED_STEP if projected else 1)
    if use.sum() < MIN_PIXELS:
        sparse = f", every {PROJECTED_STEP}rd row and column with the projected separation" if projected else ""
        raise UserError(f"{capture.name}: lambertian-plane: only {int(use.sum())} pixels to fit on the {surface} "
                        f"(need {MIN_PIXELS}{sparse})")
    P_plane, normal = fitted_plane(seen, pixels)
    centre = P_plane[pixels].mean(axis=0)
    extent = float(np.max(np.linalg.norm(P_plane[pixels] - centre, axis=1)))
    P, D = P_plane[use], D_img[use]
    if np.linalg.matrix_rank(P - P.mean(axis=0), tol=1e-6 * extent) < 2:
        raise UserError(f"{capture.name}: lambertian-plane: the {surface}'s pixels lie on a line: a degenerate plane")
    noise = camera_noise(seen, surface=pixels)
    sd = np.ones_like(D) if noise is None else np.sqrt(diffuse_variance(seen, D_img, noise, use))
    timings = {"observe": time.perf_counter() - clock}

    clock = time.perf_counter()
    with single_threaded_blas():
        model, x, n_starts = fit_lamp(P, normal, centre, extent, D, sd, beam)
        if noise is not None:  # again, each variance at the model's diffuse rather than the pixel's own draw
            expected = Profiled(model, D, sd).scales(x) * model.shading(x)[0][:, None]
            sd = np.sqrt(diffuse_variance(seen, D_img, noise, use, expected))
            x, _ = _refine(Profiled(model, D, sd), [x], extent)
        problem = Profiled(model, D, sd)
        residuals, J = problem.residuals(x), problem.jacobian(x)
    timings["fit"] = time.perf_counter() - clock

    lamp = model.lamp(x)
    distance = float(np.linalg.norm(lamp - centre))
    if distance > FAR * extent:
        raise UserError(f"{capture.name}: lambertian-plane: no fall-off: the diffuse over the {surface} fits a lamp "
                        f"{distance:.4g} m away, beyond {FAR:g} x the plane's {extent:.4g} m extent (a lamp at "
                        "infinity)")
    chi2 = float(residuals @ residuals) / max(J.shape[0] - J.shape[1] - 3, 1)
    cov_x = np.linalg.pinv(J.T @ J, hermitian=True) * (chi2 if noise is None else 1.0)
    covariance = np.full((4, 4), np.nan)
    covariance[:3, :3] = model.frame @ cov_x[:3, :3] @ model.frame.T
    beamed = model.axis0 is not None
    return Estimate(
        method="lambertian-plane",
        lamp_position=lamp,
        ks=np.full(3, np.nan),
        sigma=np.nan,
        covariance=covariance,
        stages={"fit": {
            "surface": surface, "beam": beam, "k": float(x[3]) if beamed else np.nan,
            "axis": model.axis(x) if beamed else np.full(3, np.nan), "normal": normal,
            "rms": float(np.sqrt(np.mean(residuals**2))), "chi2": chi2, "n_pixels": int(use.sum()),
            "n_starts": n_starts,
            "noise": "none: unit weights, covariance scaled by chi2" if noise is None else noise.source,
        }},
        diagnostics={"undetermined": ["ks", "sigma"], "n_pixels": int(use.sum()), "plane_extent_m": extent},
        timings=timings,
    )


lambertian_plane_estimate.uses_targets = True
