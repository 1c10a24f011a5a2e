"""Matching estimated lamps to true ones: which estimate is about which lamp, and which are about none.

A capture may have several lamps (``truth["lamps"]``) and a method may report
several (:meth:`nearlight.estimator.Estimate.found_lamps`). Before any lamp
error can be measured, each estimated lamp must be paired with the true lamp
it is an estimate *of*. :func:`match_lamps` does it with the Hungarian
algorithm (:func:`scipy.optimize.linear_sum_assignment`) on the position
error in metres, and keeps a pair only within a *gate* around the true lamp.

The gate
--------
A pair counts only when the estimate lies within :data:`GATE_FRACTION`
(20 %) of the true lamp's distance from its own highlight point (the point
every lamp metric measures from, :func:`nearlight.evaluation.scoring.metrics.highlight_point`;
:func:`gate_radii` turns those distances into radii). Why relative, and why
from the highlight:

- the errors of the benchmark are relative to that distance
  (``lamp_position_error_pct``), and what the estimators recover is a
  direction from the highlight plus a distance along it; a fixed radius in
  metres would be lax for a lamp 20 cm away and strict for one at 2 m;
- 20 % is far beyond anything the scorecard calls a success (its thresholds
  stop at 10 % of the distance), so an estimate that is merely *bad* at
  finding a lamp is still matched to it and graded by its error; the gate
  only rules out estimates that are about no lamp at all;
- two lamps at the same distance whose separation exceeds twice the gate
  (40 % of the distance, 23° seen from the object) have disjoint gates, so an
  estimate halfway between them is about neither: in ``scenes/two_lamps.yaml``
  (30° apart, 0.50 m from their highlights, 0.26 m apart) the midpoint is 26 %
  of the distance from each lamp, outside both gates, and one lamp estimated
  there counts as two missed lamps and one extra estimate instead of an
  average of the two. 25 % would put that midpoint at the edge of both gates.

Within the gate the assignment maximises the number of pairs first, then
minimises their summed error: out-of-gate pairs cost more than any set of
in-gate ones, so the Hungarian never trades a match for a smaller total.

A true lamp whose gate radius is not finite (no highlight: no surface point
sees the lamp and the camera, so the images hold nothing to find it from) can
never be matched; an estimated lamp with a non-finite coordinate matches
nothing (it is counted extra).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

#: Gate radius as a fraction of a true lamp's distance from its highlight point (see the module docstring).
GATE_FRACTION = 0.20


@dataclasses.dataclass(frozen=True)
class Matching:
    """The result of :func:`match_lamps`.

    Attributes
    ----------
    pairs : ndarray of int, shape (n, 2)
        ``(estimated index, true index)`` of every matched pair, in order of
        the true index; ``n ≤ min(k, m)``.
    errors_m : ndarray, shape (n,)
        Position error of each pair, metres (Euclidean).
    missed : ndarray of int, shape (m − n,)
        Indices of the true lamps no estimate was matched to, ascending.
    extra : ndarray of int, shape (k − n,)
        Indices of the estimated lamps matched to no true lamp, ascending.
    """

    pairs: np.ndarray
    errors_m: np.ndarray
    missed: np.ndarray
    extra: np.ndarray

    def estimate_of(self, true_index: int) -> int | None:
        """The estimated lamp matched to true lamp ``true_index``, or None when it was missed."""
        hit = np.flatnonzero(self.pairs[:, 1] == true_index)
        return int(self.pairs[hit[0], 0]) if hit.size else None


def gate_radii(true: Any, origins: Any, *, fraction: float = GATE_FRACTION) -> np.ndarray:
    """Gate radius of each true lamp: ``fraction`` of its distance from its highlight point, metres.

    Parameters
    ----------
    true, origins : array_like, shape (m, 3)
        True lamp positions and each lamp's highlight point (the point the
        lamp metrics measure from; NaN when the lamp has none), metres.
    fraction : float
        Dimensionless, :data:`GATE_FRACTION` by default.

    Returns
    -------
    ndarray, shape (m,)
        Metres; NaN for a lamp without a highlight (it cannot be matched).
    """
    t = np.asarray(true, dtype=float).reshape(-1, 3)
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    with np.errstate(over="ignore", invalid="ignore"):
        return fraction * np.linalg.norm(t - o, axis=1)


def match_lamps(est: Any, true: Any, gate: Any = None) -> Matching:
    """Match estimated lamp positions to true ones (Hungarian on the position error, gated).

    Parameters
    ----------
    est : array_like, shape (k, 3)
        Estimated lamp positions, metres; ``k ≥ 0``.
    true : array_like, shape (m, 3)
        True lamp positions, metres; ``m ≥ 0``.
    gate : array_like, shape (m,), or None
        Per true lamp, the largest position error (metres) at which an
        estimate still counts as that lamp's (:func:`gate_radii`); a NaN or
        negative radius admits no estimate. None: no gate, every pair of
        finite positions may match (the scoring uses it for one estimated
        and one true lamp, where there is nothing to choose between).

    Returns
    -------
    Matching
        The pairs (at most one per true and per estimated lamp), their errors,
        the missed true lamps and the extra estimated lamps. The pairs
        maximise the number of matches within the gate and, among those,
        minimise the summed error in metres.
    """
    e = np.asarray(est, dtype=float).reshape(-1, 3)
    t = np.asarray(true, dtype=float).reshape(-1, 3)
    k, m = len(e), len(t)
    radius = np.full(m, np.inf) if gate is None else np.asarray(gate, dtype=float).reshape(m)
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.linalg.norm(e[:, None, :] - t[None, :, :], axis=-1) if k and m else np.zeros((k, m))
        usable = np.isfinite(d) & (d <= radius[None, :])  # NaN radius or distance: False
    pairs = np.zeros((0, 2), dtype=int)
    if usable.any():
        big = (min(k, m) + 1) * (float(d[usable].max()) + 1.0)  # dearer than every in-gate assignment
        rows, cols = linear_sum_assignment(np.where(usable, d, big))
        keep = usable[rows, cols]
        pairs = np.stack([rows[keep], cols[keep]], axis=1).astype(int)
        pairs = pairs[np.argsort(pairs[:, 1], kind="stable")]
    return Matching(
        pairs=pairs,
        errors_m=d[pairs[:, 0], pairs[:, 1]] if len(pairs) else np.zeros(0),
        missed=np.setdiff1d(np.arange(m), pairs[:, 1]).astype(int),
        extra=np.setdiff1d(np.arange(k), pairs[:, 0]).astype(int),
    )
