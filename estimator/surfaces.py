"""Surface points and normals fitted to the range data: one surface where one fits, else windows the noise chooses.

What every method's :class:`~nearlight.estimator.observation.Observation`
takes when a capture has no normals
(:func:`~nearlight.estimator.geometry.surface_geometry`); tested in
``tests/estimator/test_surfaces.py``, measured by
``benchmarks/bench_surfaces.py`` and ``benchmarks/bench_range_bound.py``.

Why inverse depth over pixels
-----------------------------
A pinhole camera's unnormalised rays are affine in the pixel coordinates,
``R(c, r) = M·[c, r, 1]`` (:func:`pinhole_matrix`; columns ``c``, rows ``r``,
pixel centres at ``k + 0.5``), and a plane ``m·X = κ`` seen through them has an
inverse depth ``f = 1/((X − o)·n)`` (``n`` the optical axis, ``o`` the camera)
that is *affine* in ``(c, r)``. So a fit of ``f`` over pixel offsets has
regressors without error (a range sensor's error moves ``P`` along the ray,
never across it), is exact on planes at any window size, and gives the
tangent plane from ``f``'s value and gradient at the pixel:
``m ∝ M⁻ᵀ [f_c, f_r, f − c f_c − r f_r]`` (:func:`_normal`).

The rooms
---------
:mod:`~nearlight.estimator.range_error` (what the range's error is),
:mod:`~nearlight.estimator.pinhole` (the rays' pinhole),
:mod:`~nearlight.estimator.whole_surface` (one plane, sphere or quadric
through every pixel, tried first, simplest first) and
:mod:`~nearlight.estimator.local_windows` (windows per pixel, when none fits).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.ndimage import distance_transform_cdt

from . import local_windows, whole_surface
from .pinhole import optical_axis, pinhole_matrix
from .range_error import RangeModel, measured_range
from .whole_surface import SurfaceParameters

__all__ = ["FittedSurface", "RangeModel", "SurfaceParameters", "fit_surface", "measured_range", "optical_axis", "pinhole_matrix"]

#: Relative precision of float32 ``P`` (half an ulp over √3): the noise floor of an exact range.
FLOAT32_FLOOR = 2.0**-24 / np.sqrt(3.0)

#: Below this cosine between normal and view, a normal is refitted in its own tangent frame (:func:`tangent_fit`).
GRAZING = 0.5


def _normal(M: np.ndarray, f0: np.ndarray, gc: np.ndarray, gr: np.ndarray, cc: np.ndarray, rr: np.ndarray
            ) -> np.ndarray:
    """Unit normals ``M⁻ᵀ [f_c, f_r, f − c f_c − r f_r]`` (not yet oriented), shape ``f0.shape + (3,)``."""
    v = np.stack([gc, gr, f0 - cc * gc - rr * gr], axis=-1)
    m = v @ np.linalg.inv(M)  # (M⁻ᵀ v)ᵀ = vᵀ M⁻¹
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


@dataclasses.dataclass(frozen=True)
class FittedSurface:
    """Points and normals fitted to a range image (:func:`fit_surface`).

    Attributes
    ----------
    P : ndarray, shape (H, W, 3)
        The fitted surface's points, metres (the range with its noise fitted
        away; at grazing pixels refitted in their tangent frame, the measured
        point); NaN where no fit.
    N : ndarray, shape (H, W, 3)
        Unit normals towards the camera; NaN where no fit.
    sd_rad : ndarray, shape (H, W)
        Standard deviation of each normal's direction from the range noise,
        radians (the two tilts' in quadrature); NaN where no fit.
    half_width : ndarray of int, shape (H, W)
        Half-width of the window each normal came from (0: no window; −1:
        the whole plane; −2: the whole quadric; −3: the whole sphere).
    model : RangeModel
        The range error the fit assumed.
    kind : {"plane", "sphere", "quadric", "local"}
        One plane fitted the whole surface, one sphere, one quadric, or none
        (windows per pixel).
    parameters : SurfaceParameters or None
        A whole plane's or sphere's parameters with their covariance (what
        ``full``'s joint fit refines); None for a quadric and local windows.
    """

    P: np.ndarray
    N: np.ndarray
    sd_rad: np.ndarray
    half_width: np.ndarray
    model: RangeModel
    kind: str
    parameters: SurfaceParameters | None = None

    @property
    def plane(self) -> bool:
        """Whether one plane fitted the whole surface."""
        return self.kind == "plane"


def fit_surface(P: np.ndarray, camera_position: np.ndarray, rays: np.ndarray, *, model: RangeModel | None = None,
                valid: np.ndarray | None = None) -> FittedSurface:
    """Points and normals of the surface fitted to the range image ``P`` (see the module docstring).

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
        World positions, metres; NaN where no surface.
    camera_position : ndarray, shape (3,)
    rays : ndarray, shape (H, W, 3)
        Unit rays through the pixel centres (a pinhole's).
    model : RangeModel, optional
        The range's error; default: :func:`measured_range`.
    valid : ndarray of bool, shape (H, W), optional
        Pixels with a position (default: finite ``P``).

    Returns
    -------
    FittedSurface
    """
    P = np.asarray(P, dtype=float)
    cam = np.asarray(camera_position, dtype=float)
    valid = np.all(np.isfinite(P), axis=-1) if valid is None else valid
    H, W = valid.shape
    M = pinhole_matrix(rays)
    axis = optical_axis(M)
    rel = np.where(valid[..., None], P - cam, 0.0)
    z = rel @ axis
    valid = valid & (z > 0)
    if model is None:
        model = measured_range(P, cam, valid, axis)
    zs = np.where(valid, z, 1.0)
    dist = np.linalg.norm(rel, axis=-1)
    # the depth's noise along z: along the ray it is foreshortened by z/d
    to_z = 1.0 if model.axis == "z" else np.where(valid, zs / np.maximum(dist, 1e-300), 1.0)
    floor = FLOAT32_FLOOR * float(np.max(np.abs(P[valid]))) if valid.any() else 0.0
    sz = np.hypot(model.equivalent_sigma_m * to_z, floor)
    f = np.where(valid, 1.0 / zs, 0.0)
    sf = sz / zs**2  # the inverse depth's standard deviation
    rr, cc = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")

    plane = whole_surface.one_plane(f, sf, valid, cc, rr, jackknife=not model.quantum_m > 0)
    if plane is not None:
        return _whole_plane(P, valid, cam, rays, model, floor, *plane)
    # the simplest family that fits within the noise: a sphere's 4 parameters before a quadric's 9
    for kind, code, fitter in (("sphere", -3, whole_surface.one_sphere), ("quadric", -2, whole_surface.one_quadric)):
        whole = fitter(P, valid, rays, cam, model, floor)
        if whole is not None:
            Pq, Nq, sdq, parameters = whole
            return FittedSurface(P=Pq, N=Nq, sd_rad=sdq, half_width=np.where(valid, code, 0), model=model,
                                 kind=kind, parameters=parameters)
    # per pixel: f's value and gradient (per pixel) at the centre, the gradient's s.d. per component, the window
    fit = np.full((H, W, 4), np.nan)
    half = np.zeros((H, W), int)
    Xw, Nw = local_windows.fitted_windows(f, sf, valid, model, zs, P, fit, half)
    done = np.isfinite(fit[..., 0])
    sd = np.full((H, W), np.nan)
    f0, gc, gr, sg = fit[done].T
    x, y = cc[done], rr[done]
    n0 = _normal(M, f0, gc, gr, x, y)
    # each tilt's standard deviation: the angle a one-s.d. change of each gradient component turns the normal by
    turn = [np.arccos(np.clip(np.sum(n0 * _normal(M, f0, gc + dc * sg, gr + dr * sg, x, y), axis=-1), -1.0, 1.0))
            for dc, dr in ((1.0, 0.0), (0.0, 1.0))]
    sd[done] = np.hypot(*turn)
    Pf, N = Xw, np.where(done[..., None], Nw, np.nan)
    flip = np.sum(np.nan_to_num(N) * -rel, axis=-1) < 0
    N[flip] = -N[flip]
    view = -rel / np.maximum(dist, 1e-300)[..., None]
    # where the inverse depth bends towards a silhouette's singularity: grazing, and near the silhouette
    # for the window the pixel took
    edge = distance_transform_cdt(valid, metric="chessboard")
    grazing = done & (np.sum(np.nan_to_num(N) * view, axis=-1) < GRAZING) & (edge <= 2 * np.abs(half) + 4)
    if grazing.any():
        N[grazing] = local_windows.tangent_fit(P, valid, N, grazing,
                                               np.clip(half[grazing], 2, local_windows.TANGENT_MAX))
        Pf[grazing] = P[grazing]  # the inverse depth's value is what bends there: keep the measured point
    return FittedSurface(P=Pf, N=N, sd_rad=sd, half_width=half, model=model, kind="local")


def _whole_plane(P: np.ndarray, valid: np.ndarray, cam: np.ndarray, rays: np.ndarray, model: RangeModel,
                 floor: float, abc: np.ndarray, cov_abc: np.ndarray) -> FittedSurface:
    """The whole plane :func:`~nearlight.estimator.whole_surface.one_plane` found (inverse-depth coefficients
    ``abc`` and their covariance): fitted to the points in space, each normal's s.d. that of the plane's.

    The pixel-grid fit's plane ``m₀ = M⁻ᵀ Π abc`` (see :func:`_plane_parameters`) weighs the points
    (:func:`~nearlight.estimator.whole_surface.plane_in_space`); one plane has one normal, so its s.d. is the
    same at every pixel: the angle of the normal ``m/|m|`` under ``C_m`` (the range fit's, the staircase's
    included), ``√tr(Π⊥ C_m Π⊥)/|m|`` with ``Π⊥ = I − n nᵀ``.
    """
    T = np.linalg.inv(pinhole_matrix(rays)).T[:, [2, 0, 1]]  # M⁻ᵀ Π: [a, b, c'] -> m
    m0 = T @ abc
    Pf, N = whole_surface.plane_in_space(P, valid, cam, m0 / np.linalg.norm(m0), rays, model, floor)
    parameters = _plane_parameters(P, Pf, N, valid, cam, rays, model, floor, T @ cov_abc @ T.T)
    sd = np.full(valid.shape, np.nan)
    if parameters is not None:
        m = parameters.g
        across = np.eye(3) - np.outer(m, m) / (m @ m)
        sd[valid] = np.sqrt(max(float(np.trace(across @ parameters.cov @ across)), 0.0)) / np.linalg.norm(m)
    return FittedSurface(P=Pf, N=N, sd_rad=sd, half_width=np.where(valid, -1, 0), model=model, kind="plane",
                         parameters=parameters)


def _plane_parameters(P: np.ndarray, Pf: np.ndarray, N: np.ndarray, valid: np.ndarray, cam: np.ndarray,
                      rays: np.ndarray, model: RangeModel, floor: float, cov_m: np.ndarray
                      ) -> SurfaceParameters | None:
    """The whole plane as ``m·(X − cam) = 1`` with its covariance.

    ``m`` is that of the fitted points ``Pf`` and normals ``N``
    (:func:`~nearlight.estimator.whole_surface.plane_in_space`'s, what every
    method sees). Its covariance carries over that of
    :func:`~nearlight.estimator.whole_surface.one_plane`'s inverse-depth
    coefficients: with ``R = M·[c, r, 1]`` (``R·axis = 1``, :func:`pinhole_matrix`), a
    point ``cam + z R`` of the plane has inverse depth ``f = 1/z = m·R``, so
    ``f = a + b c + c' r`` has ``[b, c', a] = Mᵀ m``: ``m = M⁻ᵀ Π [a, b, c']`` (``Π``
    the reordering) and ``C_m = M⁻ᵀ Π C Πᵀ M⁻¹`` (``cov_m``, from :func:`_whole_plane`). On a quantised range, that
    plus the staircase's simulated one
    (:func:`~nearlight.estimator.whole_surface.staircase_cov`, for the fit of
    the points in space as ``plane_in_space`` makes it).
    """
    on = valid & np.isfinite(Pf[..., 0])  # the normal is one for all; a point is NaN where its ray is parallel
    if not on.any():
        return None
    i, j = np.argwhere(on)[0]
    n = N[i, j]
    m = n / float(n @ (Pf[i, j] - cam))
    cov = cov_m
    if model.quantum_m > 0:
        u = whole_surface.directions(P[on], cam)
        t = 1.0 / (u @ m)  # the fitted plane along each pixel's ray
        along = whole_surface.axis_cosine(u, rays, model)
        w = 1.0 / whole_surface.normal_noise(np.broadcast_to(n, u.shape), u, along, model, floor)
        # the weighted distance to the plane w (m·(X − cam) − 1)/|m|: its Jacobian in m, and its change per metre
        # of reading error along the axis (the point moves by e/along along its ray)
        J = (w * t)[:, None] * u / np.linalg.norm(m)
        sens = w * (u @ m) / np.linalg.norm(m) / along
        cov = cov + whole_surface.staircase_cov(J, sens, t * along, model)
    return SurfaceParameters("plane", m, cov)
