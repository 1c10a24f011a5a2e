"""Closed-form renders of scene files: the arrays Mitsuba would render, by arithmetic (numpy only).

:func:`closed_form_arrays` returns what :func:`nearlight.generator.render._render_arrays`
returns for a scene the closed form covers (:func:`not_covered` says why one is not):
``P``, ``N``, ``to_world`` and the Stokes images ``[3, H, W, 3]`` of the specular,
diffuse and full light (and each lamp's parts, with several lamps), so that the same
:func:`~nearlight.generator.render.assemble` and the same rig
(:func:`~nearlight.generator.nuisances.through_rig`) make the capture: a capture that
differs from Mitsuba's render only by float rounding (issue 36; checked pixel by pixel
in ``tests/generator/test_closed_form.py``).

What it computes, per pixel centre, with direct light only (the paper's model, and
``capture.max_depth: 2``):

- **geometry**: the pixel-centre rays of Mitsuba's perspective sensor
  (:func:`nearlight.physics.camera.camera_rays`) against the object's primitives as
  :mod:`nearlight.generator.shapes` places them (a board's rectangle, a sphere, a
  cylinder's tube and its two caps, a bookend's two plates); ``P`` the nearest hit,
  ``N`` its primitive's normal (Mitsuba's shading normal: outward, a plate's ``+z``
  whichever side is seen). A bookend's plates shadow each other (a shadow ray to each
  lamp); the convex objects shadow only where the lamp is below the surface;
- **the lamp** (:mod:`nearlight.generator.lamp`): radiant intensity ``I`` per channel,
  times ``max(0, k·a)^k`` for a beam, over ``r²``, through its filter: an ideal linear
  polarizer, or a diattenuator of extinction ratio ε (transmittances 1 and 1/ε), along
  Korger's effective axis ``t = k × â⊥`` of each ray ``k``. A sphere lamp (``radius`` > 0,
  radiance ``I/(π a²)``) is integrated over the cone it subtends by a product quadrature
  refined until two successive rules agree to 1e-4 (:func:`sphere_nodes`; Mitsuba samples
  the same cone by Monte Carlo), its shadows soft where the object shadows itself;
- **the specular lobe** (:mod:`nearlight.physics.reflectance`, ``f·cos θi``) and its
  Mueller matrix in the microfacet's s/p frames: ``ideal``, the mirror (the field ``e``
  leaves as ``e − 2(e·h)h``); ``fresnel``, the dielectric's amplitude coefficients
  ``rs``, ``rp`` at the microfacet angle, normalised by ``M00 = (rs² + rp²)/2`` as the
  generator's BSDF normalises Mitsuba's matrix. The filtered light is the incoherent sum
  of two linear states (along ``t``, weight 1, and across it, weight 1/ε), each reflected
  as a field: no Stokes-frame rotation is written out;
- **the diffuse lobe**: ``kd/π · cos θi``, fully depolarizing;
- a **texture** (:mod:`nearlight.physics.texture`): the checker's sign scales ``kd`` and
  the roughness, as the generator's BSDF does.

Stokes are in the analyzer's frame of each camera ray (``x = (−v) × up``, ``y = v × x``,
``v`` towards the camera), as :func:`nearlight.generator.render.trace_stokes` rotates
Mitsuba's: ``I(θ) = ½ (S0 + S1 cos 2θ + S2 sin 2θ)``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from ..files.digests import stable_hash
from ..physics.camera import camera_rays, look_at_matrix
from ..physics.polarization import analyzer_frame, filter_axes, korger_axis
from ..physics.reflectance import brdf_shape, shading_geometry
from ..physics.texture import checker_sign, textured
from .scene import Bookend, Board, Cylinder, LampSpec, MitsubaMaterial, Scene, Sphere, lamp_name, placement

#: Object types the closed form intersects.
OBJECTS = ("board", "sphere", "cylinder", "bookend")
#: Objects whose every lit point sees the lamp (convex, or one plane): no shadow ray needed.
CONVEX = ("board", "sphere", "cylinder")
#: The renderer's name in render keys and in the capture's ``meta.generator.renderer``.
NAME = "closed-form"
#: A shadow ray's hits nearer than this fraction of the lamp's distance are the point's own surface.
SHADOW_EPS = 1e-6


def not_covered(scene: Scene) -> list[str]:
    """Why ``scene`` needs Mitsuba: one line per scene key the closed form does not cover (empty: covered).

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    list of str
        E.g. ``"object.type torus: a triangle mesh (no closed-form intersection here)"``.
    """
    why = []
    if scene.object.type not in OBJECTS:
        why.append(f"object.type {scene.object.type}: a triangle mesh (no closed-form intersection here)")
    if isinstance(scene.material, MitsubaMaterial):
        why.append("material.model mitsuba: a Mitsuba BSDF (no closed form)")
    if scene.capture.max_depth > 2 and scene.object.type not in CONVEX:
        why.append(f"capture.max_depth {scene.capture.max_depth}: interreflections of a concave object (Monte Carlo)")
    if scene.targets:
        why.append("targets: calibration targets (their shadows and images are Mitsuba's)")
    for i, lamp in enumerate(scene.lamps):
        if lamp.intersectable:
            why.append(f"{lamp_name(i, len(scene.lamps))}.intersectable: a lamp rays can hit (Mitsuba's)")
    return why


def closed_form_key(scene: Scene) -> str:
    """Hash of what a closed-form render of ``scene`` depends on (never a Mitsuba render's key)."""
    from .render import render_key

    return stable_hash([NAME, render_key(scene)])


# --------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class Hits:
    """The nearest hit of each ray: ``t`` (m, inf where none), ``N`` (unit normals, NaN where none) and the
    index of the primitive hit (-1 where none)."""

    t: np.ndarray
    N: np.ndarray
    which: np.ndarray


def rectangle_hits(o: np.ndarray, d: np.ndarray, centre, u, v, n) -> tuple[np.ndarray, np.ndarray]:
    """Hits of rays ``o + t d`` on the rectangle ``centre + a u + b v`` (|a|, |b| ≤ 1) of normal ``n``."""
    u, v, n = (np.asarray(x, float) for x in (u, v, n))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((np.asarray(centre, float) - o) @ n) / (d @ n)
        q = o + t[..., None] * d - centre
        a, b = q @ u / (u @ u), q @ v / (v @ v)
    ok = (t > 0) & (np.abs(a) <= 1) & (np.abs(b) <= 1)
    return np.where(ok, t, np.inf), np.broadcast_to(n / np.linalg.norm(n), d.shape)


def _disk(o: np.ndarray, d: np.ndarray, centre, radius: float, n) -> tuple[np.ndarray, np.ndarray]:
    """Hits on the disk of ``radius`` about ``centre`` with normal ``n`` (unit)."""
    n = np.asarray(n, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((np.asarray(centre, float) - o) @ n) / (d @ n)
        q = o + t[..., None] * d - centre
    ok = (t > 0) & (np.einsum("...i,...i->...", q, q) <= radius * radius)
    return np.where(ok, t, np.inf), np.broadcast_to(n, d.shape)


def sphere_hits(o: np.ndarray, d: np.ndarray, centre, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hits in front of the ray origin on a sphere, outward normals."""
    oc = o - np.asarray(centre, float)
    b = d @ oc if oc.ndim == 1 else np.einsum("...i,...i->...", d, oc)
    c = np.einsum("...i,...i->...", oc, oc) - radius * radius
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        root = np.sqrt(disc)
    near, far = -b - root, -b + root
    t = np.where(near > 0, near, far)
    t = np.where((disc > 0) & (t > 0), t, np.inf)
    with np.errstate(invalid="ignore"):
        N = (o + t[..., None] * d - centre) / radius
    return t, N


def hit_points(o: np.ndarray, d: np.ndarray, t: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points ``o + t d`` and normals ``N`` of a primitive's hits, ``(..., 3)``; NaN where ``t`` is inf (no hit)."""
    hit = np.isfinite(t)[..., None]
    with np.errstate(invalid="ignore"):
        P = o + np.where(hit, t[..., None], 0.0) * d
    return np.where(hit, P, np.nan), np.where(hit, N, np.nan)


def _tube(o: np.ndarray, d: np.ndarray, place: np.ndarray, radius: float, half: float) -> tuple[np.ndarray, np.ndarray]:
    """Hits on a cylinder's open tube along local z (|z| ≤ ``half``), outward radial normals (world)."""
    R, c = place[:3, :3], place[:3, 3]
    lo = (o - c) @ R  # local origin (R orthonormal: the inverse is its transpose)
    ld = d @ R
    a = ld[..., 0] ** 2 + ld[..., 1] ** 2
    b = lo[..., 0] * ld[..., 0] + lo[..., 1] * ld[..., 1]
    cc = lo[..., 0] ** 2 + lo[..., 1] ** 2 - radius * radius
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(b * b - a * cc)
        roots = [(-b - root) / a, (-b + root) / a]
    t = np.full(d.shape[:-1], np.inf)
    for r in reversed(roots):  # the near root wins where both are valid
        z = lo[..., 2] + r * ld[..., 2]
        ok = (r > 0) & (np.abs(z) <= half)
        t = np.where(ok, r, t)
    with np.errstate(invalid="ignore"):
        local = lo + t[..., None] * ld
        radial = np.concatenate([local[..., :2] / radius, np.zeros_like(local[..., :1])], axis=-1)
        return t, radial @ R.T


def primitives(scene: Scene) -> list:
    """The object as primitives: callables ``(o, d) -> (t, N)`` placed as :mod:`nearlight.generator.shapes`
    places Mitsuba's shapes.

    Raises
    ------
    ValueError
        An object type outside :data:`OBJECTS`.
    """
    obj = scene.object
    place = placement(obj)
    R, c = place[:3, :3], place[:3, 3]
    if isinstance(obj, Board):
        w, h = obj.size
        return [lambda o, d: rectangle_hits(o, d, c, R[:, 0] * w / 2, R[:, 1] * h / 2, R[:, 2])]
    if isinstance(obj, Sphere):
        return [lambda o, d: sphere_hits(o, d, c, obj.radius)]
    if isinstance(obj, Cylinder):
        half, r = obj.length / 2, obj.radius
        return [lambda o, d: _tube(o, d, place, r, half),
                lambda o, d: _disk(o, d, c + half * R[:, 2], r, R[:, 2]),
                lambda o, d: _disk(o, d, c - half * R[:, 2], r, -R[:, 2])]  # fmt: skip
    if isinstance(obj, Bookend):
        beta = np.radians(obj.bend_deg)
        d_b = R @ np.array([0.0, np.cos(beta), np.sin(beta)])
        n_b = R @ np.array([0.0, np.sin(beta), -np.cos(beta)])
        x, y = R[:, 0] * obj.width / 2, R[:, 1]
        return [lambda o, d: rectangle_hits(o, d, c + y * obj.length_a / 2, x, y * obj.length_a / 2, R[:, 2]),
                lambda o, d: rectangle_hits(o, d, c + d_b * obj.length_b / 2, x, -d_b * obj.length_b / 2, n_b)]  # fmt: skip
    raise ValueError(f"object.type {obj.type}: no closed-form intersection")


def nearest(prims: list, o: np.ndarray, d: np.ndarray) -> Hits:
    """The nearest hit of rays ``o + t d`` (``d`` shape ``(..., 3)``) over ``prims``."""
    t = np.full(d.shape[:-1], np.inf)
    N = np.full(d.shape, np.nan)
    which = np.full(d.shape[:-1], -1)
    for i, prim in enumerate(prims):
        ti, Ni = prim(o, d)
        closer = ti < t
        t = np.where(closer, ti, t)
        N = np.where(closer[..., None], Ni, N)
        which = np.where(closer, i, which)
    return Hits(t, N, which)


def shadowed(prims: list, P: np.ndarray, which: np.ndarray, lamp: np.ndarray) -> np.ndarray:
    """Whether the segment from each point ``P`` (on primitive ``which``) to ``lamp`` meets another primitive."""
    to = lamp - P
    dist = np.linalg.norm(to, axis=-1)
    d = to / dist[..., None]
    out = np.zeros(P.shape[:-1], bool)
    for i, prim in enumerate(prims):
        t, _ = prim(P, d)
        out |= (which != i) & (t > SHADOW_EPS * dist) & (t < dist * (1 - SHADOW_EPS))
    return out


# --------------------------------------------------------------------------- light


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


def _across(d: np.ndarray) -> np.ndarray:
    """A unit vector normal to each unit vector ``d`` (..., 3): ``d × x̂``, or ``d × ŷ`` where ``d`` is near x̂
    (:func:`nearlight.physics.reflectance.tangent_basis`'s choice, for arrays)."""
    return _unit(np.cross(d, np.where(np.abs(d[..., :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])))


def fresnel_amplitudes(cos_i: np.ndarray, eta: float | complex) -> tuple[np.ndarray, np.ndarray]:
    """A dielectric's or a conductor's amplitude reflection coefficients, in the frames where a mirror has
    ``rs = rp = 1``.

    ``rs = (η cos θt − cos θi)/(cos θi + η cos θt)``, ``rp = (η cos θi − cos θt)/(η cos θi + cos θt)``: both
    ``(η − 1)/(η + 1)`` at normal incidence, ``rp = 0`` at Brewster's angle and negative beyond it (Born & Wolf's
    coefficients, with ``rs``'s sign turned so that the p frame is the mirror image of the incident one). A
    conductor's complex index ``η = n + iκ`` gives complex coefficients (``cos θt`` the principal root, the
    transmitted wave decaying): ``|rs|² = |rp|² = ((n − 1)² + κ²)/((n + 1)² + κ²)`` at normal incidence, both
    tending to 1 as ``κ → ∞`` (the ideal mirror).

    Parameters
    ----------
    cos_i : ndarray
        Cosine of the angle of incidence on the microfacet, in [0, 1].
    eta : float or complex
        Relative index: real (> 1: no total internal reflection) for a dielectric, ``n + iκ`` (κ ≥ 0) for a
        conductor.

    Returns
    -------
    rs, rp : ndarray, shape of ``cos_i``
        Real for a real ``eta``, complex for a complex one.
    """
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = np.sqrt(1.0 - sin2_t) if np.iscomplexobj(sin2_t) else np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    rs = (eta * cos_t - cos_i) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return rs, rp


def reflection_frames(k: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The s and p directions of light travelling along ``k`` onto a surface of normal ``n``, before and after
    reflection: ``s = k × n`` (normalised), ``p = s × k`` and ``p'`` its mirror image, the frames in which a mirror
    has ``rs = rp = 1`` (:func:`fresnel_amplitudes`).

    Parameters
    ----------
    k, n : ndarray, shape (m, 3)
        Unit propagation directions (towards the surface) and unit normals (a microfacet's ``h``).

    Returns
    -------
    s, p_in, p_out : ndarray, shape (m, 3)
    """
    s = np.cross(k, n)
    norm = np.linalg.norm(s, axis=-1, keepdims=True)
    # normal incidence (retro-reflection): every direction is s; rs = rp there, so any choice gives the same field
    s = np.where(norm > 1e-12, s / np.maximum(norm, 1e-300), _across(k))
    p_in = np.cross(s, k)
    return s, p_in, p_in - 2.0 * _dot(p_in, n)[..., None] * n


def reflected_states(k: np.ndarray, v: np.ndarray, fields: list[tuple[np.ndarray, float]], *,
                     fresnel_eta: float | None) -> Iterator[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """Each incident linear state reflected by the microfacet that sends ``k`` towards ``v``.

    Parameters
    ----------
    k : ndarray, shape (n, 3)
        Unit propagation directions of the incident light (lamp → point).
    v : ndarray, shape (n, 3)
        Unit directions from the point towards the camera.
    fields : list of (ndarray (n, 3), float)
        Incoherent linear states: unit field directions normal to ``k`` and their weights.
    fresnel_eta : float or None
        None: the ideal mirror; else a dielectric of that index.

    Yields
    ------
    e : ndarray, shape (n, 3)
        The reflected field (normal to ``v``); its squared length is the state's reflectance over ``M00``.
    weight : ndarray, shape (n,)
        The state's weight.
    """
    h = _unit(v - k)
    s, p_in, p_out = reflection_frames(k, h)
    if fresnel_eta is None:
        rs = rp = np.ones(k.shape[:-1])
    else:
        rs, rp = fresnel_amplitudes(np.clip(-_dot(k, h), 0.0, 1.0), fresnel_eta)
        m00 = np.sqrt(0.5 * (rs * rs + rp * rp))
        rs, rp = rs / m00, rp / m00
    for e, w in fields:
        yield (rs * _dot(e, s))[..., None] * s + (rp * _dot(e, p_in))[..., None] * p_out, np.full(k.shape[:-1], w)


def lamp_fields(spec: LampSpec, facing: np.ndarray, k: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """The light behind lamp ``spec``'s filter as incoherent linear states (unit fields, weights per unit
    intensity): ``½`` along Korger's effective axis ``t = k × â⊥`` and, for a finite extinction ratio ε,
    ``½/ε`` along ``k × t`` (:mod:`nearlight.generator.lamp`)."""
    t = korger_axis(k, filter_axes(spec.polarizer_axis, facing)[1])
    out = [(t, 0.5)]
    if spec.polarizer_extinction_ratio is not None:
        out.append((np.cross(k, t), 0.5 / spec.polarizer_extinction_ratio))
    return out


def beam(spec: LampSpec, facing: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The lamp's relative intensity along the propagation directions ``k``: ``max(0, k·a)^k`` (1: isotropic)."""
    if spec.anisotropy_k == 0:
        return np.ones(k.shape[:-1])
    a = np.asarray(facing if spec.anisotropy_axis is None else spec.anisotropy_axis, float)
    return np.maximum(_dot(k, a / np.linalg.norm(a)), 0.0) ** spec.anisotropy_k


def lamp_stokes(scene: Scene, i: int, P: np.ndarray, N: np.ndarray, up: np.ndarray,
                blocked: Callable[[np.ndarray], np.ndarray] | None,
                sign: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """Specular and diffuse Stokes ``(3, n, 3)`` (S0–S2, points, RGB) that lamp ``i`` sends to the camera.

    A point lamp in closed form; a sphere lamp (``radius`` > 0) by a product quadrature over the cone of
    directions it subtends from each point (:func:`sphere_nodes`: Gauss–Legendre in cos θ, the midpoint rule in φ),
    each pixel's node count doubled until two successive rules agree to :data:`QUADRATURE_RTOL` of the brightest
    value (:func:`_sphere_lamp`).

    Parameters
    ----------
    scene : Scene
    i : int
        The lamp.
    P, N : ndarray, shape (n, 3)
        Surface points (m) and unit shading normals.
    up : ndarray, shape (3,)
        The camera's up (``to_world``'s second column): the analyzer frame's reference.
    blocked : callable or None
        ``blocked(idx, lamp_points)`` -> bool: whether the segment from each point ``P[idx]`` to its lamp point
        meets the object (None: a convex object, never).
    sign : ndarray, shape (n,), or None
        The texture's checker sign, or None (untextured).

    Returns
    -------
    specular, diffuse : ndarray, shape (3, n, 3)
    error : float
        The quadrature's error estimate, relative to the brightest specular or diffuse value: the largest
        change between a pixel's last two rules (0 for a point lamp).
    """
    spec, mat = scene.lamps[i], scene.material
    everywhere = np.arange(len(P))
    if spec.radius == 0:
        lamp = np.broadcast_to(np.asarray(spec.position, float), P.shape)
        spec_s, diff = _unit_stokes(scene, i, P, N, up, lamp, 1.0 / np.sum((lamp - P) ** 2, -1), blocked, sign,
                                    everywhere)  # fmt: skip
        error = 0.0
    else:
        spec_s, diff, error = _sphere_lamp(scene, i, P, N, up, blocked, sign)
    intensity = np.asarray(spec.intensity, float)
    specular = spec_s[..., None] * (intensity * np.asarray(mat.specular, float))
    kd = np.broadcast_to(np.asarray(mat.kd, float), (len(P), 3))
    if sign is not None:
        kd = textured(kd, mat.texture.kd_contrast, sign[:, None])
    diffuse = np.zeros((3, len(P), 3))
    diffuse[0] = (diff / np.pi)[:, None] * kd * intensity
    return specular, diffuse, error


def _sphere_lamp(scene: Scene, i: int, P: np.ndarray, N: np.ndarray, up: np.ndarray,
                 blocked: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
                 sign: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """:func:`_unit_stokes` of a sphere lamp, integrated by :func:`sphere_nodes` pixel by pixel: each pixel's rule
    doubles (2, 4, 8... nodes in cos θ) until two successive rules agree to :data:`QUADRATURE_RTOL` of the
    brightest value of the first rule, or :data:`QUADRATURE_MAX_NODES`; returns the largest change left."""
    centre, radius = np.asarray(scene.lamps[i].position, float), scene.lamps[i].radius

    def rule(idx: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        spec_s, diff = np.zeros((3, len(idx))), np.zeros(len(idx))
        for lamp, weight in sphere_nodes(P[idx], centre, radius, n):
            s_j, d_j = _unit_stokes(scene, i, P[idx], N[idx], up, lamp, weight, blocked,
                                    None if sign is None else sign[idx], idx)  # fmt: skip
            spec_s += s_j
            diff += d_j
        return spec_s, diff

    active, n = np.arange(len(P)), 2
    spec_s, diff = rule(active, n)
    peak = max(float(np.abs(spec_s).max()), float(diff.max()), 1e-300)
    error = 0.0
    while len(active):
        n *= 2
        fine_s, fine_d = rule(active, n)
        change = np.maximum(np.abs(fine_s - spec_s[:, active]).max(0), np.abs(fine_d - diff[active])) / peak
        spec_s[:, active], diff[active] = fine_s, fine_d
        done = change <= QUADRATURE_RTOL
        if n >= QUADRATURE_MAX_NODES:
            error = float(change.max(initial=0.0))
            break
        error = max(error, float(change[done].max(initial=0.0)))
        active = active[~done]
    return spec_s, diff, error


#: Relative agreement of two successive sphere-lamp quadratures at which the finer one is kept.
QUADRATURE_RTOL = 1e-4
#: Most Gauss–Legendre nodes in cos θ (twice as many in φ) a sphere lamp's quadrature may use.
QUADRATURE_MAX_NODES = 32


def sphere_nodes(P: np.ndarray, centre: np.ndarray, radius: float, n: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Quadrature nodes over a sphere lamp as each point sees it: its points and weights.

    The lamp (a uniform Lambertian sphere of radiant intensity ``I``: radiance ``I/(π a²)``) subtends from ``P`` the
    cone of half-angle ``θmax`` (``cos θmax = √(1 − (a/d)²)``); Mitsuba samples it uniformly in solid angle
    (:mod:`nearlight.generator.lamp`). Here ``n`` Gauss–Legendre nodes in ``cos θ ∈ [cos θmax, 1]`` times ``2n``
    midpoint nodes in φ: weights summing to the cone's solid angle ``2π (1 − cos θmax)``, exact for polynomials of
    degree ``2n − 1`` in ``cos θ`` and trigonometric ones of degree ``2n − 1`` in φ.

    Yields
    ------
    points : ndarray, shape (m, 3)
        The nearest point of the sphere along each node's direction (where its shadow ray ends).
    weight : ndarray, shape (m,)
        The node's solid angle times the radiance per unit intensity, ``dω / (π a²)``: what multiplies
        ``f cos θi`` (and the beam, and the filter) for the point lamp's ``1/r²``.
    """
    to = centre - P
    dc = np.linalg.norm(to, axis=-1)
    axis = to / dc[..., None]
    cos_max = np.sqrt(np.maximum(1.0 - (radius / dc) ** 2, 0.0))
    a = _across(axis)
    b = np.cross(axis, a)
    x, w = np.polynomial.legendre.leggauss(n)
    for xi, wi in zip(x, w):
        cos_t = cos_max + (1.0 - cos_max) * (xi + 1.0) / 2.0
        sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
        for j in range(2 * n):
            phi = 2.0 * np.pi * (j + 0.5) / (2 * n)
            d = cos_t[..., None] * axis + sin_t[..., None] * (np.cos(phi) * a + np.sin(phi) * b)
            along = _dot(d, to)  # the ray's entry into the sphere
            t = along - np.sqrt(np.maximum(radius * radius - (dc * dc - along * along), 0.0))
            weight = wi * (1.0 - cos_max) / 2.0 * (2.0 * np.pi / (2 * n)) / (np.pi * radius * radius)
            yield P + t[..., None] * d, weight


def _unit_stokes(scene: Scene, i: int, P: np.ndarray, N: np.ndarray, up: np.ndarray, lamp: np.ndarray,
                 weight: np.ndarray, blocked: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
                 sign: np.ndarray | None, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Light from lamp ``i`` arriving at ``P`` from the points ``lamp`` (n, 3), per unit intensity and colour.

    Returns the specular Stokes ``(3, n)`` per unit specular colour and the diffuse irradiance factor ``(n,)``
    (the filter's S0 · beam · cos θi · ``weight``) per unit albedo; ``weight`` is ``1/r²`` for a point lamp.
    ``idx``: which of the render's points ``P`` are (for ``blocked(idx, lamp)``).
    """
    spec, mat = scene.lamps[i], scene.material
    facing = scene.facing(i)
    g = shading_geometry(P, N, np.asarray(scene.camera.position, float), lamp)
    ok = (g.cos_i > 0) & (g.cos_r > 0)
    if blocked is not None:
        ok &= ~blocked(idx, lamp)
    k = -g.light
    power = np.where(ok, beam(spec, facing, k) * np.clip(g.cos_i, 0, None) * weight, 0.0)
    x, y = analyzer_frame(g.view, up)
    fields = lamp_fields(spec, facing, k)
    shape = np.zeros(len(P))
    for value in ((None,) if sign is None else (-1.0, 1.0)):  # the lobe at each checker sign's roughness
        pick = np.ones(len(P), bool) if value is None else sign == value
        rough = mat.roughness if value is None else float(textured(mat.roughness, mat.texture.roughness_contrast, value))
        with np.errstate(invalid="ignore", divide="ignore"):  # unlit points (cos ≤ 0) are zeroed by `power`
            shape = np.where(pick, brdf_shape(mat.model, g.cos_i, g.cos_r, g.alpha, rough), shape)
    shape = np.where(ok, shape, 0.0)
    spec_s = np.zeros((3, len(P)))
    eta = mat.eta if mat.polarization == "fresnel" else None
    for e, w in reflected_states(k, g.view, fields, fresnel_eta=eta):
        ex, ey = _dot(e, x), _dot(e, y)
        spec_s += w * np.stack([ex * ex + ey * ey, ex * ex - ey * ey, 2 * ex * ey])  # |e|²·(1, cos 2β, sin 2β)
    incident = sum(w for _, w in fields)  # the filter's S0 per unit intensity: ½(1 + 1/ε)
    return spec_s * (power * shape), incident * power


# --------------------------------------------------------------------------- the render


def closed_form_arrays(scene: Scene) -> dict[str, np.ndarray]:
    """What :func:`nearlight.generator.render._render_arrays` returns for ``scene``, in closed form.

    Returns
    -------
    dict
        ``P``, ``N`` ``(H, W, 3)`` (NaN off the object), ``to_world`` ``(4, 4)``, ``stokes_specular``,
        ``stokes_diffuse``, ``stokes_full`` ``(3, H, W, 3)`` float32, and with several lamps each lamp's
        ``stokes_<part>_lamp<i>``; ``quadrature_error`` ``(lamps,)``: each lamp's quadrature error estimate
        relative to its brightest value (0 for a point lamp; :func:`lamp_stokes`).

    Raises
    ------
    UserError
        The scene is not covered (:func:`not_covered`, the first reason), the camera sees no part of the object,
        or a lamp is inside a closed object (as the Mitsuba renderer says).
    """
    why = not_covered(scene)
    if why:
        raise UserError(f"{scene.source}: {why[0]}: the closed-form renderer does not cover it; render with Mitsuba")
    cam = scene.camera
    to_world = look_at_matrix(cam.position, cam.target(scene.capture.seed), cam.up)
    d = camera_rays(to_world, cam.width, cam.height, cam.fov_x_deg)
    origin = np.asarray(cam.position, float)
    prims = primitives(scene)
    hits = nearest(prims, origin, d)
    seen = np.isfinite(hits.t)
    if not seen.any():
        raise UserError(f"{scene.source}: camera: sees no part of the object (check camera.position/look_at/"
                        "fov_x_deg and object.position)")  # fmt: skip
    P, N = hit_points(origin, d, hits.t, hits.N)
    _check_lamps(scene, P)
    Ps, Ns, which = P[seen], N[seen], hits.which[seen]
    mat = scene.material
    sign = None if mat.texture is None else checker_sign(Ps, placement(scene.object), mat.texture.period_m)
    several = len(scene.lamps) > 1
    out: dict[str, np.ndarray] = {"P": P, "N": N, "to_world": to_world}
    total = {part: np.zeros((3, *seen.shape, 3)) for part in ("specular", "diffuse")}
    blocked = None if scene.object.type in CONVEX else (lambda idx, lamp: shadowed(prims, Ps[idx], which[idx], lamp))
    errors = []
    for i in range(len(scene.lamps)):
        *parts, error = lamp_stokes(scene, i, Ps, Ns, to_world[:3, 1], blocked, sign)
        errors.append(error)
        for part, value in zip(("specular", "diffuse"), parts):
            image = np.zeros((3, *seen.shape, 3))
            image[:, seen] = value
            total[part] += image
            if several:
                out[f"stokes_{part}_lamp{i}"] = image.astype(np.float32)
    out["quadrature_error"] = np.asarray(errors, float)
    out["stokes_specular"] = total["specular"].astype(np.float32)
    out["stokes_diffuse"] = total["diffuse"].astype(np.float32)
    out["stokes_full"] = (total["specular"] + total["diffuse"]).astype(np.float32)
    return out


def _check_lamps(scene: Scene, P: np.ndarray) -> None:
    """A lamp inside a closed object, or a sphere lamp reaching a surface point ``P`` (H, W, 3) the camera sees, is
    an error (as the Mitsuba renderer's ``_check_geometry`` says)."""
    obj = scene.object
    place = placement(obj)
    for i, lamp in enumerate(scene.lamps):
        local = (np.asarray(lamp.position, float) - place[:3, 3]) @ place[:3, :3]
        inside = (isinstance(obj, Sphere) and np.linalg.norm(local) < obj.radius) or (
            isinstance(obj, Cylinder) and np.hypot(local[0], local[1]) < obj.radius and abs(local[2]) < obj.length / 2)
        if inside:
            raise UserError(f"{scene.source}: {lamp_name(i, len(scene.lamps))}.position: {list(lamp.position)} is "
                            "inside the object")  # fmt: skip
        if lamp.radius > 0:
            gap = float(np.nanmin(np.linalg.norm(P - np.asarray(lamp.position), axis=-1)))
            if gap <= lamp.radius:
                raise UserError(f"{scene.source}: {lamp_name(i, len(scene.lamps))}.radius: {lamp.radius} m reaches the "
                                f"object (a surface point the camera sees is {gap:.4g} m from the lamp's centre)")  # fmt: skip


def render_closed_form(scene: Scene, *, arrays: dict[str, np.ndarray] | None = None):
    """The noise-free :class:`~nearlight.capture.Capture` of ``scene``, in closed form: Mitsuba's capture but for
    float rounding, ``meta.generator.renderer`` ``closed-form``.

    ``arrays``: :func:`closed_form_arrays` of a scene with the same :func:`closed_form_key`, rendered before (a
    worker's in-memory cache); the capture holds views of them, so give a copy that nothing else changes.
    """
    from .render import assemble

    arrays = closed_form_arrays(scene) if arrays is None else arrays
    capture = assemble(scene, arrays, key=closed_form_key(scene))
    meta = dict(capture.meta)
    meta["generator"] = {**meta["generator"], "renderer": NAME}
    if any(lamp.radius > 0 for lamp in scene.lamps):
        meta["generator"]["quadrature_error"] = [float(e) for e in arrays["quadrature_error"]]
    return capture.replace(meta=meta)
