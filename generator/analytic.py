"""Analytic captures: closed-form scenes under a pinhole camera (numpy only).

Builds a :class:`~nearlight.capture.Capture` without a renderer, for tests of
the estimator and the evaluation: a planar board or a sphere seen by a pinhole
camera, lit by a point lamp behind an ideal linear polarizer, shaded with the
closed-form models of :mod:`nearlight.physics` (``docs/physics.md``). The analyzer
stack follows the ``ideal`` mode, ``I(θ) = Id/2 + Is·cos²(θ − β)``.

Default scene (tabletop, metres, z up): a 0.4 m board lying on the table at
the origin, the camera 0.61 m away looking down at it, the lamp about 0.4 m
above the board, so the highlight falls inside the board.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..capture import Camera, Capture
from ..physics.camera import camera_rays, look_at_matrix
from ..physics.polarization import analyzer_stack_ideal, through_polarizer
from ..physics.reflectance import diffuse_radiance, normalize, specular_radiance, tangent_basis

#: Default specular BSDF: the paper's simplified Torrance–Sparrow lobe.
DEFAULT_BSDF = {"model": "torrance_sparrow", "ks": [0.8, 0.6, 0.5], "sigma": 0.1}


def _board(origin, rays, centre, normal, size):
    """Hit points and normals of a square board of side ``size`` (NaN off the board)."""
    n = normalize(np.asarray(normal, dtype=float))
    c = np.asarray(centre, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.dot(c - origin, n) / (rays @ n)
    P = origin + t[..., None] * rays
    a, b = tangent_basis(n)
    d = P - c
    inside = (t > 0) & (np.abs(d @ a) <= size / 2) & (np.abs(d @ b) <= size / 2)
    P[~inside] = np.nan
    N = np.broadcast_to(n, P.shape).copy()
    N[~inside] = np.nan
    return P, N


def _sphere(origin, rays, centre, radius):
    """Nearest hit points and outward normals of a sphere (NaN where missed)."""
    c = np.asarray(centre, dtype=float)
    oc = origin - c
    b = rays @ oc
    disc = b * b - (oc @ oc - radius * radius)
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    hit = (disc > 0) & (t > 0)
    P = origin + t[..., None] * rays
    P[~hit] = np.nan
    N = (P - c) / radius
    return P, N


def analytic_capture(
    *,
    shape: str = "board",
    width: int = 160,
    height: int = 120,
    fov_x_deg: float = 50.0,
    camera_position: Sequence[float] = (0.0, -0.35, 0.5),
    look_at: Sequence[float] | None = None,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    lamp_position: Sequence[float] = (0.05, 0.15, 0.35),
    lamp_intensity: Any = (2.0, 2.0, 2.0),
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
        ``truth_specular`` and ``truth_diffuse`` (radiance without analyzer).
    """
    bsdf = dict(DEFAULT_BSDF if bsdf is None else bsdf)
    origin = np.asarray(camera_position, dtype=float)
    if look_at is None:
        look_at = board_centre if shape == "board" else sphere_centre
    to_world = look_at_matrix(origin, look_at, up)
    rays = camera_rays(to_world, width, height, fov_x_deg)
    if shape == "board":
        P, N = _board(origin, rays, board_centre, board_normal, board_size)
    elif shape == "sphere":
        P, N = _sphere(origin, rays, sphere_centre, sphere_radius)
    else:
        raise ValueError(f"shape: expected 'board' or 'sphere', got {shape!r}")
    surface = np.all(np.isfinite(P), axis=-1)
    intensity = through_polarizer(np.broadcast_to(np.asarray(lamp_intensity, dtype=float), (3,)))
    Pz = np.where(surface[..., None], P, 0.0)
    Nz = np.where(surface[..., None], N, [0.0, 0.0, 1.0])
    with np.errstate(invalid="ignore", divide="ignore"):
        spec = specular_radiance(Pz, Nz, origin, lamp_position, intensity, bsdf)
        diff = diffuse_radiance(Pz, Nz, origin, lamp_position, intensity, kd)
    spec = np.where(surface[..., None], np.nan_to_num(spec), 0.0)
    diff = np.where(surface[..., None], diff, 0.0)

    stack = angles = specular = diffuse = None
    if analyzer_angles_deg is None:
        specular, diffuse = spec.astype(np.float32), diff.astype(np.float32)
    else:
        angles = np.asarray(analyzer_angles_deg, dtype=float)
        beta = np.radians(np.broadcast_to(np.asarray(phase_deg, dtype=float), (height, width)))
        stack = analyzer_stack_ideal(diff, spec, beta, angles).astype(np.float32)
    truth = {
        "lamp_position": [float(x) for x in lamp_position],
        "lamp_intensity": [float(x) for x in np.broadcast_to(np.asarray(lamp_intensity, dtype=float), (3,))],
        "bsdf": {**bsdf, "kd": [float(x) for x in kd], "polarization": "ideal"},
    }
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
        lamp_polarizer_axis=np.array([1.0, 0.0, 0.0]),
        truth=truth,
        extra={"truth_specular": spec.astype(np.float32), "truth_diffuse": diff.astype(np.float32)},
        meta={"source": "nearlight.generator.analytic.analytic_capture"},
    )
