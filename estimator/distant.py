"""Method ``distant``: the baseline the paper argues against.

A distant light and a distant viewer: one light direction ``l`` and one view
direction ``v`` for the whole image, so α, θi and θr depend on the normal
only, and the irradiance is the same everywhere (absorbed into Ks):
``I_s = Ks / cos θr · exp(−α² / 2σ²)``. ``v`` points from the specular
pixels' centroid to the camera; ``l``, Ks and σ are fitted (``l`` starts at
the mirror of ``v`` about the peak pixel's normal, Ks and σ at the regression
line of eq. 16–17, or, when every pixel has the same α as on a plane, at the
peak's value and σ = 0.1 rad). A distant light has no position: the reported
``lamp_position`` is the peak's surface point plus ``l`` times the
camera–highlight distance (the distance at which the viewer is also
assumed "distant"), and ``light_model`` holds both directions.
"""

from __future__ import annotations

import time

import numpy as np

from nearlight.capture import Capture
from nearlight.errors import UserError
from nearlight.estimator.fitting import log_regression, robust_fit
from nearlight.estimator.observation import observe
from nearlight.estimator.pixels import fit_pixels
from nearlight.estimator.result import Estimate
from nearlight.reflectance import mirror_direction, normalize, tangent_basis, torrance_sparrow


def distant_specular(N: np.ndarray, light: np.ndarray, view: np.ndarray, ks: np.ndarray, sigma: float) -> np.ndarray:
    """Specular radiance under a distant light and viewer, shape ``(..., 3)``.

    Parameters
    ----------
    N : ndarray, shape (..., 3)
        Unit normals.
    light, view : ndarray, shape (3,)
        Unit directions towards the light and the viewer.
    ks : ndarray, shape (3,)
        Ks, absorbing the irradiance.
    sigma : float
        Roughness, radians.
    """
    h = normalize(light + view)
    cos_i, cos_r = N @ light, N @ view
    alpha = np.arccos(np.clip(N @ h, -1.0, 1.0))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        f = torrance_sparrow(cos_i, cos_r, alpha, ks=ks, sigma=sigma) * cos_i[..., None]
    lit = ((cos_i > 0) & (cos_r > 0))[..., None]
    return np.where(lit, np.nan_to_num(f), 0.0)


def distant_estimate(
    capture: Capture,
    *,
    separation: str = "fit",
    threshold: float = 0.05,
    loss: str = "soft_l1",
    max_pixels: int = 20000,
    saturation: float | None = None,
) -> Estimate:
    """Method ``distant``: fit one light direction, Ks and σ with one view direction.

    Parameters
    ----------
    capture : Capture
    separation, threshold :
        As for ``paper-init`` (:func:`~nearlight.estimator.observation.observe`).
    loss, max_pixels, saturation :
        As for ``full`` (:func:`~nearlight.estimator.full.full_estimate`).
    """
    clock = time.perf_counter()
    obs = observe(capture, separation=separation, threshold=threshold)
    timings = {"observe": time.perf_counter() - clock}
    clock = time.perf_counter()
    m = obs.mask
    view = normalize(obs.camera_position - obs.P[m].mean(axis=0))
    light0 = mirror_direction(obs.N[obs.peak], view)
    e1, e2 = tangent_basis(light0)
    Nm = obs.N[m]
    h0 = normalize(light0 + view)
    cos_r = Nm @ view
    ok = cos_r > 0
    X = 0.5 * np.arccos(np.clip(Nm[ok] @ h0, -1.0, 1.0)) ** 2
    Y = np.log(obs.specular[m][ok]) + np.log(cos_r[ok])[:, None]
    try:
        ks0, sigma0, _ = log_regression(X, Y, where=f"{capture.name}: specular")
    except UserError:
        # A plane under a distant light and viewer has one α everywhere (the
        # paper's point): start from the peak (α = 0 there) and σ = 0.1 rad.
        ks0, sigma0 = obs.specular[obs.peak] * float(obs.N[obs.peak] @ view), 0.1
    timings["init"] = time.perf_counter() - clock
    clock = time.perf_counter()

    use = fit_pixels(obs, max_pixels=int(max_pixels), saturation=saturation)
    N, I = obs.N[use], obs.specular[use]

    def light(x: np.ndarray) -> np.ndarray:
        return normalize(light0 + x[0] * e1 + x[1] * e2)

    def residuals(x: np.ndarray) -> np.ndarray:
        return (distant_specular(N, light(x), view, x[2:5], x[5]) - I).ravel()

    x0 = np.concatenate([[0.0, 0.0], ks0, [sigma0]])
    typical = np.concatenate([[0.1, 0.1], np.abs(ks0) + 1e-12, [sigma0]])
    lower = np.concatenate([[-np.inf, -np.inf], np.zeros(3), [1e-4]])
    upper = np.concatenate([[np.inf, np.inf], np.full(3, np.inf), [np.pi / 2]])
    fit = robust_fit(residuals, x0, typical=typical, lower=lower, upper=upper, loss=loss,
                     f_floor=1e-4 * float(np.max(I)))
    x = fit["x"]
    direction = light(x)
    lamp = obs.peak_point + obs.scale * direction
    timings["fit"] = time.perf_counter() - clock
    return Estimate(
        method="distant",
        lamp_position=lamp,
        ks=x[2:5],
        sigma=x[5],
        stages={
            "init": {"light_direction": light0, "ks": ks0, "sigma": sigma0},
            "fit": {"light_direction": direction, "ks": x[2:5], "sigma": x[5], "n_pixels": int(use.sum()),
                    **{k: fit[k] for k in ("f_scale", "cost", "nfev", "status", "rms")}},
        },
        diagnostics={"peak_pixel": list(obs.peak), "n_specular_pixels": int(m.sum())},
        timings=timings,
        light_model={"type": "distant", "light_direction": direction, "view_direction": view},
    )
