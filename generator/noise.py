"""Sensor and range-finder noise, applied after rendering (seeded, continuous in the render).

Seed rule
---------
A noisy capture has **one** integer seed ``s``. :func:`noise_rngs` splits it
with ``np.random.SeedSequence(s).spawn(2)`` into two independent streams:
child 0 draws the camera noise, child 1 the range noise. Both
:func:`add_camera_noise` and :func:`add_range_noise` take that same ``s`` and
pick their own child, so every verb follows one rule: ``nearlight render``
passes the scene's ``capture.seed``, a sweep task its ``seed`` (``nearlight
reproduce`` runs sweeps: seed 0 in ``sweeps/paper/``). ``nearlight render SCENE
--set capture.seed=3`` and a sweep task with seed 3 on the same scene
therefore see the same noisy images. The per-shot rig nuisances (analyzer
jitter, lamp flicker) draw from child 2
(:func:`nearlight.generator.nuisances.nuisance_rng`); children are keyed by
their index, so children 0 and 1 are the same whether 2 or 3 are spawned.

Camera noise
------------
:func:`add_camera_noise` acts on what a camera records — the analyzer stack,
and ``specular``/``diffuse`` when a capture holds separated images — never on
ground truth (``extra``: ``truth_*``, ``S0..S2``). For each recorded image, in
the order ``stack``, ``specular``, ``diffuse``, the camera stream draws two
arrays of standard normals of the image's shape, ``z_shot`` then ``z_read``:
how many numbers are drawn depends on the shapes only, never on the values.
Then, per pixel and channel:

1. radiance ``L`` (NaN → 0, negative → 0) → expected electrons
   ``λ = L / saturation · full_well``;
2. photon shot noise, ``Poisson(λ)``, by the inverse CDF of ``u = Φ(z_shot)``:

   - ``0 < λ < EXACT_POISSON_BELOW`` (20 electrons): the exact Poisson quantile
     ``min{k : P(Poisson(λ) ≤ k) ≥ u}``, an integer (``u`` capped at
     ``1 − 1e-12``, a tail no capture samples);
   - ``λ ≥ 20``: the Cornish–Fisher expansion of that quantile to order
     ``1/λ``, ``λ + √λ·z + (z² − 1)/6 + (z − z³)/(72√λ) + (12z⁴ − 17z² −
     19)/(3240λ)`` with ``z = z_shot``: a continuous (non-integer) electron
     count with mean exactly ``λ``, variance ``λ + 0.014/λ`` and third central
     moment within 2·10⁻⁴ of ``λ`` (Poisson: ``λ``, ``λ``, ``λ``; Gauss–Hermite
     quadrature). For every ``λ ≥ 20`` and ``|z| ≤ 6`` (all but 2·10⁻⁹ of the
     draws) it lies within 0.89 electron of the exact quantile of the same
     ``u`` (0.66 for ``|z| ≤ 5``; 0.5 of it is the exact quantile's own integer
     step), measured against ``scipy.stats.poisson.ppf`` on λ from 20 to 10⁶
     and a 0.0005 grid of ``z``. That bounds the approximation's error per
     sample, and the jump where a pixel crosses the threshold, below one
     electron (a sensor's read noise is a few). Below 20 the bound grows (1.1 electrons at λ = 16, 1.8 at 10),
     hence the exact branch there; its cost grows with λ (a sequential search
     of about λ steps), hence not above;
   - ``λ = 0``: 0;
3. read noise: Gaussian, ``read_noise · z_read`` electrons;
4. saturation: clip to ``[0, full_well]``;
5. quantisation: a ``bits``-bit ADC over the full well, ``round(e / full_well
   · (2^bits − 1))``;
6. back to radiance units.

``saturation: auto`` puts the brightest clean recorded pixel at 90 % of the full
well (an exposure a careful operator would pick;
:func:`nearlight.physics.camera.auto_saturation`, the rule the Cramér–Rao bounds use too).

Why inverse CDFs of fixed draws: Dr.Jit's LLVM backend compiles for the host
CPU, so a render can differ in its last bits between machines. With the same
draws the noisy electron count is a continuous function of ``λ`` on the
expansion branch, and on the exact branch it changes (by one electron) only
where ``u`` falls between ``P(k; λ)`` and ``P(k; λ + Δλ)`` for some ``k``: a
probability ``Σ_k pmf(k; λ)·|Δλ| = |Δλ|`` per pixel (below 2.4·10⁻⁶ for a
float32 last bit at ``λ < 20``). So a last-bit change of the render moves the
recorded image by at most one ADC step (where the count straddles a rounding
threshold) almost everywhere. numpy's ``Generator.poisson``, used before,
consumed a λ-dependent number of uniforms, so one pixel's last bit re-drew the
noise of every later pixel (the smoke baseline's noisy tasks moved 7–33 % on
another machine).

Range noise
-----------
:func:`add_range_noise` moves ``P`` along each camera ray by a Gaussian
distance (one standard normal per pixel from the range stream). A real range
finder gives no normals, and exact normals would not match noisy positions, so
``N`` is **dropped** (the estimator then derives normals from ``P``); the exact
normals stay in ``extra["truth_N"]``. The capture's ``rig.range`` states the
noise (:func:`with_range_sensor`: ``sigma_m``, ``axis: ray``, ``source:
renderer``), so an estimator need not measure it from ``P``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.special import ndtr

from ..capture import Capture, RangeSensor, Sensor
from ..physics.camera import auto_saturation
from .scene import NoiseSpec

#: Expected electrons below which shot noise is the exact Poisson quantile (see the module docstring).
EXACT_POISSON_BELOW = 20.0

#: Recorded images, in the order their noise is drawn from the camera stream.
RECORDED = ("stack", "specular", "diffuse")

_U_MAX = 1.0 - 1e-12  # the exact search's F(k) sums carry ~1e-14 rounding: stay clear of 1
_CHUNK = 1 << 14  # values per block of the exact search (stays in cache)
_BLOCK = 1 << 16  # values per block of add_camera_noise


def noise_rngs(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """The camera and range noise streams of a capture's noise seed (the one seed rule).

    Parameters
    ----------
    seed : int
        The capture's noise seed (``capture.seed``, a sweep task's ``seed``), ≥ 0.

    Returns
    -------
    camera_rng, range_rng : numpy.random.Generator
        Children 0 and 1 of ``np.random.SeedSequence(seed).spawn(2)``:
        independent streams, each a function of ``seed`` only.
    """
    camera, range_ = np.random.SeedSequence(int(seed)).spawn(2)
    return np.random.default_rng(camera), np.random.default_rng(range_)


def shot_electrons(lam: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Poisson shot noise by the inverse CDF of ``Φ(z)``: a continuous function of ``lam``.

    Parameters
    ----------
    lam : ndarray
        Expected electrons, ≥ 0 and finite.
    z : ndarray, same shape
        Standard normal draws (``u = Φ(z)`` is the uniform whose quantile is taken).

    Returns
    -------
    ndarray, same shape, float64
        Electrons: the exact Poisson quantile where ``0 < lam < EXACT_POISSON_BELOW``
        (integers), its Cornish–Fisher expansion above (see the
        module docstring for the error bound), 0 where ``lam == 0``.
    """
    lam = np.asarray(lam, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    lam_hi = np.maximum(lam, EXACT_POISSON_BELOW)  # the expansion's λ (exact branch overwritten below)
    s = np.sqrt(lam_hi)
    z2 = z * z
    out = 12.0 * z2
    out -= 17.0
    out *= z2
    out -= 19.0
    out /= 3240.0 * lam_hi  # (12z⁴ − 17z² − 19)/(3240λ)
    t = z2 - 1.0
    t *= 1.0 / 6.0
    out += t  # (z² − 1)/6
    np.subtract(1.0, z2, out=t)
    t /= 72.0 * s
    t += s
    t *= z
    out += t  # √λ·z + (z − z³)/(72√λ)
    out += lam
    del t, z2, s, lam_hi
    out[lam == 0.0] = 0.0
    low = np.flatnonzero((lam > 0.0) & (lam < EXACT_POISSON_BELOW))
    if low.size:
        flat = out.reshape(-1)
        flat[low] = _poisson_quantile(np.minimum(ndtr(z.reshape(-1)[low]), _U_MAX), lam.reshape(-1)[low])
    return out


def _poisson_quantile(u: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """``min{k : P(Poisson(lam) ≤ k) ≥ u}`` elementwise, for ``0 < lam < EXACT_POISSON_BELOW``, 1-d.

    A sequential search from ``k = 0`` (the pmf by its recurrence), in blocks
    that fit in cache, dropping finished pixels once fewer than half remain.
    Agrees with ``scipy.stats.poisson.ppf`` (tested) at a fraction of its cost.
    """
    out = np.empty(lam.shape, np.float64)
    for a in range(0, lam.size, _CHUNK):
        idx = np.arange(a, min(a + _CHUNK, lam.size))
        lb, ub = lam[idx], u[idx]
        p = np.exp(-lb)  # pmf(0)
        F = p.copy()  # CDF(0)
        active = F < ub
        k = active.astype(np.float64)  # k = #{j : CDF(j) < u} so far
        j = 0
        while True:
            n_active = np.count_nonzero(active)
            if n_active == 0:
                break
            if n_active < idx.size // 2:
                done = ~active
                out[idx[done]] = k[done]
                idx, lb, ub, p, F, k = idx[active], lb[active], ub[active], p[active], F[active], k[active]
            j += 1
            p *= lb
            p *= 1.0 / j  # pmf(j) = pmf(j − 1)·λ/j
            F += p
            active = F < ub
            k += active
        out[idx] = k
    return out


def add_camera_noise(capture: Capture, *, noise: NoiseSpec | Mapping[str, Any] | None, seed: int) -> Capture:
    """A copy of ``capture`` with camera noise on its recorded images.

    Continuous in the clean images for a given ``seed`` (see the module
    docstring): a last-bit change of the render moves the result by at most
    one ADC step almost everywhere.

    Parameters
    ----------
    capture : Capture
        Clean capture (radiance, arbitrary units).
    noise : NoiseSpec or mapping or None
        ``full_well`` (electrons), ``read_noise`` (electrons rms), ``bits``,
        ``saturation`` (radiance filling the full well, or ``"auto"``). None
        returns ``capture`` unchanged.
    seed : int
        The capture's noise seed; the draws come from ``noise_rngs(seed)[0]``.

    Returns
    -------
    Capture
        ``stack`` (and ``specular``/``diffuse`` if present) noisy, float32;
        ``meta["noise"]["camera"]`` records the settings and the saturation used, and
        ``sensor`` states the noise model (``saturation`` resolved to a number) for estimators.
    """
    if noise is None:
        return capture
    if not isinstance(noise, NoiseSpec):
        noise = NoiseSpec.model_validate(dict(noise))
    images = {k: getattr(capture, k) for k in RECORDED if getattr(capture, k) is not None}
    if noise.saturation == "auto":
        saturation = auto_saturation(*images.values())
    else:
        saturation = float(noise.saturation)
    rng, _ = noise_rngs(seed)
    draws = {name: (rng.standard_normal(img.shape), rng.standard_normal(img.shape)) for name, img in images.items()}
    noisy = {}
    for name, img in images.items():
        z_shot, z_read = draws.pop(name)
        dn = adc_counts(img, z_shot, z_read, noise=noise, saturation=saturation).astype(np.float64)
        noisy[name] = (dn * (saturation / (2**noise.bits - 1))).astype(np.float32)  # step 6
    record = {**noise.model_dump(mode="json"), "saturation": saturation, "seed": int(seed)}
    sensor = Sensor(saturation=saturation, full_well=float(noise.full_well), read_noise=float(noise.read_noise),
                    bits=int(noise.bits))  # fmt: skip
    return capture.replace(**noisy, sensor=sensor, meta=_with_noise(capture.meta, "camera", record))


def adc_counts(img: np.ndarray, z_shot: np.ndarray, z_read: np.ndarray, *, noise: NoiseSpec,
           saturation: float) -> np.ndarray:  # fmt: skip
    """What the camera's ADC reads for clean radiance ``img``: steps 1–5 of the module docstring.

    Parameters
    ----------
    img : ndarray, any shape
        Clean radiance (NaN and negative values count as 0).
    z_shot, z_read : ndarray, same shape
        Standard normal draws for the shot and the read noise.
    noise : NoiseSpec
    saturation : float
        Radiance that fills the full well (resolved, not ``"auto"``).

    Returns
    -------
    ndarray, same shape, float32
        Digital numbers, integers in ``[0, 2^bits − 1]``; times
        ``saturation / (2^bits − 1)`` they are radiance again (step 6).
    """
    levels = 2**noise.bits - 1
    src, zs, zr = np.asarray(img).reshape(-1), z_shot.reshape(-1), z_read.reshape(-1)
    out = np.empty(src.shape, np.float32)
    for a in range(0, src.size, _BLOCK):  # blocks: small temporaries, re-used memory
        b = min(a + _BLOCK, src.size)
        lam = np.nan_to_num(src[a:b], nan=0.0).astype(np.float64)
        np.clip(lam, 0.0, None, out=lam)
        lam *= noise.full_well / saturation
        e = shot_electrons(lam, zs[a:b])
        e += noise.read_noise * zr[a:b]
        np.clip(e, 0.0, noise.full_well, out=e)
        e *= levels / noise.full_well
        np.rint(e, out=e)
        out[a:b] = e
    return out.reshape(np.shape(img))


def add_range_noise(capture: Capture, *, sigma_m: float, seed: int) -> Capture:
    """A copy of ``capture`` with Gaussian range noise on ``P`` (and ``N`` dropped).

    Parameters
    ----------
    capture : Capture
    sigma_m : float
        Standard deviation of the error along each camera ray, metres. 0
        returns ``capture`` unchanged.
    seed : int
        The capture's noise seed; the draws come from ``noise_rngs(seed)[1]``.

    Returns
    -------
    Capture
        ``P`` moved along ``P - camera.position``; ``N`` None, exact normals in
        ``extra["truth_N"]``; ``meta["noise"]["range"]`` records the settings;
        ``rig.range.sigma_m`` states ``sigma_m`` (:func:`with_range_sensor`: an
        existing ``rig.range``'s quantisation, axis and source are kept).
    """
    if sigma_m < 0:
        raise ValueError(f"sigma_m must be >= 0, got {sigma_m}")
    if sigma_m == 0:
        return capture
    _, rng = noise_rngs(seed)
    ray = capture.P - np.asarray(capture.camera.position, float)
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    P = (capture.P + rng.normal(0.0, sigma_m, size=capture.P.shape[:-1])[..., None] * ray).astype(np.float32)
    extra = dict(capture.extra)
    if capture.N is not None:
        extra["truth_N"] = capture.N
    record = {"sigma_m": float(sigma_m), "seed": int(seed), "normals": "dropped"}
    out = capture.replace(P=P, N=None, extra=extra, meta=_with_noise(capture.meta, "range", record))
    return with_range_sensor(out, sigma_m=sigma_m)


def with_range_sensor(capture: Capture, *, sigma_m: float | None = None, quantum_m: float | None = None,
                      axis: str | None = None, source: str | None = None) -> Capture:
    """A copy of ``capture`` whose ``rig.range`` states the range sensor's error (the one place the generator sets it).

    Parameters
    ----------
    capture : Capture
    sigma_m, quantum_m : float or None
        Noise standard deviation and quantisation step, metres; None keeps the
        capture's ``rig.range`` value (0 when it has none).
    axis : {"ray", "z"} or None
        None keeps the capture's (``"ray"`` when it has none).
    source : str or None
        None keeps the capture's (``"renderer"`` when it has none).

    Returns
    -------
    Capture
        With ``rig.range`` a :class:`~nearlight.capture.RangeSensor` of these values.
    """
    old = capture.rig.range or RangeSensor(axis="ray", source="renderer")
    stated = RangeSensor(
        sigma_m=float(old.sigma_m if sigma_m is None else sigma_m),
        quantum_m=float(old.quantum_m if quantum_m is None else quantum_m),
        axis=old.axis if axis is None else axis,
        source=old.source if source is None else source,
    )
    return capture.replace(rig=dataclasses.replace(capture.rig, range=stated))


def _with_noise(meta: Mapping[str, Any], kind: str, record: dict) -> dict:
    out = dict(meta)
    out["noise"] = {**out.get("noise", {}), kind: record}
    return out
