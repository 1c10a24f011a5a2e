"""Morris screening of a sample whose runs may fail: elementary effects step by step.

SALib's :func:`SALib.analyze.morris.analyze` needs every run of a trajectory,
so one refusal anywhere drops the whole trajectory; a method that refuses one
capture in four (the paper's first stage on a sphere, ``distant`` on a plane)
then loses nearly every trajectory of 15 runs, and the screening says nothing
about it. Each step of a Morris trajectory moves one input with every other
held, so its elementary effect stands alone: here a step is used when the
method answered at both ends, and left out otherwise.

Per input, over its usable steps (``r`` at most, one per trajectory), with
SALib's conventions: the effect ``(y(x + Δ e_i) − y(x)) / Δ`` in units of the
output per unit of the input's range, ``Δ = p / (2(p − 1))`` on the unit
hypercube for ``p`` levels; ``mu`` its mean, ``mu_star`` the mean of its
absolute value, ``sigma`` its standard deviation (``ddof = 1``), and
``mu_star_conf`` the half-width of the percentile bootstrap interval of
``mu_star`` (``resamples`` resamplings of the input's steps). With every run
answered these are SALib's ``mu``, ``mu_star`` and ``sigma`` exactly (a test);
with refusals they describe the steps the method answered at both ends, which
the ``failed`` output of the same study puts beside them (what made it refuse).
"""

from __future__ import annotations

import numpy as np


def step_effects(X: np.ndarray, Y: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Each trajectory's elementary effect of each input and the row its step starts from.

    Parameters
    ----------
    X : ndarray, shape (r·(k + 1), k)
        SALib's Morris sample (trajectories of ``k + 1`` rows, one input moved per step).
    Y : ndarray, shape (r·(k + 1),)
        The outputs (NaN: no answer).
    levels : int
        The design's grid levels ``p``.

    Returns
    -------
    effects : ndarray, shape (r, k)
        The effect of input ``i`` in trajectory ``t``; NaN where an end of its step has no answer.
    base : ndarray, shape (r, k)
        The index into ``X`` of the row that step starts from.
    """
    r_rows, k = X.shape
    Xt, Yt = X.reshape(-1, k + 1, k), np.asarray(Y, float).reshape(-1, k + 1)
    delta = levels / (2 * (levels - 1))
    dx = np.diff(Xt, axis=1)  # (r, k steps, k inputs): one nonzero input per step
    moved = np.argmax(dx != 0, axis=2)  # (r, k): the input step j moves
    up = np.take_along_axis(dx, moved[..., None], axis=2)[..., 0] > 0
    ee = np.where(up, 1.0, -1.0) * np.diff(Yt, axis=1) / delta  # (r, k steps)
    effects = np.full((Xt.shape[0], k), np.nan)
    base = np.zeros((Xt.shape[0], k), dtype=int)
    rows = np.arange(Xt.shape[0])[:, None] * (k + 1) + np.arange(k)[None, :]
    np.put_along_axis(effects, moved, ee, axis=1)
    np.put_along_axis(base, moved, rows, axis=1)
    return effects, base


def morris_indices(X: np.ndarray, Y: np.ndarray, levels: int, *, resamples: int = 1000, conf_level: float = 0.95,
                   seed: int = 0) -> dict[str, np.ndarray]:  # fmt: skip
    """``mu``, ``mu_star``, ``mu_star_conf``, ``sigma`` and ``steps`` (the usable steps), each shape ``(k,)``: NaN
    for an input with fewer than 2 usable steps (see the module docstring)."""
    effects, _ = step_effects(X, Y, levels)
    k = effects.shape[1]
    rng = np.random.default_rng(seed)
    q = [(1 - conf_level) / 2, (1 + conf_level) / 2]
    out = {key: np.full(k, np.nan) for key in ("mu", "mu_star", "mu_star_conf", "sigma")}
    out["steps"] = np.zeros(k, dtype=int)
    for i in range(k):
        e = effects[:, i][np.isfinite(effects[:, i])]
        out["steps"][i] = e.size
        if e.size < 2:
            continue
        out["mu"][i], out["mu_star"][i], out["sigma"][i] = e.mean(), np.abs(e).mean(), e.std(ddof=1)
        boot = np.abs(e)[rng.integers(e.size, size=(resamples, e.size))].mean(axis=1)
        lo, hi = np.quantile(boot, q)
        out["mu_star_conf"][i] = (hi - lo) / 2
    return out
