"""Render a scene to a noise-free capture (Stokes images, exact P and N, truth).

How a capture is rendered
-------------------------
- Variant ``llvm_ad_mono_polarized`` (see :mod:`nearlight.generator.llvm`),
  one colour channel at a time, so RGB truth is reproduced exactly.
- **Pixel-centre sampling.** Every sample of a pixel traces the ray through
  the pixel's centre (no anti-aliasing), so each pixel holds the radiance of
  exactly the surface point whose ``P`` and ``N`` the capture records, as a
  calibrated range finder would pair them. With the default ``max_depth: 2``
  (direct light only, the paper's model) this is deterministic and one sample
  per pixel is exact; ``spp`` only averages the indirect bounces when
  ``max_depth > 2``, and points of a sphere lamp (``lamp.radius`` > 0, then
  ``spp × lamp.samples`` samples are traced, :func:`traced_spp`).
- The integrator is Mitsuba's ``path``; its Mueller-matrix result is rotated
  into the sensor's Stokes frame exactly as Mitsuba's ``stokes`` integrator
  does (x axis = image horizontal), giving S0, S1, S2. One render serves every
  analyzer angle: ``I(θ) = ½ (S0 + S1 cos 2θ + S2 sin 2θ)``, θ measured
  counter-clockwise from the image's rightward horizontal as the image is
  viewed (checked against a physical polarizer sheet in front of the camera).
- Specular-only (``kd = 0``) and diffuse-only (``ks = 0``) renders give
  ``truth_specular`` / ``truth_diffuse``. With direct light only the image is
  linear in ``ks``, ``kd`` and the lamp intensity, so the two parts are
  rendered once with unit values and scaled per channel (exact), and the full
  image is their sum; with ``max_depth > 2`` every part is rendered per
  channel, and the full image separately.
- ``P`` and ``N`` come from ``mi.Scene.ray_intersect`` of the same pixel-centre
  rays (shading normals: those the BSDF was evaluated with).
- **Several lamps** (``lamps:``): every pass lights one lamp (its own emitter
  and filter) and the passes are summed, radiance being linear in the lamps;
  in one Mitsuba scene with several emitters the integrator would pick one
  emitter per sample and a one-sample render would not be exact. Each lamp's
  own parts are kept as ``truth_specular_lamp<i>`` / ``truth_diffuse_lamp<i>``.
  A one-lamp scene renders exactly as before lamps were a list (its passes,
  arrays, render key and capture, bit for bit).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from scipy.ndimage import binary_dilation

from ..capture import Camera, Capture, LampFilter, Rig
from ..errors import UserError
from ..files.atomic import atomic_write
from ..files.digests import file_sha256
from ..physics.polarization import analyzer_stack, filter_axes
from .scene import LAMP_V1_KEYS, LampSpec, MitsubaMaterial, Scene, lamp_name, placement
from .targets import BLACK, lamp_shape_name, needs_ids, object_names, rig_targets, target_shapes
from .targets import target_truth

#: Bump when a change alters rendered values (invalidates caches).
RENDER_VERSION = 1
#: Render passes: which lobes are on (``others``: the object black, the targets and a lamp seen directly lit).
PARTS = ("specular", "diffuse", "full", "others")


# --------------------------------------------------------------------------- scene dicts


def _transform(mi: ModuleType, m: Any) -> Any:
    return mi.ScalarTransform4f(np.asarray(m, float).tolist())


def sensor_dict(mi: ModuleType, scene: Scene) -> dict:
    """Mitsuba perspective sensor (box filter) for ``scene.camera``."""
    cam = scene.camera
    return {
        "type": "perspective",
        "fov": cam.fov_x_deg,
        "fov_axis": "x",
        "to_world": mi.ScalarTransform4f().look_at(origin=cam.position, target=cam.target(scene.capture.seed), up=cam.up),
        "film": {
            "type": "hdrfilm",
            "width": cam.width,
            "height": cam.height,
            "rfilter": {"type": "box"},
            "pixel_format": "luminance",
        },
        "sampler": {"type": "independent", "sample_count": scene.capture.spp},
    }


def _per_channel(value: Any, channel: int) -> Any:
    """A Mitsuba dict with every ``{type: rgb, value: [r, g, b]}`` replaced by channel ``channel``."""
    if isinstance(value, dict):
        if value.get("type") == "rgb" and isinstance(value.get("value"), (list, tuple)) and len(value["value"]) == 3:
            return float(value["value"][channel])
        return {k: _per_channel(v, channel) for k, v in value.items()}
    return value


def bsdf_dict(scene: Scene, *, part: str, channel: int | None) -> dict:
    """The object's Mitsuba BSDF for one render pass.

    ``channel`` None means unit ``ks``/``kd`` (the linear, direct-light case).
    """
    mat = scene.material
    if part == "others":
        return BLACK
    if isinstance(mat, MitsubaMaterial):
        return _per_channel(mat.bsdf, channel)
    unit = channel is None
    ks = 1.0 if unit else mat.specular[channel]
    kd = 1.0 if unit else mat.kd[channel]
    out = {
        "type": "nearlight_bsdf",
        "model": mat.model,
        "roughness": mat.roughness,
        "ks": ks if part in ("specular", "full") else 0.0,
        "kd": kd if part in ("diffuse", "full") else 0.0,
        "polarization": mat.polarization,
        "eta": mat.eta,
    }
    if mat.texture is not None:
        frame = placement(scene.object)
        out.update(texture_period=mat.texture.period_m, kd_contrast=mat.texture.kd_contrast,
                   roughness_contrast=mat.texture.roughness_contrast, texture_origin=frame[:3, 3].tolist(),
                   **{f"texture_{a}": frame[:3, i].tolist() for i, a in enumerate("xyz")})  # fmt: skip
    return out


def object_dicts(mi: ModuleType, scene: Scene, bsdf: dict, scratch: Path) -> dict[str, dict]:
    """The object's shapes with ``bsdf``, transforms converted for Mitsuba."""
    from .shapes import BUILDERS

    shapes = BUILDERS[scene.object.type](scene.object, bsdf, scratch)
    return {name: {**d, "to_world": _transform(mi, d["to_world"])} for name, d in shapes.items()}


def scene_dict(mi: ModuleType, scene: Scene, *, part: str = "full", channel: int | None = None,
               lamp_route: str = "emitter", scratch: Path, stokes: bool = False,
               lit: Sequence[int] | None = None) -> dict:  # fmt: skip
    """The whole Mitsuba scene dict for one render pass.

    Parameters
    ----------
    part : {"specular", "diffuse", "full", "others"}
        The object's lobes on (``others``: none); the targets are lit in ``full`` and ``others`` only, black
        (blocking light, adding none) in the others.
    channel : int or None
        Colour channel (0, 1, 2) or None for unit reflectances and intensity.
    lamp_route : {"emitter", "sheet"}
        The polarized point emitter (``path``) or a point light behind a
        polarizer sheet (``volpath``); see :mod:`nearlight.generator.lamp`.
    stokes : bool
        Wrap the integrator in Mitsuba's ``stokes`` (for ``mi.render``).
    lit : sequence of int, optional
        Indices of ``scene.lamps`` to include, each as its own emitter (and sheet); default every lamp. The
        renderer lights one lamp per pass (:func:`_render_arrays`): Mitsuba's integrators pick one emitter per
        sample, so a pass with several lamps is exact only in expectation.
    """
    from . import lamp

    lit = range(len(scene.lamps)) if lit is None else lit
    lamps: dict[str, dict] = {}
    for i in lit:
        spec = scene.lamps[i]
        intensity = 1.0 if channel is None else spec.intensity[channel]
        facing = scene.facing(i)
        name = "lamp" if i == 0 else f"lamp{i}"  # lamp 0's dict is the one-lamp scene's, name included
        if lamp_route == "emitter":
            lamps[name] = lamp.polarized_lamp(spec.position, intensity, spec.polarizer_axis, facing,
                                              extinction_ratio=spec.polarizer_extinction_ratio,
                                              anisotropy_k=spec.anisotropy_k, anisotropy_axis=spec.anisotropy_axis,
                                              radius=spec.radius, intersectable=spec.intersectable)  # fmt: skip
        else:
            if not scene.is_v1_lamp(spec):
                raise ValueError("the polarizer-sheet route renders only an ideal isotropic point lamp")
            sheet = lamp.polarizer_sheet(mi, spec.position, intensity, spec.polarizer_axis, facing)
            lamps.update({name + k.removeprefix("lamp"): v for k, v in sheet.items()})
    for i, spec in enumerate(scene.lamps):  # an unlit lamp a ray can hit is still there, dark
        if spec.intersectable and i not in lit:
            lamps[lamp_shape_name(i)] = {"type": "sphere", "center": list(spec.position), "radius": spec.radius,
                                         "bsdf": BLACK}  # fmt: skip
    targets = {k: {**v, "to_world": _transform(mi, v["to_world"])} if "to_world" in v else v
               for k, v in target_shapes(scene, lit=part in ("full", "others")).items()}  # fmt: skip
    kind = "path" if lamp_route == "emitter" else "volpath"
    integrator = {"type": kind, "max_depth": scene.capture.max_depth}
    if stokes:
        integrator = {"type": "stokes", "integrator": integrator}
    return {
        "type": "scene",
        "integrator": integrator,
        "sensor": sensor_dict(mi, scene),
        **object_dicts(mi, scene, bsdf_dict(scene, part=part, channel=channel), scratch),
        **targets,
        **lamps,
    }


# --------------------------------------------------------------------------- tracing


#: Most rays traced in one wavefront (several samples per pixel go in one call).
MAX_WAVEFRONT = 1 << 21


def sensor_rays(mi: ModuleType, sensor: Any, repeat: int = 1) -> Any:
    """Rays through every pixel centre, row-major from the top-left pixel, the image ``repeat`` times over."""
    import drjit as dr

    w, h = sensor.film().size()
    idx = dr.arange(mi.UInt32, w * h * repeat) % (w * h)
    pos = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    return ray


def _to_sensor_stokes(mi: ModuleType, sensor: Any, ray: Any, spec: Any) -> list:
    """S0, S1, S2 of the integrator's Mueller result along ``ray``, rotated from the ray's implicit basis to the
    sensor's x axis, as Mitsuba's ``stokes`` integrator does."""
    import drjit as dr

    vertical = sensor.world_transform() @ mi.Vector3f(0.0, 1.0, 0.0)
    to_sensor = mi.mueller.rotate_stokes_basis(-ray.d, mi.mueller.stokes_basis(-ray.d), dr.cross(ray.d, vertical))
    spec = mi.Spectrum(to_sensor) * spec
    stokes = [spec[i, 0] for i in range(3)]
    dr.eval(stokes)
    return stokes


def trace_stokes(mi: ModuleType, mscene: Any, *, spp: int, seed: int = 0, tick=None) -> np.ndarray:
    """Stokes S0, S1, S2 at every pixel centre, in the sensor frame.

    Parameters
    ----------
    mi : module
    mscene : mitsuba.Scene
        With a ``path`` or ``volpath`` integrator (not ``stokes``).
    spp : int
        Samples per pixel, all through the pixel centre.
    seed : int
        Sampler seed.
    tick : callable, optional
        Called with the number of samples per pixel done, for progress bars.

    Returns
    -------
    ndarray, shape (3, H, W)
        Mean over ``spp`` samples; x axis of the Stokes frame = image horizontal.
    """
    import drjit as dr

    from .llvm import is_scalar

    sensor = mscene.sensors()[0]
    if is_scalar(mi):
        return _trace_stokes_scalar(mi, mscene, spp=spp, seed=seed, tick=tick)
    w, h = sensor.film().size()
    integrator = mscene.integrator()
    batch = max(1, min(spp, MAX_WAVEFRONT // (w * h)))
    total = np.zeros((3, h * w))
    done = 0
    while done < spp:
        n = min(batch, spp - done)
        ray = sensor_rays(mi, sensor, n)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed + done, w * h * n)
        spec, _, _ = integrator.sample(mscene, sampler, ray, None, True)
        stokes = _to_sensor_stokes(mi, sensor, ray, spec)
        total += np.stack([np.asarray(c, dtype=float).reshape(n, h * w).sum(0) for c in stokes])
        done += n
        if tick is not None:
            tick(n)
    return (total / spp).reshape(3, h, w)


def trace_stokes_area(mi: ModuleType, mscene: Any, pixels: np.ndarray, *, side: int, seed: int = 0,
                      tick=None) -> np.ndarray:  # fmt: skip
    """Stokes S0, S1, S2 averaged over the area of each marked pixel, in the sensor frame (0 at the others).

    A pixel integrating the light over its area, as a camera's does: ``side²`` samples per pixel, one uniformly
    in each cell of a ``side`` × ``side`` grid over it (jittered stratification: an image edge crossing the
    pixel is found to within a cell, where independent samples would miss a lamp's image a tenth of a pixel
    wide as often as not).

    Parameters
    ----------
    mi : module
    mscene : mitsuba.Scene
        With a ``path`` integrator.
    pixels : ndarray of bool, shape (H, W)
        The pixels to trace.
    side : int
        Cells per pixel side.
    seed : int
    tick : callable, optional
        Called with the share of the image's samples done (in samples per pixel of the whole image).

    Returns
    -------
    ndarray, shape (3, H, W)

    Raises
    ------
    UserError
        Mitsuba's scalar fallback (no LLVM): it traces pixel centres only.
    """
    from .llvm import is_scalar

    if is_scalar(mi):
        raise UserError("calibration targets and lamps rays can hit need Mitsuba's LLVM variant (its scalar "
                        "fallback traces pixel centres only): install libLLVM (docs/physics.md)")
    sensor = mscene.sensors()[0]
    w, h = sensor.film().size()
    idx = np.flatnonzero(pixels.ravel())
    total = np.zeros((3, h * w))
    cells = side * side
    per = max(1, MAX_WAVEFRONT // max(idx.size, 1))
    rng = np.random.default_rng(seed)
    for start in range(0, cells if idx.size else 0, per):
        k = np.repeat(np.arange(start, min(cells, start + per)), idx.size)
        p = np.tile(idx, len(k) // idx.size)
        u, v = rng.random((2, k.size))
        x = ((p % w) + ((k % side) + u) / side) / w
        y = ((p // w) + ((k // side) + v) / side) / h
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(mi.Float(x.astype(np.float32)), mi.Float(y.astype(np.float32))),
                                   mi.Point2f(0.5))  # fmt: skip
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed + start, k.size)
        spec, _, _ = mscene.integrator().sample(mscene, sampler, ray, None, True)
        for c, s in enumerate(_to_sensor_stokes(mi, sensor, ray, spec)):
            total[c] += np.bincount(p, weights=np.asarray(s, dtype=float).reshape(-1), minlength=h * w)
        if tick is not None:
            tick(k.size / (w * h))
    return (total / cells).reshape(3, h, w)


def _scalar_rays(mi: ModuleType, sensor: Any) -> list:
    """Pixel-centre rays one by one (scalar variants), row-major."""
    w, h = sensor.film().size()
    return [sensor.sample_ray(0.0, 0.5, mi.Point2f((x + 0.5) / w, (y + 0.5) / h), mi.Point2f(0.5))[0]
            for y in range(h) for x in range(w)]  # fmt: skip


def _trace_stokes_scalar(mi: ModuleType, mscene: Any, *, spp: int, seed: int, tick) -> np.ndarray:
    """:func:`trace_stokes` for scalar spectral variants: every spectrum is flat, so wavelength 0 is exact."""
    import drjit as dr

    sensor = mscene.sensors()[0]
    w, h = sensor.film().size()
    integrator = mscene.integrator()
    vertical = sensor.world_transform() @ mi.Vector3f(0.0, 1.0, 0.0)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, 1)
    out = np.zeros((3, h * w))
    for k, ray in enumerate(_scalar_rays(mi, sensor)):
        rot = mi.Spectrum(mi.mueller.rotate_stokes_basis(-ray.d, mi.mueller.stokes_basis(-ray.d),
                                                         dr.cross(ray.d, vertical)))  # fmt: skip
        for _ in range(spp):
            spec = rot * integrator.sample(mscene, sampler, ray, None, True)[0]
            out[:, k] += [spec[i, 0][0] for i in range(3)]
            sampler.advance()
    if tick is not None:
        tick(spp)
    return (out / spp).reshape(3, h, w)


def surface(mi: ModuleType, mscene: Any) -> tuple[np.ndarray, np.ndarray]:
    """Exact ``P`` and ``N`` ``[H, W, 3]`` at pixel centres (NaN where no surface)."""
    from .llvm import is_scalar

    sensor = mscene.sensors()[0]
    w, h = sensor.film().size()
    if is_scalar(mi):
        hits = [mscene.ray_intersect(ray) for ray in _scalar_rays(mi, sensor)]
        valid = np.array([bool(si.is_valid()) for si in hits]).reshape(h, w)
        P = np.array([list(si.p) for si in hits], float).reshape(h, w, 3)
        N = np.array([list(si.sh_frame.n) for si in hits], float).reshape(h, w, 3)
    else:
        si = mscene.ray_intersect(sensor_rays(mi, sensor))
        valid = np.asarray(si.is_valid(), dtype=bool).reshape(h, w)
        P = np.stack([np.asarray(c, float) for c in si.p], -1).reshape(h, w, 3)
        N = np.stack([np.asarray(c, float) for c in si.sh_frame.n], -1).reshape(h, w, 3)
    P[~valid] = np.nan
    N[~valid] = np.nan
    return P, N


def object_ids(mi: ModuleType, sensor: Any, groups: Sequence[Any]) -> np.ndarray:
    """``[H, W]`` int32: which object each pixel-centre ray meets first (0: none, ``i + 1``: ``groups[i]``).

    Each of ``groups`` is a Mitsuba scene holding one object's shapes alone; a pixel's id is the group whose
    nearest hit along its ray is nearest. Intersecting each object by itself, not asking the whole scene which
    shape it hit: Mitsuba merges meshes that share a BSDF (a bookend's two plates, two cards) into one shape
    without their names.
    """
    from .llvm import is_scalar

    w, h = sensor.film().size()
    if is_scalar(mi):
        rays = _scalar_rays(mi, sensor)
        t = np.array([[float(g.ray_intersect(ray).t) for ray in rays] for g in groups])
    else:
        rays = sensor_rays(mi, sensor)
        t = np.stack([np.asarray(g.ray_intersect(rays).t, dtype=float) for g in groups])
    t = np.where(np.isfinite(t), t, np.inf)
    first = np.argmin(t, axis=0)
    return np.where(np.isfinite(t.min(axis=0)), first + 1, 0).astype(np.int32).reshape(h, w)


def lamp_inside(mi: ModuleType, mscene: Any, position: Any) -> bool:
    """Whether ``position`` is inside a closed object: an odd number of surface crossings along each of 3 rays.

    Requiring all three (not a majority) keeps a lamp outside an open PLY mesh (a plane crossed by some rays
    only) from being reported as inside.
    """
    votes = 0
    for d in ((0.5773, 0.5774, 0.5774), (-0.267, 0.535, -0.802), (0.0, -0.6, 0.8)):
        o, crossings = mi.Point3f(*position), 0
        for _ in range(64):
            si = mscene.ray_intersect(mi.Ray3f(o, mi.Vector3f(*d)))
            if not bool(np.asarray(si.is_valid()).reshape(-1)[0]):
                break
            crossings += 1
            o = si.spawn_ray(mi.Vector3f(*d)).o
        votes += crossings % 2
    return votes == 3


# --------------------------------------------------------------------------- render_clean


def render_key(scene: Scene) -> str:
    """Hash of everything the clean render depends on (not noise, seed, angles, nor the nuisances applied after
    rendering; the camera's sub-pixel shift of this seed, not the seed); lamp nuisances and the camera shift at
    their off values are left out, so a scene without them keeps its v1 key."""
    doc = scene.model_dump(mode="json")
    lamps = [_lamp_key(spec) for spec in scene.lamps]
    lamp_key = "lamp" if len(lamps) == 1 else "lamps"  # a one-lamp scene keeps its key from before lamps existed
    doc[lamp_key] = lamps[0] if len(lamps) == 1 else lamps
    shift = scene.camera.shift_for(scene.capture.seed)  # what the seed does to the render, and only that
    doc["camera"] = {k: v for k, v in doc["camera"].items() if k not in ("shift_px", "jitter_px")}
    if shift != (0.0, 0.0):
        doc["camera"]["shift_px"] = list(shift)
    cap = doc["capture"]
    relevant = {
        "version": RENDER_VERSION,
        **{k: doc[k] for k in ("camera", "object", "material", lamp_key)},
        "spp": cap["spp"],
        "max_depth": cap["max_depth"],
    }
    if scene.targets:  # a scene without targets keeps its key from before targets existed
        relevant["targets"] = doc["targets"]
    if scene.object.type == "mesh":
        relevant["mesh_sha256"] = file_sha256(scene.object.file)
    return hashlib.sha256(json.dumps(relevant, sort_keys=True).encode()).hexdigest()[:24]


def _lamp_key(spec: LampSpec) -> dict[str, Any]:
    """What a lamp contributes to :func:`render_key`: v1's keys, and the nuisances away from their off values."""
    doc = spec.model_dump(mode="json")
    default = LampSpec(position=spec.position).model_dump(mode="json")
    unused = {"samples"} if spec.radius == 0 else set()  # a point lamp is not sampled
    return {k: v for k, v in doc.items() if k in LAMP_V1_KEYS or (v != default[k] and k not in unused)}


#: Memory a render needs, measured (peak resident set of ``nearlight render``,
#: Mitsuba 3.9.1, 8 analyzer angles: 216 MB at 160x120, 396 MB at 640x480, 936 MB
#: at 1280x960, i.e. about 600 bytes per pixel above a 200 MB base), with margin:
#: a base, bytes per pixel, per analyzer angle per pixel, and per pixel again
#: when every colour channel is rendered separately (``max_depth`` > 2 or a
#: Mitsuba material).
MEMORY_BASE = 300e6
MEMORY_PER_PIXEL = 400.0
MEMORY_PER_ANGLE_PIXEL = 40.0
MEMORY_PER_PIXEL_PER_CHANNEL_PASSES = 200.0
#: Per pixel for each lamp after the first: its own Stokes images of two parts, float64 then float32.
MEMORY_PER_PIXEL_PER_EXTRA_LAMP = 250.0


def memory_needed(scene: Scene) -> float:
    """Bytes a render of ``scene`` and the capture written from it need at their peak (an estimate)."""
    pixels = scene.camera.width * scene.camera.height
    per_pixel = MEMORY_PER_PIXEL + MEMORY_PER_ANGLE_PIXEL * len(scene.capture.analyzer_angles_deg)
    if isinstance(scene.material, MitsubaMaterial) or scene.capture.max_depth > 2:
        per_pixel += MEMORY_PER_PIXEL_PER_CHANNEL_PASSES
    if len(scene.lamps) > 1:
        per_pixel += MEMORY_PER_PIXEL_PER_EXTRA_LAMP * (len(scene.lamps) - 1)
    return MEMORY_BASE + pixels * per_pixel


def memory_available() -> float | None:
    """Bytes this process can still use: ``MemAvailable`` and the address-space limit (None when unknown)."""
    import resource

    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = float(line.split()[1]) * 1024
    except OSError:
        pass
    if avail is None:
        try:
            avail = float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            avail = None
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        avail = soft if avail is None else min(avail, float(soft))
    return avail


def check_memory(scene: Scene) -> None:
    """Refuse, before anything starts, a render that will not fit in memory.

    Raises
    ------
    UserError
        Naming ``camera.resolution`` and the memory it needs.
    """
    need, avail = memory_needed(scene), memory_available()
    if avail is not None and need > avail:
        w, h = scene.camera.width, scene.camera.height
        raise UserError(
            f"{scene.source}: camera.resolution: a {w}x{h} render needs about {need / 1e9:.1f} GB of memory, "
            f"{avail / 1e9:.1f} GB is available; lower camera.resolution"
        )


def render_clean(scene: Scene, *, cache_dir: str | os.PathLike | None = None, progress: bool = True) -> Capture:
    """Render ``scene`` to a noise-free capture.

    Parameters
    ----------
    scene : Scene
    cache_dir : path-like, optional
        Folder of cached renders, keyed by :func:`render_key`; a hit skips Mitsuba.
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    Capture
        ``stack`` for ``capture.analyzer_angles_deg``, exact ``P``/``N``,
        ``extra``: ``S0``, ``S1``, ``S2``, ``truth_specular``,
        ``truth_diffuse`` (analytic materials), ``mask``; ``truth`` with lamp
        and BSDF.

    Raises
    ------
    UserError
        The camera sees no object, the lamp is inside it, the render will not
        fit in memory (:func:`check_memory`), or Mitsuba cannot load a
        ``mitsuba`` material.
    """
    check_memory(scene)
    key = render_key(scene)
    cached = None if cache_dir is None else Path(cache_dir) / f"{key}.npz"
    if cached is not None and cached.is_file():
        try:
            with np.load(cached) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, KeyError):
            arrays = None  # a damaged cache entry: render again
        if arrays is not None and not _cache_entry_ok(arrays, scene):
            arrays = None  # not what this render produces (damaged, or from another version): render again
    else:
        arrays = None
    if arrays is None:
        arrays = _render_arrays(scene, progress=progress)
        if cached is not None:
            try:
                _save_atomic(cached, arrays)
            except OSError as exc:  # the render itself is fine: go on without caching it
                import sys

                print(f"nearlight: note: {cached}: cannot write the render cache ({exc.strerror or exc})",
                      file=sys.stderr)  # fmt: skip
    return assemble(scene, arrays, key=key)


def _cache_entry_ok(arrays: dict[str, np.ndarray], scene: Scene) -> bool:
    """Whether a cached render has every array :func:`assemble` needs, with this scene's shapes."""
    hw = (scene.camera.height, scene.camera.width)
    want = {"P": (*hw, 3), "N": (*hw, 3), "to_world": (4, 4), "stokes_full": (3, *hw, 3)}
    if needs_ids(scene):
        want["object_id"] = hw
    for part in ("specular", "diffuse"):
        if f"stokes_{part}" in arrays:
            want[f"stokes_{part}"] = (3, *hw, 3)
            if len(scene.lamps) > 1:  # every lamp's own part too
                want.update({f"stokes_{part}_lamp{i}": (3, *hw, 3) for i in range(len(scene.lamps))})
    return all(k in arrays and arrays[k].shape == shape and arrays[k].dtype.kind == ("i" if k == "object_id" else "f")
               for k, shape in want.items())  # fmt: skip


def _save_atomic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays), suffix=".npz")  # np.savez adds .npz to other names


#: Scratch folders of renders (mesh files for Mitsuba) in the temporary folder:
#: ``nearlight-render-<pid>-<random>``. They are removed when the render ends,
#: also on SIGTERM and Ctrl-C; one left by a render killed with SIGKILL is
#: removed by the next render once its process is gone.
SCRATCH_PREFIX = "nearlight-render-"


def _remove_stale_scratch() -> None:
    """Remove scratch folders of this user's renders whose process no longer runs."""
    import shutil

    root = Path(tempfile.gettempdir())
    try:
        entries = list(root.glob(f"{SCRATCH_PREFIX}*-*"))
    except OSError:
        return
    for folder in entries:
        pid = folder.name[len(SCRATCH_PREFIX):].split("-", 1)[0]
        try:
            if not pid.isdigit() or folder.is_symlink() or folder.stat().st_uid != os.getuid():
                continue
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(folder, ignore_errors=True)
        except OSError:
            continue


_MITSUBA_TAG = re.compile(r"\[[A-Za-z_]+\.(?:cpp|h):\d+\]\s*|(?:At|While loading) dictionary node \"[a-z_.]+\":\s*")


def check_mitsuba_bsdf(mi: ModuleType, scene: Scene) -> None:
    """Load a ``material.model: mitsuba`` BSDF once per colour channel, before any rendering.

    Raises
    ------
    UserError
        Naming the scene file and ``material.bsdf`` with Mitsuba's own reason
        (unknown plugin, a parameter of the wrong type, an unused parameter...).
    """
    if not isinstance(scene.material, MitsubaMaterial):
        return
    for channel in range(3):
        try:
            mi.load_dict(_per_channel(scene.material.bsdf, channel))
        except Exception as exc:  # Mitsuba raises RuntimeError/TypeError/ValueError for a bad dict
            reason = " ".join(_MITSUBA_TAG.sub("", str(exc)).split()) or type(exc).__name__
            raise UserError(f"{scene.source}: material.bsdf: Mitsuba cannot load it: {reason}") from None


def _load_scene(mi: ModuleType, scene: Scene, doc: dict) -> Any:
    """``mi.load_dict`` of a scene; a mesh file Mitsuba cannot read is a :class:`UserError` naming ``object.file``."""
    try:
        return mi.load_dict(doc)
    except Exception as exc:
        if scene.object.type != "mesh":
            raise  # our own scene dict: a bug, keep the traceback
        reason = " ".join(_MITSUBA_TAG.sub("", str(exc)).split()) or type(exc).__name__
        raise UserError(f"{scene.source}: object.file: Mitsuba cannot load {scene.object.file}: {reason}") from None


#: Cells per pixel side of the ``others`` pass (:func:`trace_stokes_area`): 32 × 32 = 1024 samples over each
#: pixel that sees (or borders) a target or a lamp, where a lamp's image on a mirror ball may be a tenth of a pixel
#: wide; a pixel its edge crosses is then within about one cell row of the edge's length (≤ 1/32 of the pixel).
OTHERS_SIDE = 32


def traced_spp(scene: Scene, lamp: int | None = None) -> int:
    """Samples traced per pixel in one pass lighting lamp ``lamp`` (default: the one lamp of a one-lamp scene):
    ``capture.spp``, times ``lamp.samples`` for a sphere lamp (``lamp.radius`` > 0)."""
    spec = scene.lamp if lamp is None else scene.lamps[lamp]
    spp = scene.capture.spp
    return spp * spec.samples if spec.radius > 0 else spp


def _render_arrays(scene: Scene, *, progress: bool) -> dict[str, np.ndarray]:
    """Run Mitsuba: ``P``, ``N``, ``to_world`` and Stokes ``[3, H, W, 3]`` per part.

    Each lamp is rendered in its own passes and the parts are summed over the lamps (radiance is linear in the
    lamps; one lamp per pass keeps a point lamp's direct light exact, where Mitsuba would pick one emitter per
    sample). With several lamps, every lamp's own specular and diffuse parts are kept too
    (``stokes_<part>_lamp<i>``); a one-lamp scene renders exactly as before lamps were a list.

    With calibration targets or a lamp rays can hit (:func:`~nearlight.generator.targets.needs_ids`), the
    arrays also hold ``object_id`` (:func:`object_ids`); the specular and diffuse parts are the object's alone
    (zero at every other pixel: a lamp seen directly is in every pass), and with direct light only the light of
    everything else is the ``others`` pass (the object black), added to the full image. The ``others`` pass is
    sampled over the area of each pixel that sees or borders a target or a lamp (:func:`trace_stokes_area`,
    :data:`OTHERS_SIDE`² samples), as a camera integrates: a lamp's image on a mirror ball is often smaller than
    a pixel and would fall between pixel centres. So a pixel whose centre
    sees the object holds the object's light at that point (its ``P``, ``N``), exactly as before targets existed,
    and any other pixel the light of everything but the object over its area (a target's edge pixel is dimmer
    by the fraction of it the object covers).
    """
    from tqdm import tqdm

    from .llvm import mitsuba

    mi = mitsuba()
    check_mitsuba_bsdf(mi, scene)
    analytic = not isinstance(scene.material, MitsubaMaterial)
    linear = analytic and scene.capture.max_depth == 2
    several = len(scene.lamps) > 1
    ids = needs_ids(scene)
    passes = []
    for i in range(len(scene.lamps)):
        if linear:  # unit renders, scaled per channel below
            passes += [(p, None, i) for p in ("specular", "diffuse", *(("others",) if ids else ()))]
        else:
            parts = ("specular", "diffuse", "full") if analytic else ("full",)
            passes += [(p, c, i) for c in range(3) for p in (*parts, *(("others",) if ids else ()))]
    _remove_stale_scratch()
    total = sum(traced_spp(scene, i) for p, _, i in passes if p != "others")
    with tempfile.TemporaryDirectory(prefix=f"{SCRATCH_PREFIX}{os.getpid()}-") as scratch, tqdm(
        total=total, desc=f"render ({len(passes)} passes)", unit="spp", disable=not progress, leave=False
    ) as bar:
        stokes: dict[str, np.ndarray] = {}
        for n, (part, channel, i) in enumerate(passes):
            doc = scene_dict(mi, scene, part=part, channel=channel, scratch=Path(scratch), lit=[i])
            mscene = _load_scene(mi, scene, doc)
            if n == 0:  # every pass has the same geometry: check it before any rendering
                P, N = surface(mi, mscene)
                id_image = _object_ids(mi, scene, mscene, Path(scratch)) if ids else None
                _check_geometry(mi, scene, mscene, P, id_image, Path(scratch))
                to_world = np.asarray(mscene.sensors()[0].world_transform().matrix, float).reshape(4, 4)
            if part == "others":  # over the area of every pixel that sees or borders a target or a lamp
                around = binary_dilation((id_image > 1), iterations=1)
                s = trace_stokes_area(mi, mscene, around, side=OTHERS_SIDE)
            else:
                s = trace_stokes(mi, mscene, spp=traced_spp(scene, i), tick=bar.update)
            if id_image is not None and part != "full":  # a pixel's light is the object's where its centre sees it
                s = np.where((id_image == 1) == (part != "others"), s, 0.0)
            keys = [f"{part}_lamp{i}", part] if several else [part]
            if channel is None:
                scale = np.asarray(scene.lamps[i].intensity) * (1.0 if part == "others" else np.asarray(
                    scene.material.specular if part == "specular" else scene.material.kd
                ))
                value = s[..., None] * scale
                for key in keys:  # the first lamp's value as is (bit for bit the one-lamp render), then sums
                    stokes[key] = value if key not in stokes else stokes[key] + value
            else:
                for key in keys:
                    if key not in stokes:
                        stokes[key] = np.zeros((*s.shape, 3))
                        stokes[key][..., channel] = s
                    elif key == part and i > 0:
                        stokes[key][..., channel] += s
                    else:
                        stokes[key][..., channel] = s
    if linear:
        stokes["full"] = stokes["specular"] + stokes["diffuse"]
        if ids:
            stokes["full"] = stokes["full"] + stokes["others"]
    elif ids:  # the full pass traced pixel centres: every other pixel's light is the others pass's, over its area
        stokes["full"] = np.where((id_image == 1)[..., None], stokes["full"], stokes["others"])
    out = {"P": P, "N": N, "to_world": to_world}
    if id_image is not None:
        out["object_id"] = id_image
    out.update({f"stokes_{k}": v.astype(np.float32) for k, v in stokes.items()
                if not k.startswith(("full_", "others"))})  # fmt: skip
    return out


def _object_ids(mi: ModuleType, scene: Scene, mscene: Any, scratch: Path) -> np.ndarray:
    """:func:`object_ids` of a render pass's sensor, one group per name of
    :func:`~nearlight.generator.targets.object_names`: the object, each target, each lamp rays can hit."""
    groups = [{"type": "scene", **object_dicts(mi, scene, BLACK, scratch)}]
    for name, shape in target_shapes(scene, lit=False).items():
        groups.append({"type": "scene", name: {**shape, "to_world": _transform(mi, shape["to_world"])}
                       if "to_world" in shape else shape})  # fmt: skip
    groups += [{"type": "scene", "lamp": {"type": "sphere", "center": list(lamp.position), "radius": lamp.radius,
                                          "bsdf": BLACK}}
               for lamp in scene.lamps if lamp.intersectable]  # fmt: skip
    return object_ids(mi, mscene.sensors()[0], [_load_scene(mi, scene, g) for g in groups])


def _check_geometry(mi: ModuleType, scene: Scene, geometry: Any, P: np.ndarray, ids: np.ndarray | None,
                    scratch: Path) -> None:  # fmt: skip
    """Refuse a camera that sees no part of the object, a lamp inside the object, a sphere lamp reaching it.

    ``ids``: :func:`object_ids` when the scene has other objects (targets, a lamp rays can hit): the object's
    pixels are those with id 1, and the lamp's inside is tested against the object's shapes alone.
    """
    from .shapes import CLOSED

    seen = "the object" if not scene.targets else "the object or its targets"
    if ids is not None:  # a view of the targets alone is a calibration shot: the object's pixels may be none
        P = np.where(((ids == 1) | (ids > 1) & (ids <= 1 + len(scene.targets)))[..., None], P, np.nan)
    if not np.isfinite(P).all(axis=-1).any():
        raise UserError(
            f"{scene.source}: camera: sees no part of {seen} (check camera.position/look_at/fov_x_deg "
            f"and object.position)"
        )
    if ids is not None:
        P = np.where((ids == 1)[..., None], P, np.nan)
    if ids is not None and scene.object.type in CLOSED:
        geometry = _load_scene(mi, scene, {"type": "scene", **object_dicts(mi, scene, BLACK, scratch)})
    for i, spec in enumerate(scene.lamps):
        name = lamp_name(i, len(scene.lamps))
        if scene.object.type in CLOSED and lamp_inside(mi, geometry, spec.position):
            raise UserError(f"{scene.source}: {name}.position: {list(spec.position)} is inside the object")
        if spec.radius > 0 and np.isfinite(P).any():
            gap = float(np.nanmin(np.linalg.norm(P - np.asarray(spec.position), axis=-1)))
            if gap <= spec.radius:
                raise UserError(
                    f"{scene.source}: {name}.radius: {spec.radius} m reaches the object (a surface point the camera "
                    f"sees is {gap:.4g} m from the lamp's centre)"
                )


def lamp_truth(scene: Scene, i: int = 0) -> dict[str, Any]:
    """Lamp ``i`` of the scene as ``truth.lamps[i]`` of capture format v2 (world frame, metres, W/sr)."""
    spec = scene.lamps[i]
    facing = scene.facing(i)
    axis = spec.anisotropy_axis if spec.anisotropy_axis is not None else facing
    return {
        "position": list(spec.position),
        "intensity": list(spec.intensity),
        "radius_m": spec.radius,
        "anisotropy": None if spec.anisotropy_k == 0 else
        {"k": spec.anisotropy_k, "axis": (np.asarray(axis, float) / np.linalg.norm(axis)).tolist()},
        "polarizer_axis": filter_axes(spec.polarizer_axis, facing)[0].tolist(),
        "polarizer_extinction_ratio": spec.polarizer_extinction_ratio,
    }  # fmt: skip


def shared_lamp_filter(scene: Scene) -> LampFilter | None:
    """``rig.lamp_filter`` of a scene whose lamps' filters share one ``polarizer_axis`` (else None).

    Every filter faces ``object.position`` (:meth:`Scene.facing`), so that is
    the filters' ``aim``: with the shared axis, what a rig whose lamps are aimed
    at the object and whose filters were set alike knows, without knowing
    where the lamps are.
    """
    axes = {tuple(float(c) for c in lamp.polarizer_axis) for lamp in scene.lamps}
    if len(axes) != 1:
        return None
    return LampFilter(axis=axes.pop(), aim=tuple(float(c) for c in scene.object.position))


def truth_of(scene: Scene) -> dict[str, Any]:
    """The capture's ``truth`` for ``scene``: ``lamps`` lists every lamp (:func:`lamp_truth`); a one-lamp scene also
    has v1's ``lamp_position`` and ``lamp_intensity``, a scene with several lamps has neither (single-lamp scoring
    then fails loudly instead of grading against one of them)."""
    one = len(scene.lamps) == 1
    v1 = {"lamp_position": list(scene.lamp.position), "lamp_intensity": list(scene.lamp.intensity)} if one else {}
    targets = {"targets": target_truth(scene)} if scene.targets else {}
    return {**v1, "bsdf": scene.material.truth(), "lamps": [lamp_truth(scene, i) for i in range(len(scene.lamps))],
            **targets}  # fmt: skip


def assemble(scene: Scene, arrays: dict[str, np.ndarray], *, key: str) -> Capture:
    """The clean :class:`Capture` from rendered arrays."""
    P, N = arrays["P"].astype(np.float32), arrays["N"].astype(np.float32)
    full = arrays["stokes_full"]
    mask = np.isfinite(P).all(axis=-1)
    extra = {f"S{i}": full[i] for i in range(3)}
    for part in ("specular", "diffuse"):
        if f"stokes_{part}" in arrays:
            extra[f"truth_{part}"] = arrays[f"stokes_{part}"][0]
    for i in range(len(scene.lamps) if len(scene.lamps) > 1 else 0):
        for part in ("specular", "diffuse"):
            if f"stokes_{part}_lamp{i}" in arrays:
                extra[f"truth_{part}_lamp{i}"] = arrays[f"stokes_{part}_lamp{i}"][0]
    extra["mask"] = mask.astype(np.float32)
    angles = np.asarray(scene.capture.analyzer_angles_deg, float)
    one = len(scene.lamps) == 1
    cam = scene.camera
    return Capture(
        width=cam.width,
        height=cam.height,
        camera=Camera(position=np.asarray(cam.position, float), to_world=arrays["to_world"], fov_x_deg=cam.fov_x_deg),
        P=P,
        N=N,
        stack=analyzer_stack(full, angles).astype(np.float32),
        analyzer_angles_deg=angles,
        # v1's one lamp polarizer axis; with several lamps each has its own (truth.lamps), and no one is "the" axis
        lamp_polarizer_axis=filter_axes(scene.lamp.polarizer_axis, scene.lamp_facing)[0] if one else None,
        truth=truth_of(scene),
        rig=Rig(lamps=len(scene.lamps), lamp_polarizer_extinction_ratio=scene.lamps[0].polarizer_extinction_ratio,
                lamp_filter=None if one else shared_lamp_filter(scene), targets=rig_targets(scene)),
        object_id=arrays.get("object_id"),
        objects=object_names(scene) if "object_id" in arrays else (),
        extra=extra,
        meta={
            "generator": {
                "scene": scene.model_dump(mode="json"),
                "render_key": key,
                "pixel_sampling": "centre",
                "analyzer_angle": "counter-clockwise from the image's rightward horizontal, as viewed",
            }
        },
    )
