"""What a real rig records from a clean render: nuisances applied after rendering, per seed, around the noise.

:func:`through_rig` is the one function that turns a clean capture (a render) into
the capture an estimator sees; ``nearlight render`` and every sweep task call
it. With every nuisance off it is exactly camera noise then range noise
(:mod:`nearlight.generator.noise`), as before nuisances existed: each step
below returns its input unchanged when its nuisance is off.

Which nuisances are rendered and which are applied here
-------------------------------------------------------
Rendered (scene keys in ``lamp``, part of the render key): whatever changes the
light reaching the surface, which only a render can follow through the BSDF
and shadows: the lamp polarizer's extinction ratio and the lamp's anisotropy
(:mod:`nearlight.generator.lamp`). Applied here (scene keys in ``nuisances``,
not part of the render key, so one render serves every value and seed): what
happens between the surface's radiance and the recorded numbers, a function of
the clean Stokes images and range image alone.

Order, as light and data go through a rig
-----------------------------------------
1. analyzer (``nuisances.analyzer``): each shot ``k`` is the Stokes render
   seen through a real polarizer at its real angle ``θk + offset + jitter·zk``
   with extinction ratio ε (:func:`nearlight.physics.polarization.analyzer_stack`);
   the capture keeps the nominal angles (what the rig believes);
2. lamp flicker (``nuisances.camera.flicker``): shot ``k`` scaled by
   ``max(0, 1 + flicker·fk)``;
3. vignetting and white balance (``nuisances.camera``): every recorded image
   times ``(1 − v·ρ²)`` per pixel and the per-channel gains;
4. camera noise (``capture.noise``; its exposure sees the images above);
5. response curve (``nuisances.camera.gamma``): ``white·(V/white)^(1/γ)``,
   ``white`` the full-well radiance of the noise model (the ``saturation``
   used), or the ``saturation: auto`` level of the images when noise is off;
6. range noise (``capture.range_noise_m``), then depth quantisation, then the
   misregistration shift, then holes (``nuisances.range``); any of the last
   three drops ``N`` (exact normals kept in ``truth_N``) and keeps the exact
   positions in ``truth_P``; with noise or quantisation, ``rig.range`` states
   both (along the ray, source ``renderer``);
7. calibration (``nuisances.calibration``): the capture's ``camera`` becomes
   the true one moved by the given amounts; ``truth.camera`` keeps the true one;
8. the calibration targets' centres (``rig.targets``), each moved by a draw of
   its stated error (:func:`nearlight.generator.targets.calibrated`, its own
   stream: child 3 of the seed's sequence); ``truth.targets`` keeps the true ones.

Draws: the standard normals ``z`` (jitter) then ``f`` (flicker), ``K`` each
(the number of analyzer angles), come from :func:`nuisance_rng` ``(seed)``,
child 2 of ``np.random.SeedSequence(seed)`` (children 0 and 1 are the camera
and range noise streams, unchanged): how many numbers are drawn depends on
``K`` only, so each nuisance's draws do not depend on the others' settings.

Everything applied, with what was drawn, goes into ``truth.nuisances``
(capture format v2); what a calibrated rig knows (the analyzer's extinction
ratio) goes into ``rig``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..capture import Camera, Capture
from ..physics.camera import auto_saturation, response, vignetting_gain
from ..physics.polarization import analyzer_stack, linear_stokes
from .noise import RECORDED, add_camera_noise, add_range_noise, with_range_sensor
from .realism import expand
from .scene import NoiseSpec, Nuisances, Scene, euler_rotation
from .targets import calibrated


def nuisance_rng(seed: int) -> np.random.Generator:
    """The nuisance stream of a capture's seed: child 2 of ``np.random.SeedSequence(seed)`` (see the module)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed)).spawn(3)[2])


def nuisances_of(scene: Scene | Mapping[str, Any]) -> tuple[str, Nuisances]:
    """The ``realism`` profile name and the resolved post-render nuisances of a scene (object or document)."""
    if isinstance(scene, Scene):
        return scene.realism, scene.nuisances
    doc = expand(dict(scene))
    return str(doc.get("realism", "none")), Nuisances.model_validate(doc.get("nuisances") or {})


def draws_from_seed(nuisances: Nuisances) -> bool:
    """Whether a capture with these nuisances changes with the seed (analyzer jitter or lamp flicker is on).

    A sweep runs every seed of a configuration only when something in it is
    random: camera or range noise, or this.
    """
    return nuisances.analyzer.jitter_deg > 0 or nuisances.camera.flicker > 0


def through_rig(
    clean: Capture,
    *,
    nuisances: Nuisances | None = None,
    realism: str = "none",
    noise: NoiseSpec | Mapping[str, Any] | None = None,
    range_noise: float = 0.0,
    seed: int = 0,
) -> Capture:
    """The capture a rig records from the clean render ``clean`` (see the module docstring for the order).

    Parameters
    ----------
    clean : Capture
        A noise-free capture (a render: ``extra`` holds ``S0``, ``S1``, ``S2``
        when it has a stack; otherwise the Stokes images are fitted to the stack).
    nuisances : Nuisances or None
        The scene's ``nuisances`` (None: all off).
    realism : str
        The profile they came from, recorded in ``truth.nuisances``.
    noise : NoiseSpec or mapping or None
        ``capture.noise``.
    range_noise : float
        ``capture.range_noise_m``, metres.
    seed : int
        The capture's one seed (camera, range and nuisance streams).

    Returns
    -------
    Capture
        With every nuisance off and ``nuisances`` None: exactly
        ``add_range_noise(add_camera_noise(clean, ...), ...)``.
    """
    nz = Nuisances() if nuisances is None else nuisances
    K = 0 if clean.stack is None else len(clean.stack)
    rng = nuisance_rng(seed)
    z_jitter, z_flicker = rng.standard_normal(K), rng.standard_normal(K)
    record: dict[str, Any] = {"realism": realism, **nz.model_dump(mode="json")}

    cap, angles = _analyzer(clean, nz, z_jitter)
    if angles is not None:
        record["analyzer"]["angles_deg"] = angles.tolist()
    cap, gains = _flicker(cap, nz.camera.flicker, z_flicker)
    if gains is not None:
        record["camera"]["flicker_gains"] = gains.tolist()
    cap = _gains(cap, nz)
    cap = add_camera_noise(cap, noise=noise, seed=seed)
    cap, white = _response(cap, nz.camera.gamma)
    if white is not None:
        record["camera"]["response_white"] = white
    cap = add_range_noise(cap, sigma_m=range_noise, seed=seed)
    cap = _range(cap, clean, nz)
    if range_noise > 0 or nz.range.quantum_m > 0:  # what the rig states of its range sensor (rig.range)
        cap = with_range_sensor(cap, sigma_m=range_noise, quantum_m=nz.range.quantum_m, axis="ray", source="renderer")
    cap = _calibration(cap, nz)
    cap, offsets = _target_calibration(cap, seed)
    if offsets is not None:
        record["targets"] = {"centre_offsets_m": offsets}
    if nuisances is None and realism == "none" and offsets is None:
        return cap
    truth = None if cap.truth is None else {**cap.truth, "nuisances": record}
    return cap.replace(truth=truth)


# --------------------------------------------------------------------------- the steps


def _target_calibration(capture: Capture, seed: int) -> tuple[Capture, list[list[float]] | None]:
    """``rig.targets`` as the lab calibrated them for this capture (:func:`~nearlight.generator.targets.calibrated`),
    when a target states an error; the offsets drawn (None: nothing drawn)."""
    targets = capture.rig.targets
    if not any(t.centre_error_m > 0 for t in targets):
        return capture, None
    moved, offsets = calibrated(targets, seed)
    return capture.replace(rig=dataclasses.replace(capture.rig, targets=moved)), offsets


def _stokes(capture: Capture) -> np.ndarray:
    """``[3, H, W, 3]`` clean Stokes images: the render's ``S0..S2``, else fitted to the stack (exact when clean)."""
    if all(f"S{i}" in capture.extra for i in range(3)):
        return np.stack([np.asarray(capture.extra[f"S{i}"], float) for i in range(3)])
    S = linear_stokes(np.asarray(capture.stack, float), capture.analyzer_angles_deg)
    return np.asarray(S, float)[:3]


def _analyzer(capture: Capture, nz: Nuisances, z: np.ndarray) -> tuple[Capture, np.ndarray | None]:
    an = nz.analyzer
    if capture.stack is None or (an.extinction_ratio is None and an.offset_deg == 0 and an.jitter_deg == 0):
        return capture, None
    angles = np.asarray(capture.analyzer_angles_deg, float) + an.offset_deg + an.jitter_deg * z
    stack = analyzer_stack(_stokes(capture), angles, extinction_ratio=an.extinction_ratio).astype(np.float32)
    rig = capture.rig
    if an.extinction_ratio is not None:
        rig = dataclasses.replace(rig, analyzer_extinction_ratio=float(an.extinction_ratio))
    return capture.replace(stack=stack, rig=rig), angles


def _flicker(capture: Capture, flicker: float, z: np.ndarray) -> tuple[Capture, np.ndarray | None]:
    if capture.stack is None or flicker == 0:
        return capture, None
    gains = np.maximum(0.0, 1.0 + flicker * z)
    return capture.replace(stack=(capture.stack * gains[:, None, None, None]).astype(np.float32)), gains


def _gains(capture: Capture, nz: Nuisances) -> Capture:
    cam = nz.camera
    if cam.vignetting == 0 and cam.white_balance == (1.0, 1.0, 1.0):
        return capture
    g = vignetting_gain(capture.width, capture.height, cam.vignetting)[..., None] * np.asarray(cam.white_balance)
    out = {k: (getattr(capture, k) * g).astype(np.float32) for k in RECORDED if getattr(capture, k) is not None}
    return capture.replace(**out)


def _response(capture: Capture, gamma: float) -> tuple[Capture, float | None]:
    if gamma == 1.0:
        return capture, None
    images = {k: getattr(capture, k) for k in RECORDED if getattr(capture, k) is not None}
    camera_noise = capture.meta.get("noise", {}).get("camera")
    white = float(camera_noise["saturation"]) if camera_noise else auto_saturation(*images.values())
    out = {k: response(np.asarray(v, float), gamma, white).astype(np.float32) for k, v in images.items()}
    return capture.replace(**out), white


def bilinear_shift(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``image`` resampled at ``(col + dx, row + dy)`` by bilinear interpolation; NaN outside or next to NaN.

    Parameters
    ----------
    image : ndarray, shape (H, W, C)
    dx, dy : float
        Shift in pixels (columns rightwards, rows downwards).

    Returns
    -------
    ndarray, shape (H, W, C), float64
        Integer shifts move pixels exactly; a neighbour with zero weight never contributes (not even its NaN).
    """
    H, W = image.shape[:2]
    img = np.asarray(image, float)
    x = np.arange(W) + dx
    y = np.arange(H) + dy
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    out = np.zeros(img.shape)
    for oy, wy in ((0, 1.0 - fy), (1, fy)):
        for ox, wx in ((0, 1.0 - fx), (1, fx)):
            w = wy[:, None] * wx[None, :]
            rows, cols = y0 + oy, x0 + ox
            inside = ((rows >= 0) & (rows < H))[:, None] & ((cols >= 0) & (cols < W))[None, :]
            v = img[np.clip(rows, 0, H - 1)][:, np.clip(cols, 0, W - 1)]
            v = np.where(inside[..., None], v, np.nan)
            out += np.where(w[..., None] > 0, w[..., None] * v, 0.0)
    return out


def _range(capture: Capture, clean: Capture, nz: Nuisances) -> Capture:
    rn = nz.range
    if rn.holes_shiny_above is None and rn.holes_dark_below == 0 and rn.shift_px == (0.0, 0.0) and rn.quantum_m == 0:
        return capture
    cam = np.asarray(capture.camera.position, float)
    P = np.asarray(capture.P, float)
    if rn.quantum_m > 0:
        ray = P - cam
        dist = np.linalg.norm(ray, axis=-1, keepdims=True)
        P = cam + ray / dist * (np.round(dist / rn.quantum_m) * rn.quantum_m)
    if rn.shift_px != (0.0, 0.0):
        P = bilinear_shift(P, *rn.shift_px)
    holes = range_holes(clean, shiny_above=rn.holes_shiny_above, dark_below=rn.holes_dark_below)
    P[holes] = np.nan
    extra = dict(capture.extra)
    extra.setdefault("truth_P", np.asarray(clean.P, np.float32))
    if capture.N is not None:
        extra.setdefault("truth_N", capture.N)
    return capture.replace(P=P.astype(np.float32), N=None, extra=extra)


def range_holes(clean: Capture, *, shiny_above: float | None, dark_below: float) -> np.ndarray:
    """``[H, W]`` bool: surface pixels where the range finder returns nothing.

    A pixel's brightness is its clean ``S0`` averaged over the colour channels
    (the stack's mean when there is no ``S0``); a hole is where it is at least
    ``shiny_above`` times the brightest surface pixel's (None: never) or below
    ``dark_below`` times it.
    """
    surface = clean.surface_mask
    if "S0" in clean.extra:
        b = np.asarray(clean.extra["S0"], float).mean(-1)
    else:
        b = np.asarray(clean.stack if clean.stack is not None else clean.specular, float)
        b = b.mean(axis=(0, -1)) if b.ndim == 4 else b.mean(-1)
    peak = np.nanmax(np.where(surface, b, np.nan))
    holes = np.zeros(surface.shape, bool)
    if shiny_above is not None:
        holes |= b >= shiny_above * peak
    if dark_below > 0:
        holes |= b < dark_below * peak
    return holes & surface


def _calibration(capture: Capture, nz: Nuisances) -> Capture:
    cal = nz.calibration
    if cal.position_m == (0.0, 0.0, 0.0) and cal.rotation_deg == (0.0, 0.0, 0.0):
        return capture
    true = capture.camera
    position = np.asarray(true.position, float) + np.asarray(cal.position_m)
    to_world = None
    if true.to_world is not None:
        to_world = np.array(true.to_world, float)
        to_world[:3, :3] = euler_rotation(cal.rotation_deg) @ to_world[:3, :3]
        to_world[:3, 3] = position
    truth_cam: dict[str, Any] = {"position": np.asarray(true.position, float).tolist()}
    if true.to_world is not None:
        truth_cam["to_world"] = np.asarray(true.to_world, float).tolist()
    if true.fov_x_deg is not None:
        truth_cam["fov_x_deg"] = float(true.fov_x_deg)
    truth = None if capture.truth is None else {**capture.truth, "camera": truth_cam}
    return capture.replace(camera=Camera(position=position, to_world=to_world, fov_x_deg=true.fov_x_deg), truth=truth)
