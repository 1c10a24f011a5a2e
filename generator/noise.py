"""Sensor and range-finder noise, applied after rendering (seeded).

Camera noise (:func:`add_camera_noise`) acts on what a camera records — the
analyzer stack, and ``specular``/``diffuse`` when a capture holds separated
images — never on ground truth (``extra``: ``truth_*``, ``S0..S2``):

1. radiance ``L`` → expected electrons ``L / saturation · full_well``;
2. photon shot noise: Poisson draw;
3. read noise: Gaussian, ``read_noise`` electrons rms;
4. saturation: clip to ``[0, full_well]``;
5. quantisation: ``bits``-bit ADC over the full well;
6. back to radiance units.

``saturation: auto`` puts the brightest clean analyzer pixel at 90 % of the full
well (an exposure a careful operator would pick).

Range noise (:func:`add_range_noise`) moves ``P`` along each camera ray by a
Gaussian distance. A real range finder gives no normals, and exact normals
would not match noisy positions, so ``N`` is **dropped** (the estimator then
derives normals from ``P``); the exact normals stay in ``extra["truth_N"]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from nearlight.capture import Capture
from nearlight.generator.scene import CameraNoise

#: Fraction of the full well the brightest clean pixel reaches with ``saturation: auto``.
AUTO_EXPOSURE = 0.9


def add_camera_noise(capture: Capture, *, noise: CameraNoise | Mapping[str, Any] | None, seed: int) -> Capture:
    """A copy of ``capture`` with camera noise on its recorded images.

    Parameters
    ----------
    capture : Capture
        Clean capture (radiance, arbitrary units).
    noise : CameraNoise or mapping or None
        ``full_well`` (electrons), ``read_noise`` (electrons rms), ``bits``,
        ``saturation`` (radiance filling the full well, or ``"auto"``). None
        returns ``capture`` unchanged.
    seed : int
        Seed of the noise draws.

    Returns
    -------
    Capture
        ``stack`` (and ``specular``/``diffuse`` if present) noisy, float32;
        ``meta["noise"]["camera"]`` records the settings and the saturation used.
    """
    if noise is None:
        return capture
    if not isinstance(noise, CameraNoise):
        noise = CameraNoise.model_validate(dict(noise))
    images = {k: getattr(capture, k) for k in ("stack", "specular", "diffuse") if getattr(capture, k) is not None}
    if noise.saturation == "auto":
        peak = max(float(np.nanmax(v)) for v in images.values())
        saturation = peak / AUTO_EXPOSURE if peak > 0 else 1.0
    else:
        saturation = float(noise.saturation)
    rng = np.random.default_rng(seed)
    levels = 2**noise.bits - 1
    noisy = {}
    for name, img in images.items():
        electrons = np.clip(np.nan_to_num(img, nan=0.0), 0.0, None) / saturation * noise.full_well
        e = rng.poisson(electrons).astype(float) + rng.normal(0.0, noise.read_noise, size=electrons.shape)
        e = np.clip(e, 0.0, noise.full_well)
        noisy[name] = (np.round(e / noise.full_well * levels) / levels * saturation).astype(np.float32)
    record = {**noise.model_dump(mode="json"), "saturation": saturation, "seed": int(seed)}
    return capture.replace(**noisy, meta=_with_noise(capture.meta, "camera", record))


def add_range_noise(capture: Capture, *, sigma_m: float, seed: int) -> Capture:
    """A copy of ``capture`` with Gaussian range noise on ``P`` (and ``N`` dropped).

    Parameters
    ----------
    capture : Capture
    sigma_m : float
        Standard deviation of the error along each camera ray, metres. 0
        returns ``capture`` unchanged.
    seed : int

    Returns
    -------
    Capture
        ``P`` moved along ``P - camera.position``; ``N`` None, exact normals in
        ``extra["truth_N"]``; ``meta["noise"]["range"]`` records the settings.
    """
    if sigma_m < 0:
        raise ValueError(f"sigma_m must be >= 0, got {sigma_m}")
    if sigma_m == 0:
        return capture
    rng = np.random.default_rng(seed)
    ray = capture.P - np.asarray(capture.camera.position, float)
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    P = (capture.P + rng.normal(0.0, sigma_m, size=capture.P.shape[:-1])[..., None] * ray).astype(np.float32)
    extra = dict(capture.extra)
    if capture.N is not None:
        extra["truth_N"] = capture.N
    record = {"sigma_m": float(sigma_m), "seed": int(seed), "normals": "dropped"}
    return capture.replace(P=P, N=None, extra=extra, meta=_with_noise(capture.meta, "range", record))


def _with_noise(meta: Mapping[str, Any], kind: str, record: dict) -> dict:
    out = dict(meta)
    out["noise"] = {**out.get("noise", {}), kind: record}
    return out
