"""Shared numerical pieces: the log-linear regression and a robust least-squares fit."""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import ThreadpoolController

from ..errors import UserError


def log_regression(X: np.ndarray, Y: np.ndarray, *, where: str = "specular") -> tuple[np.ndarray, float, np.ndarray]:
    """Ks and σ from the regression line ``Y_m = −X/σ² + ln Ks,m`` (paper eq. 11, 16–17).

    Parameters
    ----------
    X : ndarray, shape (n,)
        ``α²/2`` per pixel.
    Y : ndarray, shape (n, 3)
        ``ln E_m + ln cos θr`` per pixel and channel.
    where : str
        Name for error messages.

    Returns
    -------
    ks : ndarray, shape (3,)
        ``exp(b_m)``.
    sigma : float
        Mean over channels of ``sqrt(−1/a_m)``.
    sigma_rgb : ndarray, shape (3,)

    Raises
    ------
    UserError
        When a slope is not negative (no specular lobe in the data).
    """
    xc = X - X.mean()
    sxx = float(xc @ xc)
    slope = (xc @ (Y - Y.mean(axis=0))) / sxx if sxx > 0 else np.zeros(Y.shape[1])
    intercept = Y.mean(axis=0) - slope * X.mean()
    if not np.all(slope < 0):
        m = "RGB"[int(np.argmax(slope >= 0))]
        raise UserError(
            f"{where}: channel {m}: regression slope {slope[int(np.argmax(slope >= 0))]:.3g} is not negative "
            "(the specular pixels do not fall off away from the mirror direction)"
        )
    sigma_rgb = np.sqrt(-1.0 / slope)
    return np.exp(intercept), float(sigma_rgb.mean()), sigma_rgb


def central_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Central-difference Jacobian ``[n_outputs, n_params]`` with per-parameter steps.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> ndarray`` of any shape (flattened to n_outputs).
    x : array_like, shape (n_params,)
    step : array_like, shape (n_params,) or scalar
        Difference step per parameter, in the parameter's units.
    """
    x = np.asarray(x, dtype=float)
    step = np.broadcast_to(np.asarray(step, dtype=float), x.shape)
    cols = []
    for i, h in enumerate(step):
        dx = np.zeros_like(x)
        dx[i] = h
        cols.append((np.ravel(fun(x + dx)) - np.ravel(fun(x - dx))) / (2.0 * h))
    return np.stack(cols, axis=1)


def robust_fit(*args, **kwargs) -> dict:
    """:func:`_robust_fit` with single-threaded BLAS.

    Its matrices are tall and thin (n × ≤ 7): threads buy nothing there, and
    on a machine whose cores are busy, OpenBLAS's spinning threads made each
    SVD 20–40 times slower (measured: 46 ms vs 0.9 ms for 5400 × 7).
    """
    with single_threaded_blas():
        return _robust_fit(*args, **kwargs)


def single_threaded_blas():
    """Context manager: the BLAS libraries numpy and scipy loaded, limited to one thread.

    The libraries are found once (:func:`_blas`): a fresh scan,
    ``threadpoolctl.threadpool_limits``, costs ~1.5 ms, and ``full`` enters
    this ten times or more per capture.
    """
    return _blas().limit(limits=1, user_api="blas")


@functools.cache
def _blas() -> ThreadpoolController:
    return ThreadpoolController()


def _robust_fit(
    fun: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    *,
    typical: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    loss: str = "soft_l1",
    f_scale: float | None = None,
    jac: Callable[[np.ndarray], np.ndarray] | None = None,
    f_floor: float = 0.0,
    max_nfev: int = 200,
    start_is_fit: bool = False,
    tol: float = 1e-12,
    prior_rows: int = 0,
    prior_var: float = 1.0,
) -> dict:
    """Robust nonlinear least squares with a sandwich covariance.

    Two passes of :func:`scipy.optimize.least_squares` (trust-region
    reflective): the first with a loss scale from the starting residuals, the
    second with ``f_scale = 3 × 1.4826 · MAD`` of the first pass's residuals,
    so that pixels more than ~3 noise standard deviations off (outliers,
    saturation) are down-weighted. When the start is itself a least-squares
    fit (``start_is_fit``: ``full``'s final fit starts from a fit on a
    subset of its pixels), its residuals already measure the noise: one
    pass, with the scale from the start's residuals. The covariance is the M-estimator sandwich
    ``A⁻¹ B A⁻¹ · n/(n − p)`` with ``A = Σ ψ'(ρ) J Jᵀ``, ``B = Σ ψ(ρ)² J Jᵀ``;
    for Gaussian noise and a linear loss it is ``s² (JᵀJ)⁻¹``.

    Parameters
    ----------
    fun : callable
        Residuals ``(params,) -> (n,)``.
    x0 : ndarray, shape (p,)
    typical : ndarray, shape (p,)
        Typical magnitude of each parameter (finite-difference steps, scaling).
    lower, upper : ndarray, shape (p,)
        Bounds.
    loss : str
        ``least_squares`` loss (``linear``, ``soft_l1``, ``huber``, ``cauchy``).
    f_scale : float or None
        Fixed loss scale (residual units); None: the two-pass estimate above.
    jac : callable, optional
        Jacobian ``(params,) -> (n, p)``; default central differences with
        steps ``1e-6 × typical``.
    f_floor : float
        Smallest loss scale (keeps noise-free fits quadratic, so they converge fast).
    max_nfev : int
        Evaluation budget per pass.
    start_is_fit : bool
        ``x0`` is a least-squares fit (of these residuals or a subset of
        them): one pass, ``f_scale = 3 × 1.4826 · MAD`` of the residuals at ``x0``.
    tol : float
        ``least_squares``' ``xtol``, ``ftol`` and ``gtol``.
    prior_rows : int
        The last this many residuals are a Gaussian prior's whitened terms
        (``full``'s joint fit: the range's information about the surface), not
        observations: in the sandwich's ``B`` each counts with its expected
        square ``prior_var`` instead of its own (one draw of a few terms is no
        estimate of their variance: a prior term that happens to be small
        would shrink the covariance).
    prior_var : float
        Expected square of each prior term (the observations' residual variance).

    Returns
    -------
    dict
        ``x``, ``cov`` (p × p), ``f_scale``, ``cost``, ``nfev``, ``status``, ``rms``.
    """
    if jac is None:
        step = 1e-6 * np.asarray(typical, dtype=float)

        def jac(x: np.ndarray) -> np.ndarray:
            return central_jacobian(fun, x, step)

    last: dict[str, np.ndarray] = {}

    def kept(x: np.ndarray) -> np.ndarray:
        # the solver's last Jacobian is at its answer (it evaluates one after every accepted step): kept (a copy,
        # whatever the solver does with its own) for the covariance, not computed again
        J = jac(x)
        last["x"], last["J"] = np.array(x, dtype=float), np.array(J, dtype=float)
        return J

    def solve(x: np.ndarray, scale: float) -> object:
        return least_squares(
            fun, x, jac=kept, bounds=(lower, upper), loss=loss, f_scale=scale,
            x_scale=np.asarray(typical, dtype=float), method="trf", xtol=tol, ftol=tol, gtol=tol,
            max_nfev=max_nfev,
        )

    r0 = fun(x0)
    floor = max(f_floor, 1e-9 * max(float(np.max(np.abs(r0))), 1e-300))
    if f_scale is not None:
        scales = [f_scale]
    else:
        scales = [max(3.0 * _mad(r0), floor)] if start_is_fit else [max(_mad(r0), floor), None]
    res, nfev = None, 0
    for s in scales:
        if s is None:
            s = max(3.0 * _mad(res.fun), floor)
        res = solve(res.x if res is not None else np.asarray(x0, dtype=float), s)
        nfev += res.nfev
    J = last["J"] if "x" in last and np.array_equal(last["x"], res.x) else jac(res.x)
    rho = res.fun
    n, p = J.shape
    if loss == "linear":
        psi, dpsi = rho, np.ones_like(rho)
    else:
        z = (rho / s) ** 2
        d1, d2 = _LOSS_DERIVATIVES[loss](z)
        psi, dpsi = d1 * rho, d1 + 2.0 * z * d2
    if prior_rows:
        psi = np.concatenate([psi[:-prior_rows], np.full(prior_rows, np.sqrt(prior_var))])
    A = J.T @ (dpsi[:, None] * J)
    B = J.T @ ((psi**2)[:, None] * J)
    try:
        Ainv = np.linalg.inv(A)
        cov = Ainv @ B @ Ainv * (n / max(n - p, 1))
    except np.linalg.LinAlgError:
        cov = np.full((p, p), np.nan)
    return {
        "x": res.x, "cov": cov, "f_scale": float(s), "cost": float(res.cost), "nfev": int(nfev),
        "status": int(res.status), "rms": float(np.sqrt(np.mean(rho**2))),
    }


def _mad(r: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


#: The losses :func:`robust_fit` takes: :func:`scipy.optimize.least_squares`' own.
LOSSES = ("huber", "soft_l1", "linear", "cauchy", "arctan")
#: ρ'(z) and ρ''(z) of scipy's losses, z = (residual / f_scale)².
_LOSS_DERIVATIVES: dict[str, Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]] = {
    "soft_l1": lambda z: ((1 + z) ** -0.5, -0.5 * (1 + z) ** -1.5),
    "huber": lambda z: (np.where(z <= 1, 1.0, np.maximum(z, 1.0) ** -0.5),
                        np.where(z <= 1, 0.0, -0.5 * np.maximum(z, 1.0) ** -1.5)),
    "cauchy": lambda z: (1 / (1 + z), -1 / (1 + z) ** 2),
    "arctan": lambda z: (1 / (1 + z**2), -2 * z / (1 + z**2) ** 2),
}
