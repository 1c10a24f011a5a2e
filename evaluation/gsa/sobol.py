"""Sobol' indices of a Saltelli sample: SALib's estimators, percentile bootstrap intervals, and a chance floor.

The point estimates are SALib's (:func:`SALib.analyze.sobol.first_order`,
Saltelli et al. 2010, and :func:`~SALib.analyze.sobol.total_order`, Jansen
1999) on the outputs standardised as SALib does. The intervals are
**percentile** bootstrap intervals: the ``(1 - conf)/2`` and ``(1 + conf)/2``
quantiles of the index over ``resamples`` resamplings of the base samples
(rows of A, B and every A_B^i together), drawn here with the design's seed so
a run is reproducible whatever the seed (SALib draws unseeded resamples for
seed 0) and the floor below is resampled with the very same rows. SALib's own
half-width (``Z·std`` of the resamples) assumes a normal sampling distribution,
which an index near 0 or 1 does not have.

**The floor** answers "how large can an index come out by chance at this N,
for these outputs?". A dummy input that the model does not read gets
``S1 = ST = 0`` exactly from these estimators (``f(A_B^d) = f(A)``), which
says nothing. The floor is the index of such a dummy computed instead with the
estimators of Khorashadi Zadeh et al. (2017), as R's ``sensobol::sobol_dummy``
(Puy et al. 2022) does: they use ``f(A)`` and ``f(B)`` only, so sampling noise
does not cancel,

    f0  = (1/N) Σ fA·fB
    V   = 1/(2N−1) Σ (fA² + fB²) − f0
    S1d = ((1/(N−1)) Σ fA·fB − f0) / V
    STd = 1 − ((1/(N−1)) Σ fB² − f0) / V,

and the floor of each index is the upper end of the dummy's percentile
interval. An input's index is *distinguishable from zero* when the lower end
of its own interval lies above that floor; otherwise the report says "not
distinguishable from zero" and does not rank it. The floor is > 0 for any
output that varies, shrinks as 1/√N, and costs no model run.

References: Saltelli et al. (2010), Comput. Phys. Commun. 181, 259-270;
Khorashadi Zadeh et al. (2017), Environ. Model. Softw. 91, 210-222; Puy et al.
(2022), J. Stat. Softw. 102(5).
"""

from __future__ import annotations

import math

import numpy as np

#: The index kinds, in the order of the columns.
KINDS = ("S1", "ST")


def split(Y: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``f(A)``, ``f(B)`` shape ``(N,)`` and ``f(A_B^i)`` shape ``(N, k)`` of a Saltelli sample's outputs
    (SALib's order: blocks of ``k + 2`` rows ``A, A_B^1 … A_B^k, B``), standardised as SALib does."""
    Y = np.asarray(Y, dtype=float)
    Y = (Y - Y.mean()) / Y.std()
    blocks = Y.reshape(-1, k + 2)
    return blocks[:, 0], blocks[:, -1], blocks[:, 1:-1]


def dummy_indices(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dummy's ``S1`` and ``ST`` (module docstring) from ``A``, ``B`` of shape ``(N, ...)``: each ``(...)``."""
    N = A.shape[0]
    f0 = (A * B).sum(axis=0) / N
    V = (A * A + B * B).sum(axis=0) / (2 * N - 1) - f0
    with np.errstate(divide="ignore", invalid="ignore"):  # V = 0 (a resample of constant outputs): NaN, no floor
        S1 = ((A * B).sum(axis=0) / (N - 1) - f0) / V
        ST = 1 - ((B * B).sum(axis=0) / (N - 1) - f0) / V
    return np.where(V > 0, S1, np.nan), np.where(V > 0, ST, np.nan)


def sobol_indices(Y: np.ndarray, k: int, *, resamples: int = 1000, conf_level: float = 0.95,
                  seed: int = 0) -> dict[str, np.ndarray]:  # fmt: skip
    """First-order and total indices of ``k`` inputs with percentile intervals and the chance floor.

    Parameters
    ----------
    Y : ndarray, shape (N·(k + 2),)
        The outputs of a Saltelli sample in SALib's order, all finite and not all equal (every index NaN when
        those of A and B are all equal: no variance to share out).
    k : int
        Inputs.
    resamples : int
        Bootstrap resamplings of the N base samples.
    conf_level : float
        Confidence of the intervals.
    seed : int
        Seed of the resampling.

    Returns
    -------
    dict
        ``S1``, ``ST`` shape ``(k,)``; ``S1_lo``, ``S1_hi``, ``ST_lo``, ``ST_hi`` the percentile interval;
        ``S1_conf``, ``ST_conf`` its half-width ``(hi − lo)/2``; ``S1_floor``, ``ST_floor`` (scalars) the upper
        end of the dummy's interval.
    """
    from SALib.analyze.sobol import first_order, total_order

    A, B, AB = split(Y, k)
    N = A.shape[0]
    if np.ptp(np.r_[A, B]) == 0:  # A and B show no variance (outputs that vary only in some A_B^i): undefined
        nan = np.full(k, np.nan)
        return {key: nan for kind in KINDS for key in (kind, f"{kind}_lo", f"{kind}_hi", f"{kind}_conf")} | {
            f"{kind}_floor": np.asarray(np.nan) for kind in KINDS}
    r = np.random.default_rng(seed).integers(N, size=(N, resamples))
    q = [(1 - conf_level) / 2, (1 + conf_level) / 2]
    out: dict[str, np.ndarray] = {}
    for kind, estimator in zip(KINDS, (first_order, total_order)):
        point = np.array([estimator(A, AB[:, j], B) for j in range(k)])
        boot = np.array([estimator(A[r], AB[r, j], B[r]) for j in range(k)])  # (k, resamples)
        lo, hi = np.quantile(boot, q, axis=1)
        out |= {kind: point, f"{kind}_lo": lo, f"{kind}_hi": hi, f"{kind}_conf": (hi - lo) / 2}
    for kind, boot in zip(KINDS, dummy_indices(A[r], B[r])):
        out[f"{kind}_floor"] = np.asarray(np.nanquantile(boot, q[1]) if np.isfinite(boot).any() else np.nan)
    return out


def distinguishable(lo: float, floor: float) -> bool:
    """Whether an index whose interval starts at ``lo`` stands above the chance ``floor`` (NaN: no)."""
    return bool(math.isfinite(lo) and math.isfinite(floor) and lo > floor)


def level_total_indices(Y: np.ndarray, k: int, level_a: np.ndarray, level_b: np.ndarray, *, resamples: int = 1000,
                        conf_level: float = 0.95, seed: int = 0) -> dict[str, np.ndarray]:  # fmt: skip
    """Total indices within one level of a categorical input, as shares of that level's own variance.

    A row ``A_B^i`` of an input other than the categorical one keeps ``A``'s level, so the blocks whose ``A``
    has the level are a Saltelli sample of the study with the level fixed, for every other input's total
    index (Jansen's estimator, :func:`SALib.analyze.sobol.total_order`, needs ``f(A)`` and ``f(A_B^i)`` only).
    The variance is that of ``f(A)`` and ``f(B)`` wherever they have the level; the floor is the dummy's
    (:func:`dummy_indices`) over the blocks where both do. First-order indices would need ``B`` at the level
    too (a quarter of the blocks with two levels) and are not given.

    Parameters
    ----------
    Y : ndarray, shape (N·(k + 2),)
        A Saltelli sample's outputs in SALib's order, all finite.
    k : int
        Inputs.
    level_a, level_b : ndarray of bool, shape (N,)
        Whether ``A`` (``B``) of each block has the level.
    resamples, conf_level, seed
        As :func:`sobol_indices` (resamples of the blocks whose ``A`` has the level, and of the ``B`` at it for
        the variance).

    Returns
    -------
    dict
        ``ST``, ``ST_lo``, ``ST_hi`` shape ``(k,)`` (the categorical input's own entry is meaningless: the caller
        drops it); ``ST_floor`` scalar; ``blocks``: blocks used. NaN everywhere with fewer than 2 blocks or no
        variance at the level.
    """
    A, B, AB = split(Y, k)
    level_a, level_b = np.asarray(level_a, dtype=bool), np.asarray(level_b, dtype=bool)
    n = int(level_a.sum())
    V = np.var(np.r_[A[level_a], B[level_b]]) if n else 0.0
    nan = np.full(k, np.nan)
    if n < 2 or not V > 0:
        return {"ST": nan, "ST_lo": nan, "ST_hi": nan, "ST_floor": np.asarray(np.nan), "blocks": n}
    a, ab, b = A[level_a], AB[level_a], B[level_b]
    rng = np.random.default_rng(seed)
    r, rb = rng.integers(n, size=(n, resamples)), rng.integers(max(len(b), 1), size=(len(b), resamples))
    point = 0.5 * np.mean((a[:, None] - ab) ** 2, axis=0) / V
    Vb = np.var(np.r_[a[r], b[rb]], axis=0)  # (resamples,): the variance resampled with the blocks
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = 0.5 * np.mean((a[r][..., None] - ab[r]) ** 2, axis=0) / Vb[:, None]  # (resamples, k)
    lo, hi = np.quantile(boot, [(1 - conf_level) / 2, (1 + conf_level) / 2], axis=0)
    both = level_a & level_b
    floor = np.nan
    if both.sum() >= 2:
        rb = np.random.default_rng(seed).integers(both.sum(), size=(both.sum(), resamples))
        _, st_dummy = dummy_indices(A[both][rb], B[both][rb])
        floor = np.nanquantile(st_dummy, (1 + conf_level) / 2) if np.isfinite(st_dummy).any() else np.nan
    return {"ST": point, "ST_lo": lo, "ST_hi": hi, "ST_floor": np.asarray(floor), "blocks": n}
