"""Analytic captures: closed-form scenes under a pinhole camera (numpy only).

Builds a :class:`~nearlight.capture.Capture` without a renderer, for tests of
the estimator and the evaluation: a planar board or a sphere seen by a pinhole
camera, lit by a point lamp behind an ideal linear polarizer, shaded with the
closed-form models of :mod:`nearlight.physics` (``docs/physics.md``). The analyzer
stack follows the ``ideal`` mode, ``I(θ) = Id/2 + Is·cos²(θ − β)``.

Default scene (tabletop, metres, z up): a 0.4 m board lying on the table at
the origin, the camera 0.61 m away looking down at it, the lamp about 0.4 m
above the board, so the highlight falls inside the board.

Several lamps (:func:`analytic_capture_lamps`, ``lamps=[{"position": ...}, ...]``): radiance
is linear in the lamps and incoherent light adds, so each lamp's specular and
diffuse images (each through its own ideal polarizer, with its own phase β)
are summed, analyzer images included:
``I(θ) = Σᵢ [Id,i/2 + Is,i·cos²(θ − βᵢ)]``.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..capture import Camera, Capture, Rig
from .closed_form import hit_points, rectangle_hits, sphere_hits
from ..physics.camera import camera_rays, look_at_matrix
from ..physics.polarization import analyzer_stack_ideal, through_polarizer
from ..physics.reflectance import diffuse_radiance, normalize, specular_radiance, tangent_basis

#: Default lamp position, metres: about 0.4 m above the default board.
DEFAULT_LAMP_POSITION = (0.05, 0.15, 0.35)
#: Default bare lamp intensity, W/sr per channel: the ideal polarizer passes 1.
DEFAULT_LAMP_INTENSITY = (2.0, 2.0, 2.0)
#: Keys of one lamp of ``analytic_capture(lamps=...)``.
LAMP_KEYS = ("position", "intensity", "phase_deg", "polarizer_axis")

#: Default specular BSDF: the paper's simplified Torrance–Sparrow lobe.
DEFAULT_BSDF = {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.1}


def analytic_capture(
    *,
    shape: str = "board",
    width: int = 160,
    height: int = 120,
    fov_x_deg: float = 50.0,
    camera_position: Sequence[float] = (0.0, -0.35, 0.5),
    look_at: Sequence[float] | None = None,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    lamp_position: Sequence[float] = DEFAULT_LAMP_POSITION,
    lamp_intensity: Any = DEFAULT_LAMP_INTENSITY,
    bsdf: Mapping[str, Any] | None = None,
    kd: Sequence[float] = (0.3, 0.4, 0.35),
    analyzer_angles_deg: Sequence[float] | None = (0.0, 45.0, 90.0, 135.0),
    phase_deg: Any = 0.0,
    board_size: float = 0.4,
    board_centre: Sequence[float] = (0.0, 0.0, 0.0),
    board_normal: Sequence[float] = (0.0, 0.0, 1.0),
    sphere_centre: Sequence[float] = (0.0, 0.0, 0.15),
    sphere_radius: float = 0.15,
    with_normals: bool = True,
) -> Capture:
    """A noise-free capture of a board or sphere, computed in closed form.

    Parameters
    ----------
    shape : {"board", "sphere"}, optional
        ``"board"``: a square of side ``board_size`` (m) at ``board_centre``
        with unit normal ``board_normal``; ``"sphere"``: a sphere at
        ``sphere_centre`` of radius ``sphere_radius`` (m).
    width, height : int
        Image size, pixels.
    fov_x_deg : float
        Horizontal field of view, degrees.
    camera_position, look_at, up : sequence of 3 floats
        Pinhole camera pose (metres); the camera-to-world matrix is Mitsuba's
        look-at (see :func:`look_at_matrix`). ``look_at`` defaults to the
        board's or the sphere's centre.
    lamp_position : sequence of 3 floats
        Point lamp, metres.
    lamp_intensity : float or sequence of 3 floats
        Radiant intensity of the bare lamp, W/sr per channel. An ideal
        polarizer halves it, so ``lamp_intensity / 2`` reaches the surface;
        the default 2 makes that 1, so an estimator's Ks (which absorbs the
        lamp intensity) equals the BSDF's ``ks``.
    bsdf : mapping, optional
        Specular BSDF dict (a model of :data:`nearlight.physics.reflectance.LOBES`:
        ``torrance_sparrow``, ``ward``, ``ggx`` or ``beckmann``); default
        :data:`DEFAULT_BSDF`.
    kd : sequence of 3 floats
        Lambertian albedo.
    analyzer_angles_deg : sequence of float or None
        Analyzer angles of the stack, degrees. ``None`` writes the separated
        ``specular`` and ``diffuse`` images instead of a stack.
    phase_deg : float or ndarray, shape (H, W)
        β, the analyzer angle of maximum specular transmission, degrees.
    with_normals : bool
        Write ``N``; when false the estimator must derive normals from ``P``.

    Returns
    -------
    Capture
        ``truth`` holds lamp position, intensity and BSDF; ``extra`` holds
        ``truth_specular`` and ``truth_diffuse`` (radiance without analyzer,
        ``[H, W, 3]``). Several lamps: :func:`analytic_capture_lamps`.
    """
    return _capture(lamps=None, **locals())


def analytic_capture_lamps(lamps: Sequence[Mapping[str, Any]], **kwargs: Any) -> Capture:
    """A noise-free capture lit by one or more lamps, computed in closed form.

    Radiance is linear in the lamps and incoherent light adds, so each lamp's
    specular and diffuse images (each behind its own ideal polarizer, with its
    own phase β) are summed, analyzer images included:
    ``I(θ) = Σᵢ [Id,i/2 + Is,i·cos²(θ − βᵢ)]``.

    A function of its own rather than an argument of :func:`analytic_capture`:
    the evaluation's analytic renderer builds its scenes and render keys from
    ``analytic_capture``'s signature, which stays as it was so that no existing
    sweep changes.

    Parameters
    ----------
    lamps : sequence of mappings
        One or more point
        lamps, each ``{"position": [x, y, z]}`` (metres) with optional
        ``"intensity"`` (as ``lamp_intensity``, default 2 per channel),
        ``"phase_deg"`` (its specular light's β, default ``phase_deg``) and
        ``"polarizer_axis"`` (world, recorded in ``truth.lamps``; default
        ``[1, 0, 0]``). Each passes its own ideal polarizer; their images add.
    **kwargs
        Any other argument of :func:`analytic_capture` (camera, object, BSDF,
        analyzer angles, ``phase_deg`` the default β of every lamp), not
        ``lamp_position`` nor ``lamp_intensity``.

    Returns
    -------
    Capture
        As :func:`analytic_capture`'s, with ``truth.lamps`` listing the lamps
        (capture format v2) and ``rig.lamps`` their number; one lamp also has
        ``truth.lamp_position`` and ``truth.lamp_intensity`` (and its images
        are :func:`analytic_capture`'s for that lamp, bit for bit), several
        have neither, no ``lamp_polarizer_axis``, and every lamp's own
        ``truth_specular_lamp<i>`` and ``truth_diffuse_lamp<i>`` in ``extra``.

    Raises
    ------
    ValueError
        ``lamp_position`` or ``lamp_intensity`` given, an empty ``lamps``, or a
        lamp with an unknown key or without a position.
    TypeError
        An argument :func:`analytic_capture` does not have.
    """
    for key in ("lamp_position", "lamp_intensity"):
        if key in kwargs:
            raise ValueError(f"{key}: give the lamps in lamps, not {key}")
    bound = inspect.signature(analytic_capture).bind(**kwargs)
    bound.apply_defaults()
    return _capture(lamps=lamps, **bound.arguments)


def _capture(
    *,
    lamps: Sequence[Mapping[str, Any]] | None,
    shape: str,
    width: int,
    height: int,
    fov_x_deg: float,
    camera_position: Sequence[float],
    look_at: Sequence[float] | None,
    up: Sequence[float],
    lamp_position: Sequence[float],
    lamp_intensity: Any,
    bsdf: Mapping[str, Any] | None,
    kd: Sequence[float],
    analyzer_angles_deg: Sequence[float] | None,
    phase_deg: Any,
    board_size: float,
    board_centre: Sequence[float],
    board_normal: Sequence[float],
    sphere_centre: Sequence[float],
    sphere_radius: float,
    with_normals: bool,
) -> Capture:
    """The one implementation of :func:`analytic_capture` (``lamps`` None: its one lamp, ``lamp_position`` and
    ``lamp_intensity``) and :func:`analytic_capture_lamps` (``lamps``: the lamps, ``lamp_position`` and
    ``lamp_intensity`` unused)."""
    if lamps is not None:
        lamp_list = [_lamp(lamp, i, phase_deg) for i, lamp in enumerate(lamps)]
        if not lamp_list:
            raise ValueError("lamps: expected at least one lamp")
    bsdf = dict(DEFAULT_BSDF if bsdf is None else bsdf)
    origin = np.asarray(camera_position, dtype=float)
    if look_at is None:
        look_at = board_centre if shape == "board" else sphere_centre
    to_world = look_at_matrix(origin, look_at, up)
    rays = camera_rays(to_world, width, height, fov_x_deg)
    if shape == "board":  # the closed-form renderer's intersections: one home for the geometry
        n = normalize(np.asarray(board_normal, dtype=float))
        a, b = tangent_basis(n)
        t, N = rectangle_hits(origin, rays, np.asarray(board_centre, float), a * board_size / 2, b * board_size / 2, n)
    elif shape == "sphere":
        t, N = sphere_hits(origin, rays, np.asarray(sphere_centre, float), sphere_radius)
    else:
        raise ValueError(f"shape: expected 'board' or 'sphere', got {shape!r}")
    P, N = hit_points(origin, rays, t, N)
    surface = np.all(np.isfinite(P), axis=-1)
    Pz = np.where(surface[..., None], P, 0.0)
    Nz = np.where(surface[..., None], N, [0.0, 0.0, 1.0])

    def shade(position: Any, bare_intensity: Any) -> tuple[np.ndarray, np.ndarray]:
        """Specular and diffuse radiance ``[H, W, 3]`` of one lamp behind its ideal polarizer (0 off the object)."""
        intensity = through_polarizer(np.broadcast_to(np.asarray(bare_intensity, dtype=float), (3,)))
        with np.errstate(invalid="ignore", divide="ignore"):
            spec = specular_radiance(Pz, Nz, origin, position, intensity, bsdf)
            diff = diffuse_radiance(Pz, Nz, origin, position, intensity, kd)
        return np.where(surface[..., None], np.nan_to_num(spec), 0.0), np.where(surface[..., None], diff, 0.0)

    def phase(deg: Any) -> np.ndarray:
        return np.radians(np.broadcast_to(np.asarray(deg, dtype=float), (height, width)))

    stack = angles = specular = diffuse = None
    angles = None if analyzer_angles_deg is None else np.asarray(analyzer_angles_deg, dtype=float)
    per_lamp: dict[str, np.ndarray] = {}
    if lamps is None:  # v1's one lamp, computed exactly as before lamps existed
        spec, diff = shade(lamp_position, lamp_intensity)
        if angles is not None:
            stack = analyzer_stack_ideal(diff, spec, phase(phase_deg), angles).astype(np.float32)
    else:
        parts = [(*shade(lamp["position"], lamp["intensity"]), phase(lamp["phase_deg"])) for lamp in lamp_list]
        spec, diff = sum(p[0] for p in parts), sum(p[1] for p in parts)
        if angles is not None:  # incoherent light adds: Σ Id,i/2 + Is,i cos²(θ − βi)
            stack = sum(analyzer_stack_ideal(d, s, b, angles) for s, d, b in parts).astype(np.float32)
        if len(parts) > 1:
            for i, (s, d, _) in enumerate(parts):
                per_lamp[f"truth_specular_lamp{i}"] = s.astype(np.float32)
                per_lamp[f"truth_diffuse_lamp{i}"] = d.astype(np.float32)
    if angles is None:
        specular, diffuse = spec.astype(np.float32), diff.astype(np.float32)
    truth: dict[str, Any] = {}
    if lamps is None or len(lamp_list) == 1:
        one_position = lamp_position if lamps is None else lamp_list[0]["position"]
        one_intensity = lamp_intensity if lamps is None else lamp_list[0]["intensity"]
        truth["lamp_position"] = [float(x) for x in one_position]
        truth["lamp_intensity"] = [float(x) for x in np.broadcast_to(np.asarray(one_intensity, dtype=float), (3,))]
    truth["bsdf"] = {**bsdf, "kd": [float(x) for x in kd], "polarization": "ideal"}
    if lamps is not None:
        truth["lamps"] = [_lamp_truth(lamp) for lamp in lamp_list]
    return Capture(
        width=width,
        height=height,
        camera=Camera(position=origin, to_world=to_world, fov_x_deg=float(fov_x_deg)),
        P=P.astype(np.float32),
        N=N.astype(np.float32) if with_normals else None,
        stack=stack,
        analyzer_angles_deg=angles,
        specular=specular,
        diffuse=diffuse,
        lamp_polarizer_axis=np.array([1.0, 0.0, 0.0]) if lamps is None else
        (np.asarray(truth["lamps"][0]["polarizer_axis"]) if len(lamp_list) == 1 else None),
        rig=Rig(lamps=1 if lamps is None else len(lamp_list)),
        truth=truth,
        extra={"truth_specular": spec.astype(np.float32), "truth_diffuse": diff.astype(np.float32), **per_lamp},
        meta={"source": "nearlight.generator.analytic.analytic_capture"},
    )


def _lamp(lamp: Mapping[str, Any], i: int, phase_deg: Any) -> dict[str, Any]:
    """Lamp ``i`` of ``analytic_capture(lamps=...)`` with its defaults filled in."""
    if not isinstance(lamp, Mapping) or "position" not in lamp:
        raise ValueError(f"lamps[{i}]: expected a mapping with a position, got {lamp!r}")
    unknown = sorted(set(lamp) - set(LAMP_KEYS))
    if unknown:
        raise ValueError(f"lamps[{i}].{unknown[0]}: unknown key (a lamp has {', '.join(LAMP_KEYS)})")
    position = np.asarray(lamp["position"], dtype=float)
    if position.shape != (3,):
        raise ValueError(f"lamps[{i}].position: expected 3 numbers, got {lamp['position']!r}")
    return {"position": position, "intensity": lamp.get("intensity", DEFAULT_LAMP_INTENSITY),
            "phase_deg": lamp.get("phase_deg", phase_deg), "polarizer_axis": lamp.get("polarizer_axis", (1.0, 0.0, 0.0))}  # fmt: skip


def _lamp_truth(lamp: Mapping[str, Any]) -> dict[str, Any]:
    """One lamp as ``truth.lamps[i]`` of capture format v2: an ideal isotropic point lamp."""
    axis = np.asarray(lamp["polarizer_axis"], dtype=float)
    return {
        "position": [float(x) for x in lamp["position"]],
        "intensity": [float(x) for x in np.broadcast_to(np.asarray(lamp["intensity"], dtype=float), (3,))],
        "radius_m": 0.0,
        "anisotropy": None,
        "polarizer_axis": (axis / np.linalg.norm(axis)).tolist(),
        "polarizer_extinction_ratio": None,
    }
