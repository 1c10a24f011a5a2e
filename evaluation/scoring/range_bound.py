"""The Cramér–Rao bound when the range is noisy too: lamp, reflectance and the surface's parameters together.

:func:`nearlight.evaluation.scoring.crlb.specular_crlb` takes the surface as
exact. A real range sensor's error (``nearlight.generator.range_sensor``)
makes the surface a parameter as well: here ``θ = (lamp x, y, z, colour r,
g, b, roughness, s)`` with ``s`` the surface's own parameters, and two sets
of observations with independent Gaussian noise:

* the specular radiance ``Is`` of each counted pixel, with the variance the
  analyzer stack gives it (:func:`~nearlight.evaluation.scoring.crlb.specular_variance_factor`),
  its point and normal those of the surface ``s`` on the pixel's ray;
* the range of every surface pixel: its depth along the ray or along the
  optical axis, where the surface ``s`` meets the pixel's ray, with the range
  noise's variance ``σ²``.

The Fisher information is the sum of the two (the observations stacked,
:func:`_equilibrated_bound`); the bound on the lamp is the lamp block of its inverse. Its
surface families are those a closed-form capture has: a **plane**
(``m·X = 1``, three parameters) and a **sphere** (centre and radius, four),
identified from the capture's exact ``P`` (:func:`surface_family`); any other
surface has no bound here and says so.

**Quantisation** (a staircase, not noise) is bounded by the equivalent
noise of the grid's offset drawn per seed: a uniform error over one step,
variance ``q²/12`` (:attr:`nearlight.estimator.surfaces.RangeModel.equivalent_sigma_m`),
independent between pixels. It is a model, stated as one: a staircase's
errors are correlated over each terrace, so the bound is optimistic where
terraces span many pixels (a surface nearly square to the axis the steps
are taken along).

The truth's ``θ``, the specular radiance's variance and the columns are
:mod:`~nearlight.evaluation.scoring.crlb`'s (one home each); a sweep's CRLB
columns are this bound wherever the task's range is noisy or quantised
(:func:`nearlight.evaluation.engine.tasks.run_task`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...estimator.fitting import central_jacobian
from ...estimator.geometry import capture_rays
from ...estimator.whole_surface import on_rays
from ...physics.reflectance import specular_radiance
from .crlb import bound_columns, specular_variance, truth_parameters

#: A family fits the exact ``P`` when its RMS residual is below this, metres (float32 ``P``: ~3e-8 m).
EXACT = 1e-6


#: Largest condition number of the column-equilibrated Fisher matrix that is inverted (beyond: a parameter the
#: data do not determine).
MAX_CONDITION = 1e12


def _equilibrated_bound(model, theta: np.ndarray, noise_var: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """``F⁻¹`` for independent Gaussian observations, its columns scaled to unit diagonal before inverting.

    :func:`nearlight.evaluation.scoring.crlb.crlb` inverts ``F`` as it is;
    here the parameters mix units whose information differs by ten orders
    (a plane's ``m`` in 1/m fixed by 10⁵ range pixels beside a colour), so
    its raw condition number says nothing about whether it is determined:
    the equilibrated matrix's does.
    """
    J = central_jacobian(model, theta, steps) / np.sqrt(noise_var)[:, None]
    F = J.T @ J
    d = np.sqrt(np.diag(F))
    if not (np.all(np.isfinite(F)) and np.all(d > 0)):
        return np.full_like(F, np.nan)
    E = F / np.outer(d, d)
    if np.linalg.cond(E) > MAX_CONDITION:
        return np.full_like(F, np.nan)
    return np.linalg.inv(E) / np.outer(d, d)


def surface_family(P: np.ndarray, origin: np.ndarray) -> tuple[str, np.ndarray] | None:
    """``("plane", m)`` or ``("sphere", [cx, cy, cz, R])`` when the points ``P`` (n, 3) lie on one within
    :data:`EXACT`, else None.

    The plane as ``m·(X − origin) = 1`` (``origin`` the camera, which is
    never on a plane it sees, so ``m`` is finite), from the points'
    principal axes; the sphere by least squares of
    ``|X|² = 2c·X + (R² − |c|²)``, linear in ``c`` and that constant.
    """
    P = np.asarray(P, dtype=float)
    if len(P) < 10:
        return None
    ref = P.mean(axis=0)
    Q = P - ref
    normal = np.linalg.svd(Q, full_matrices=False)[2][-1]
    if np.sqrt(np.mean((Q @ normal) ** 2)) < EXACT:
        d = float(normal @ (ref - np.asarray(origin, dtype=float)))
        if abs(d) > 0:
            return "plane", normal / d
    A = np.column_stack([2 * Q, np.ones(len(P))])
    sol = np.linalg.lstsq(A, np.sum(Q * Q, axis=1), rcond=None)[0]
    c = sol[:3]
    R = float(np.sqrt(sol[3] + c @ c))
    if np.sqrt(np.mean((np.linalg.norm(Q - c, axis=1) - R) ** 2)) < EXACT:
        return "sphere", np.concatenate([c + ref, [R]])
    return None


def range_crlb(capture: Any, *, noise_var: np.ndarray, range_sigma_m: float, axis: str = "ray",
               pixels: np.ndarray | None = None) -> dict[str, Any]:
    """The bound on the lamp and the roughness with the camera noise and the range noise together.

    Parameters
    ----------
    capture : Capture
        Noise-free capture with ``stack``, ``N`` (exact) and ``truth``, one lamp, one of
        :data:`nearlight.physics.reflectance.LOBES`' families.
    noise_var : ndarray, shape (K, H, W, 3) or (H, W, 3) or float
        Variance of the camera noise of each analyzer image pixel (radiance²).
    range_sigma_m : float
        Standard deviation of the range noise, metres (for a quantum ``q``: ``q/√12``); > 0.
    axis : {"ray", "z"}
        What the range measures: the distance along each ray, or the depth along the optical axis.
    pixels : ndarray of bool, shape (H, W), optional
        The pixels whose specular radiance the bound counts (default: every
        surface pixel); the range counts every surface pixel.

    Returns
    -------
    dict
        ``crlb_lamp_m`` (``sqrt(trace)`` of the lamp block, metres),
        ``crlb_sigma_rel`` (roughness s.d. over the roughness), ``family``
        (``"plane"`` or ``"sphere"``); or ``{"crlb_lamp_m": nan, ...,
        "reason": ...}`` when the surface is neither.
    """
    if not range_sigma_m > 0:
        raise ValueError(f"range_sigma_m must be > 0, got {range_sigma_m}")
    if axis not in ("ray", "z"):
        raise ValueError(f"axis must be 'ray' or 'z', got {axis!r}")
    bsdf, lobe, lamp, colour, rough = truth_parameters(capture)
    surface = capture.object_mask
    cam = np.asarray(capture.camera.position, float)
    found = surface_family(np.asarray(capture.P, float)[surface], cam)
    if found is None:
        return {"crlb_lamp_m": np.nan, "crlb_sigma_rel": np.nan, "family": None,
                "reason": "the surface is neither a plane nor a sphere: no parametric bound"}
    family, s0 = found
    counted = surface & (np.ones_like(surface) if pixels is None else pixels)
    rays = capture_rays(capture)
    axis_vec = np.asarray(capture.camera.to_world, float)[:3, 2] if axis == "z" else None
    var_is = specular_variance(capture, counted, noise_var).ravel()
    r_counted, r_all = rays[counted], rays[surface]
    to_depth = 1.0 if axis_vec is None else r_all @ axis_vec  # depth along z = distance · cos

    def model(theta: np.ndarray) -> np.ndarray:
        s = theta[7:]
        t, n = on_rays(family, s, cam, r_counted)
        P = cam + t[:, None] * r_counted
        b = {"model": bsdf["model"], lobe.colour_key: theta[3:6], lobe.roughness_key: theta[6]}
        Is = specular_radiance(P, n, cam, theta[:3], 1.0, b).ravel()
        depth = on_rays(family, s, cam, r_all)[0] * to_depth
        return np.concatenate([Is, depth])

    theta = np.concatenate([lamp, colour, [rough], s0])
    scale = float(np.linalg.norm(lamp - capture.P[surface].mean(axis=0)))
    s_steps = 1e-7 * (np.maximum(np.abs(s0), 1e-3) if family == "sphere" else np.full(3, np.linalg.norm(s0)))
    steps = np.concatenate([np.full(3, 1e-6 * scale), 1e-6 * np.maximum(colour, 1e-12), [1e-6 * rough], s_steps])
    noise = np.concatenate([var_is, np.full(int(surface.sum()), float(range_sigma_m) ** 2)])
    return {**bound_columns(_equilibrated_bound(model, theta, noise, steps), rough), "family": family}
