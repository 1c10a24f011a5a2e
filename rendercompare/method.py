"""Method ``render-compare``: lamp position, Ks and roughness fitted by gradient descent through Mitsuba 3.

Analysis by synthesis, the field's modern alternative to hand-built fits: a
Mitsuba BSDF (:data:`~nearlight.rendercompare.lobes.LOBES`, option ``bsdf``)
lit by a point lamp predicts the specular image, and Dr.Jit's automatic
differentiation gives the gradient of its squared difference to the
capture's specular image with respect to the lamp's position and the BSDF's
roughness. It fits from the best few of ``full``'s starts (``paper-init``'s
lamp and points along its peak ray, ranked by :func:`rank_starts`), keeps
the fit of least loss, and is a baseline for ``full``.

What is rendered, and why not a path tracer
-------------------------------------------
The model is evaluated at the capture's own pixels: for each pixel a
``mi.SurfaceInteraction3f`` at the recorded point ``P`` with the recorded
normal ``N`` (its shading frame), ``wi`` towards the camera, and ``wo``
towards the lamp; the predicted radiance is ``(I / r²) · bsdf.eval(wi, wo)``
(Mitsuba's ``eval`` includes cos θi), ``I = 1`` as in every estimator. That
is exactly what Mitsuba's ``path`` integrator computes for direct light
from a point emitter at a pixel-centre hit (emitter sample, shadow ray,
``bsdf.eval``), minus the ray cast and the shadow ray. We chose it over
rendering a triangle mesh built from the ``P`` grid because, on 2 shared
CPU cores,

- a mesh from ``P`` only re-creates the points the capture already holds
  (its pixel-centre rays hit its vertices) and would interpolate normals
  that ``N`` gives exactly;
- it is deterministic and noise-free at one evaluation per pixel, so
  scipy's L-BFGS-B can use the gradients (a Monte Carlo render's noisy
  gradients need Adam and many more iterations);
- no shadow ray means no visibility discontinuity in the lamp gradient;
  the estimators' own models have no shadowing either, and the shipped
  boards cast none.

It is still "any Mitsuba BSDF as the lobe": ``bsdf.eval`` is Mitsuba's own
code, and a new lobe is a row of :data:`~nearlight.rendercompare.lobes.LOBES`.

Mitsuba's variant and Ks
------------------------
Mitsuba's variant is global to the process, and the generator renders in
``llvm_ad_mono_polarized`` (:mod:`nearlight.generator.llvm`); a sweep worker
that renders and then estimates would break if this method switched to
``llvm_ad_rgb``. So it uses the generator's variant: the Mueller matrix's
``M00`` is the radiance for unpolarized light (the lamp's polarizer is not
modelled: a separated specular image is the polarized part of the specular
radiance, which for ``ideal`` polarization is all of it). One colour
channel is enough because σ is shared by the channels and Ks enters
linearly: for each lobe shape ``g`` (unit Ks), the best Ks per channel is
the closed-form least-squares ``Σ g y_c / Σ g²`` (variable projection), and
the gradient flows through it. The optimiser sees four unknowns: the lamp's
position in units of the camera–highlight distance and ``ln alpha``.

Reported Ks and σ are Torrance–Sparrow equivalents: σ from ``alpha`` as in
:mod:`~nearlight.rendercompare.lobes`; Ks per channel such that the
Torrance–Sparrow lobe with that σ (docs/physics.md) has the fitted lobe's
radiance at the fitted lobe's brightest pixel.
"""

from __future__ import annotations

import time
from types import ModuleType
from typing import Any

import numpy as np

from ..capture import Capture
from ..errors import UserError
from ..estimator.first_stage import stage_one
from ..estimator.options import Choice, Count, CountOrZero, Positive, forwards
from ..estimator.pixels import fit_pixels
from ..estimator.pointlamp import peak_ray_starts
from ..estimator.result import Estimate
from ..estimator.separation import SEPARATION_METHODS
from ..physics.reflectance import specular_radiance
from .lobes import LOBES, Lobe

#: Bounds of the microfacet roughness ``alpha`` during the fit.
ALPHA_BOUNDS = (1e-3, 1.5)


class PixelModel:
    """A Mitsuba BSDF at fixed pixels, lit by a unit point lamp; loss and gradient by Dr.Jit.

    Parameters
    ----------
    mi : module
        ``mitsuba``, a JIT AD variant set.
    lobe : Lobe
    P, N : ndarray, shape (n, 3)
        Surface points (m) and unit normals.
    camera : ndarray, shape (3,)
    observed : ndarray, shape (n, 3)
        Specular radiance.
    polarizer : tuple of ndarray, optional
        ``(axis, aim)``: the lamp filter's transmission axis (world, in the
        filter's plane) and the point the filter faces; None for an
        unpolarized lamp.
    """

    def __init__(self, mi: ModuleType, lobe: Lobe, P: np.ndarray, N: np.ndarray, camera: np.ndarray,
                 observed: np.ndarray, *, polarizer: tuple[np.ndarray, np.ndarray] | None = None):  # fmt: skip
        import drjit as dr

        self.mi, self.lobe = mi, lobe
        self.bsdf = mi.load_dict({**lobe.bsdf, lobe.alpha_key.partition(".")[0]: 0.1})
        self.params = mi.traverse(self.bsdf)
        si = dr.zeros(mi.SurfaceInteraction3f, len(P))
        si.p = mi.Point3f(*(P[:, i] for i in range(3)))
        si.n = mi.Normal3f(*(N[:, i] for i in range(3)))
        si.sh_frame = mi.Frame3f(si.n)
        view = camera - P
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        si.wi = si.sh_frame.to_local(mi.Vector3f(*(view[:, i] for i in range(3))))
        self.si = si
        self.polarizer = None if polarizer is None else tuple(mi.Vector3f(*map(float, v)) for v in polarizer)
        self.observed = [mi.Float(observed[:, c]) for c in range(3)]
        self.norm = float(np.sum(observed**2))
        if not self.norm > 0:
            raise UserError("specular: no signal on the fitted pixels (all zero)")

    def _shape(self, lamp: Any, alpha: Any) -> Any:
        """``g``: radiance per unit Ks of a unit lamp at every pixel (Dr.Jit Float)."""
        import drjit as dr

        mi = self.mi
        self.params[self.lobe.alpha_key] = alpha
        self.params.update()
        d = lamp - self.si.p
        r2 = dr.squared_norm(d)
        wo = self.si.sh_frame.to_local(d / dr.sqrt(r2))
        mueller = self.bsdf.eval(mi.BSDFContext(), self.si, wo)
        if self.polarizer is None:
            return mueller[0, 0][0] / r2  # M00: the radiance for unpolarized light (one channel: mono_polarized)
        light = self._lamp_stokes(lamp, -wo)
        s1, s2 = (sum(mueller[i, j][0] * light[j] for j in range(4)) for i in (1, 2))
        # Imax - Imin behind a linear analyzer: the linearly polarized part (a separated specular image)
        return dr.sqrt(dr.maximum(dr.square(s1) + dr.square(s2), 1e-30)) / r2

    def _lamp_stokes(self, lamp: Any, forward: Any) -> list:
        """Stokes vector ``[S0, S1, S2, S3]`` of unit light after the lamp's ideal filter, as ``bsdf.eval`` takes it.

        ``forward``: the light's direction of travel in the shading frame;
        the vector is in Mitsuba's implicit Stokes basis of ``forward``
        (``mi.mueller.stokes_basis``), the basis of ``eval``'s input. As
        :mod:`nearlight.generator.lamp`: the filter faces the aim point; for
        an oblique ray its transmission axis is ``k × â``, ``â`` the absorbing
        axis projected normal to the ray direction ``k`` (Korger et al. 2013).
        The filter's factor ½ is left in Ks. The basis rotation is
        ``mi.mueller.rotate_stokes_basis`` (equal to it to 5e-7, measured)
        written with cos θ and sin θ from dot and cross products: measured,
        the lamp gradient through Mitsuba's own rotations
        (``rotate_stokes_basis`` of the lamp's filter, ``to_world_mueller``)
        was NaN; this one is finite and matches finite differences (tests).
        """
        import drjit as dr

        mi = self.mi
        axis, aim = self.polarizer
        absorb = self.si.sh_frame.to_local(dr.cross(dr.normalize(aim - lamp), axis))
        transmit = dr.normalize(dr.cross(forward, absorb - dr.dot(absorb, forward) * forward))
        basis = mi.mueller.stokes_basis(forward)
        cos, sin = dr.dot(transmit, basis), dr.dot(forward, dr.cross(transmit, basis))
        return [1.0, dr.square(cos) - dr.square(sin), -2.0 * sin * cos, 0.0]  # rotator(θ) @ [1, 1, 0, 0]

    def _variables(self, lamp: np.ndarray, alpha: float) -> tuple[Any, Any]:
        import drjit as dr

        mi = self.mi
        # opaque: a new value must not compile a new kernel (literals are baked into kernels)
        return mi.Point3f(*(dr.opaque(mi.Float, float(v)) for v in lamp)), dr.opaque(mi.Float, float(alpha))

    def _ks(self, g: Any) -> list:
        """Per channel, the Ks minimising ``Σ (Ks g − y)²`` (0 when the lobe is dark everywhere)."""
        import drjit as dr

        den = dr.sum(g * g)
        return [dr.select(den > 0, dr.sum(g * y) / den, 0.0) for y in self.observed]

    def loss_and_grad(self, lamp: np.ndarray, alpha: float) -> tuple[float, np.ndarray, float]:
        """Relative loss ``Σ (Ks g − y)² / Σ y²`` and its gradient w.r.t. the lamp (1/m) and ``alpha``.

        Returns
        -------
        loss : float
        grad_lamp : ndarray, shape (3,)
        grad_alpha : float
        """
        import drjit as dr

        p, a = self._variables(lamp, alpha)
        dr.enable_grad(p, a)
        g = self._shape(p, a)
        ks = self._ks(g)
        loss = sum(dr.sum(dr.square(k * g - y)) for k, y in zip(ks, self.observed)) / self.norm
        dr.backward(loss)
        grad = np.array([float(dr.grad(c)[0]) for c in p])
        return float(loss[0]), grad, float(dr.grad(a)[0])

    def evaluate(self, lamp: np.ndarray, alpha: float) -> tuple[np.ndarray, np.ndarray]:
        """The lobe shape ``g``, shape (n,), and the best Ks, shape (3,), without gradients."""
        p, a = self._variables(lamp, alpha)
        g = self._shape(p, a)
        ks = self._ks(g)
        return np.asarray(g, dtype=float), np.array([float(k[0]) for k in ks])


def ts_equivalent_ks(P: np.ndarray, N: np.ndarray, camera: np.ndarray, lamp: np.ndarray, g: np.ndarray,
                     ks: np.ndarray, sigma: float) -> np.ndarray:  # fmt: skip
    """Torrance–Sparrow Ks with the fitted lobe's radiance at its brightest pixel.

    Parameters
    ----------
    P, N : ndarray, shape (n, 3)
    camera, lamp : ndarray, shape (3,)
    g : ndarray, shape (n,)
        The fitted lobe per unit Ks.
    ks : ndarray, shape (3,)
        The fitted lobe's Ks per channel.
    sigma : float
        Torrance–Sparrow σ, radians.

    Returns
    -------
    ndarray, shape (3,)
        NaN when the Torrance–Sparrow lobe is 0 there (σ far too small).
    """
    k = int(np.argmax(g))
    ts = specular_radiance(P[k], N[k], camera, lamp, 1.0, {"model": "torrance_sparrow", "ks": 1.0, "sigma": sigma})
    unit = float(np.asarray(ts).reshape(-1)[0])
    return ks * g[k] / unit if unit > 0 else np.full(3, np.nan)


def _mitsuba() -> ModuleType:
    """Mitsuba in the generator's variant; refused when that variant cannot differentiate (scalar fallback)."""
    from ..generator.llvm import is_scalar, mitsuba

    mi = mitsuba()
    if is_scalar(mi):
        raise UserError(f"method render-compare: needs a Dr.Jit LLVM AD variant, Mitsuba runs {mi.variant()} "
                        "(no libLLVM >= 17 found: set DRJIT_LIBLLVM_PATH)")  # fmt: skip
    return mi


def rank_starts(model: PixelModel, starts: list[tuple[np.ndarray, float]]) -> tuple[list[int], list[float]]:
    """The loss at each start, and the starts in order of increasing loss.

    Parameters
    ----------
    model : PixelModel
        Anything with :meth:`PixelModel.loss_and_grad`.
    starts : list of (ndarray, float)
        Lamp positions (m), shape (3,), and roughness ``alpha``.

    Returns
    -------
    order : list of int
        Indices into ``starts``, least loss first; non-finite losses last, in
        their order.
    losses : list of float
        Relative loss per start (:meth:`PixelModel.loss_and_grad`; NaN or ±inf
        where the lobe is dark or undefined).
    """
    losses = [model.loss_and_grad(lamp, alpha)[0] for lamp, alpha in starts]
    order = np.argsort([v if np.isfinite(v) else np.inf for v in losses], kind="stable")
    return [int(i) for i in order], losses


def fit(model: PixelModel, lamp0: np.ndarray, alpha0: float, *, scale: float, max_iter: int) -> dict:
    """L-BFGS-B over ``(lamp / scale, ln alpha)`` from a start.

    Returns
    -------
    dict
        ``lamp_position``, ``alpha``, ``loss`` (final), ``loss_curve`` (per
        iteration, the start first), ``iterations``, ``evaluations``,
        ``status``, ``message``.
    """
    from scipy.optimize import minimize

    def fun(u: np.ndarray) -> tuple[float, np.ndarray]:
        loss, g_lamp, g_alpha = model.loss_and_grad(u[:3] * scale, np.exp(u[3]))
        if not np.isfinite(loss):
            return np.inf, np.zeros(4)
        return loss, np.concatenate([g_lamp * scale, [g_alpha * np.exp(u[3])]])

    u0 = np.concatenate([lamp0 / scale, [np.log(np.clip(alpha0, *ALPHA_BOUNDS))]])
    curve = [fun(u0)[0]]
    bounds = [(None, None)] * 3 + [tuple(np.log(ALPHA_BOUNDS))]
    res = minimize(fun, u0, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": max_iter},
                   callback=lambda intermediate_result: curve.append(float(intermediate_result.fun)))  # fmt: skip
    return {
        "lamp_position": res.x[:3] * scale, "alpha": float(np.exp(res.x[3])), "loss": float(res.fun),
        "loss_curve": curve, "iterations": int(res.nit), "evaluations": int(res.nfev), "status": int(res.status),
        "message": str(res.message),
    }  # fmt: skip


@forwards(stage_one, fixed={"strict_t_max"})
def render_compare_estimate(
    capture: Capture,
    *,
    bsdf: Choice(LOBES) = "beckmann",
    max_iter: Count = 200,
    max_pixels: Count = 20000,
    saturation: Positive | None = None,
    separation: Choice(SEPARATION_METHODS) = "projected",
    lamp_polarizer: bool = True,
    n_starts: CountOrZero = 6,
    n_fits: Count = 3,
    **init_options,
) -> Estimate:
    """Method ``render-compare``: ``full``'s starts, then fits through a Mitsuba BSDF from the best (see module doc).

    Parameters
    ----------
    capture : Capture
    bsdf : {"beckmann", "ggx", "roughplastic", "pplastic"}
        The Mitsuba lobe fitted (:data:`~nearlight.rendercompare.lobes.LOBES`).
    max_iter : int
        Most L-BFGS-B iterations.
    max_pixels : int
        Largest number of pixels fitted (the brightest, when the surface has more).
    saturation : float, optional
        Drop pixels whose specular reaches this value (clipped sensors).
    separation : {"projected", "fit", "maxmin"}
        Separation of an analyzer stack, as ``full``'s.
    lamp_polarizer : bool
        Model the lamp's polarizer (its axis ``capture.lamp_polarizer_axis``,
        facing the highlight) and predict the polarized part of the specular
        radiance, which is what separation measures; False, a capture
        without the axis, or a lobe that does not polarize
        (``roughplastic``): an unpolarized lamp (``M00``).
    n_starts : int
        Extra starts on ``paper-init``'s peak ray, at ``n_starts`` distances
        log-spaced from 0.1 to 3 × the camera–highlight distance, each with
        the σ of the regression at that distance (``full``'s starts,
        :func:`~nearlight.estimator.pointlamp.peak_ray_starts`). The loss is evaluated at
        every start and at ``paper-init``'s (one forward and backward pass
        each, :func:`rank_starts`); 0: ``paper-init``'s start alone.
    n_fits : int
        L-BFGS-B runs from this many starts of least loss; the fit of least
        final loss is reported. The loss at a start is a weak guide (its σ,
        the regression's, can be 2–3 × too wide: every start's loss within
        15 % of the others' on a ``pplastic`` sphere), the final loss a strong
        one. 3 (default): measured on that sphere, 0.8–2.2 × the run time of
        one fit from ``paper-init``'s start (fits that stall on a plateau stop
        within a few iterations).
    **init_options
        Options of :func:`~nearlight.estimator.first_stage.stage_one` (the start).

    Returns
    -------
    Estimate
        Torrance–Sparrow-equivalent Ks and σ; ``stages["render-compare"]``
        holds the fit reported (BSDF, ``alpha``, Ks of the lobe, its loss
        curve, iterations and evaluations) and the starts (``starts``: each one's lamp, ``alpha``
        and loss, ``paper-init``'s first, and ``fit_loss``, the final loss of
        the fit from it, None when not fitted from; ``start``: the index of
        the fit reported); no covariance.

    Raises
    ------
    UserError
        Bad input (see :func:`~nearlight.estimator.first_stage.stage_one`), or a
        Mitsuba that cannot differentiate (scalar fallback).
    """
    lobe = LOBES[bsdf]
    init, obs = stage_one(capture, strict_t_max=False, separation=separation, **init_options)
    clock = time.perf_counter()
    mi = _mitsuba()
    use = fit_pixels(obs, max_pixels=int(max_pixels), saturation=saturation)
    P, N = obs.P[use], obs.N[use]
    axis = capture.lamp_polarizer_axis if lamp_polarizer and lobe.polarizing else None
    polarizer = None if axis is None else (np.asarray(axis, float), obs.peak_point)
    model = PixelModel(mi, lobe, P, N, obs.camera_position, obs.specular[use], polarizer=polarizer)
    setup = time.perf_counter() - clock
    clock = time.perf_counter()
    starts = [(x[:3], float(np.clip(lobe.alpha(x[6]), *ALPHA_BOUNDS)))
              for x in peak_ray_starts(init, obs, n_starts=int(n_starts))]
    order, losses = rank_starts(model, starts)
    fits = {i: fit(model, *starts[i], scale=obs.scale, max_iter=int(max_iter)) for i in order[:int(n_fits)]}
    best = min(fits, key=lambda i: fits[i]["loss"])  # a fit whose loss is not finite reports inf
    result = fits[best]
    lamp, alpha = result["lamp_position"], result["alpha"]
    g, ks_lobe = model.evaluate(lamp, alpha)
    sigma = lobe.sigma(alpha)
    ks = ts_equivalent_ks(P, N, obs.camera_position, lamp, g, ks_lobe, sigma)
    stage = {
        **result, "bsdf": bsdf, "mitsuba_bsdf": lobe.bsdf, "mitsuba_variant": mi.variant(), "ks_lobe": ks_lobe,
        "sigma": sigma, "ks": ks, "n_pixels": int(use.sum()), "lamp_polarizer": polarizer is not None,
        "starts": [{"lamp_position": lamp0, "alpha": alpha0, "loss": loss0,
                    "fit_loss": fits[i]["loss"] if i in fits else None}
                   for i, ((lamp0, alpha0), loss0) in enumerate(zip(starts, losses))], "start": best,
    }  # fmt: skip
    return Estimate(
        method="render-compare",
        lamp_position=lamp,
        ks=ks,
        sigma=sigma,
        stages={"init": init.stages["init"], "render-compare": stage},
        diagnostics=init.diagnostics,
        timings={**init.timings, "mitsuba_setup": setup, "render-compare": time.perf_counter() - clock},
    )
