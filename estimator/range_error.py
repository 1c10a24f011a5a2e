"""What a range sensor's error is: noise or quantisation, along the ray or the optical axis, stated or read off ``P``.

Quantisation
------------
Depth quantised in steps ``q`` (a depth map in millimetres, a light stripe's
0.2 mm) is a staircase, not noise: along the axis the steps are taken (``z``
for a depth map, the ray for a stripe scanner) the depth sits on a lattice
(:func:`measured_range` finds it). Inside a terrace the range is flat and a
small window reads a false slope of zero, with no scatter to warn the ICI;
so a quantised range takes no window narrower than one that spans
:data:`STEPS_PER_WINDOW` steps of the local slope, and its noise is the
staircase's ``q/√12`` (the grid's offset unknown, the error over a window
that spans several steps behaves as that uniform noise).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

#: A range is quantised when its pixels share few depth levels: on average at least this many per level.
PIXELS_PER_LEVEL = 4

#: A lattice of depths is taken for quantisation when the measured scatter is at most this × its ``q/√12``.
LATTICE_EXPLAINS = 2.0

#: Range noise measured at a stride of 2 pixels is taken over stride 1's when it is this many times larger: the
#: errors are correlated between neighbours (:func:`measured_range`).
CORRELATED = 1.15

#: Below this noise (metres) a range is exact as far as any sensor goes (a micrometre: 0.5 % of a light stripe's
#: 0.2-mm step), and stride 2 reads only the surface's curvature.
EXACT_RANGE = 1e-6

#: Largest ratio of the smallest gap between depth levels to the step :func:`_lattice` looks for.
MAX_DIVISOR = 16


@dataclasses.dataclass(frozen=True)
class RangeModel:
    """What the range sensor's error is (``rig.range``, or measured from ``P``).

    Attributes
    ----------
    sigma_m : float
        Standard deviation of Gaussian noise, metres (0: none).
    quantum_m : float
        Step of the depth's quantisation, metres (0: not quantised).
    axis : {"ray", "z"}
        Along what the noise and the steps are: the distance along each ray
        (a light-stripe or time-of-flight sensor) or the depth along the
        optical axis (what a depth map stores).
    source : str
        ``"rig"`` (stated by the capture), ``"measured"`` (from ``P``).
    """

    sigma_m: float = 0.0
    quantum_m: float = 0.0
    axis: Literal["ray", "z"] = "ray"
    source: str = "measured"

    @property
    def equivalent_sigma_m(self) -> float:
        """Standard deviation of the noise and the staircase together, ``√(σ² + q²/12)``, metres."""
        return float(np.hypot(self.sigma_m, self.quantum_m / np.sqrt(12.0)))


def _lattice(depth: np.ndarray) -> float:
    """Step ``q`` when the depths (metres, 1-D) sit on a lattice ``k·q + offset``, else 0.

    A lattice has few distinct levels for its pixels (on average at least
    :data:`PIXELS_PER_LEVEL` on each) and every gap between consecutive levels
    a whole multiple of one step (the smallest gap, or that divided by up to
    :data:`MAX_DIVISOR`); a smooth range's values are all distinct. Values
    within float32 precision of each other count as one.
    """
    if depth.size < 50:
        return 0.0
    vals = np.sort(depth)
    tol = 1e-7 + 4e-7 * float(np.abs(vals).max())
    levels = vals[np.concatenate([[True], np.diff(vals) > tol])]
    if levels.size < 3 or levels.size * PIXELS_PER_LEVEL > vals.size:
        return 0.0
    gaps = np.diff(levels)
    # the step is the gaps' greatest common divisor: on a surface steeper than a step per pixel no two
    # neighbours share a level, and the smallest gap seen is a multiple of the step
    for m in range(1, MAX_DIVISOR + 1):
        q = float(np.min(gaps)) / m
        if q <= 8 * tol:
            break
        k = gaps / q
        if np.all(np.abs(k - np.rint(k)) * q <= 4 * tol):
            return q
    return 0.0


def range_noise(P: np.ndarray, camera_position: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Standard deviation of the range noise, metres, from fourth differences of the range along rows and columns.

    A smooth surface's range has fourth differences of order ``h⁴ / R³``
    (nanometres for a 15-cm sphere at millimetre pixels) where independent
    noise of standard deviation ``σ_r`` has ``√70 σ_r`` (70 = Σ of the squared
    binomial weights 1, 4, 6, 4, 1); so ``σ_r = 1.4826 · median|Δ⁴ d| / √70``
    over every run of five surface pixels along rows, and along columns, the
    larger of the two: robust to the silhouettes' and holes' few large
    values, and blind to curvature (which plane-fit residuals would take for
    noise). Depth quantised in steps ``q`` on a slanted surface reads as
    ``≈ q/√12`` along the axis the steps cross (along the other, for a camera
    without roll, the depth is constant and its differences zero).

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
    camera_position : ndarray, shape (3,)
    valid : ndarray of bool, shape (H, W), optional

    Returns
    -------
    float
        NaN when no row or column holds five surface pixels in a run.
    """
    P = np.asarray(P, dtype=float)
    valid = np.all(np.isfinite(P), axis=-1) if valid is None else valid
    d = np.linalg.norm(np.where(valid[..., None], P, 0.0) - np.asarray(camera_position, dtype=float), axis=-1)
    w = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
    sigmas = []
    for axis in (0, 1):
        dd, vv = np.moveaxis(d, axis, -1), np.moveaxis(valid, axis, -1)
        n = dd.shape[-1] - 4
        if n <= 0:
            continue
        fourth = sum(w[k] * dd[..., k:k + n] for k in range(5))
        run = np.logical_and.reduce([vv[..., k:k + n] for k in range(5)])
        if run.any():
            sigmas.append(float(1.4826 * np.median(np.abs(fourth[run])) / np.sqrt(70.0)))
    # the larger of the two axes: depth quantised along a camera without roll is constant along rows
    # (zero fourth differences there), so a median over both would read the steps as no noise
    return max(sigmas) if sigmas else np.nan


def measured_range(P: np.ndarray, camera_position: np.ndarray, valid: np.ndarray, axis: np.ndarray) -> RangeModel:
    """The range sensor's error read off ``P``: a lattice along ``z`` or along the ray, else Gaussian noise.

    Quantisation is found as depths on a lattice (:func:`_lattice`);
    otherwise the noise is measured from fourth differences
    of the distance along the ray
    (:func:`range_noise`).

    Parameters
    ----------
    P : ndarray, shape (H, W, 3)
    camera_position : ndarray, shape (3,)
    valid : ndarray of bool, shape (H, W)
    axis : ndarray, shape (3,)
        The optical axis.
    """
    # fourth differences of neighbours miss errors correlated over a few pixels (a staircase blurred by a
    # sub-pixel misregistration's interpolation: the bench profile's torus reads 0.030 mm at stride 1, 0.038 mm at
    # stride 2), which the windows' slopes see at their full size; at stride 2 a curved surface's own fourth
    # differences grow 16-fold (the 160x120 sphere with 0.2 mm: 0.203 and 0.216 mm), so stride 2 is taken only
    # when it reads more than CORRELATED times stride 1, on a range that is not exact
    sigmas = [range_noise(P[::k, ::k], camera_position, valid[::k, ::k]) for k in (1, 2)]
    sigmas = [float(x) if np.isfinite(x) else 0.0 for x in sigmas]
    sigma = sigmas[1] if sigmas[0] > EXACT_RANGE and sigmas[1] > CORRELATED * sigmas[0] else sigmas[0]
    rel = np.where(valid[..., None], P - camera_position, 0.0)
    for name, depth in (("z", rel @ axis), ("ray", np.linalg.norm(rel, axis=-1))):
        q = _lattice(depth[valid])
        # a lattice is the error model only when it explains the scatter: a 0.2-mm staircase interpolated by a
        # (0.3, 0.2)-px shift sits exactly on a 4-µm lattice (its weights are multiples of 0.02), while its
        # scatter is that of the 0.2-mm steps
        if q > 0 and sigma <= LATTICE_EXPLAINS * q / np.sqrt(12.0):
            return RangeModel(quantum_m=q, axis=name)
    return RangeModel(sigma_m=sigma, axis="ray")
