"""Closed forms for calibration targets: chrome mirror balls and a matte card lit by a scene's lamp (numpy only).

The arrays a Mitsuba render of the targets should hold, by arithmetic, to check those renders pixel by pixel
(``tests/generator/test_targets_closed_form.py`` checks these against Mitsuba's own sphere, ``conductor`` and
``area`` emitter):

- :func:`mirror_sphere_stokes`: what a conductor ball reflects of an intersectable sphere lamp into each camera
  ray: the lamp's radiance behind its filter (:func:`~nearlight.generator.closed_form.lamp_fields`), each linear
  state reflected as a field with the conductor's complex ``rs``, ``rp``
  (:func:`~nearlight.generator.closed_form.fresnel_amplitudes` with ``η = n + iκ``): a phase difference between
  them turns linear light elliptical, which lowers S1, S2 (S3 is not kept);
- :func:`lamp_image_centre`: where the lamp's centre appears on a ball (the specular point of a convex mirror);
- :func:`lambert_card_radiance`: a Lambertian card's radiance under the lamp, which a sphere lamp gives exactly as a
  point lamp at its centre while it is wholly above the card's plane.

Frames and units as :mod:`nearlight.generator.closed_form`'s: Stokes in the analyzer frame of each camera ray
(``x = (−v) × up``, ``y = v × x``, ``v`` towards the camera), radiance per unit radiant intensity of the lamp
before its filter (a sphere lamp of radius ``a`` and intensity ``I`` has radiance ``I/(π a²)``).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

from ..physics.polarization import analyzer_frame
from .closed_form import _dot, _unit, beam, fresnel_amplitudes, lamp_fields, reflection_frames, sphere_hits
from .scene import LampSpec

#: Absolute tolerance on the normal's angle (radians) of :func:`lamp_image_centre`'s root: 1e-15 m at a 1 m ball.
ANGLE_XTOL = 1e-15


def _conductor_field(k: np.ndarray, n: np.ndarray, e: np.ndarray, rs: np.ndarray, rp: np.ndarray) -> np.ndarray:
    """The complex field ``rs (e·s) s + rp (e·p) p'`` that the surface of normal ``n`` reflects of the real unit
    field ``e`` travelling along ``k``: ``s = k × n`` (normalised), ``p = s × k`` and ``p'`` its mirror image, the
    frames in which ``rs = rp = 1`` is the mirror (:func:`~nearlight.generator.closed_form.reflected_states`'s).

    Parameters
    ----------
    k, n, e : ndarray, shape (m, 3)
        Unit propagation directions (towards the surface), unit normals, unit fields normal to ``k``.
    rs, rp : ndarray, shape (m,), complex

    Returns
    -------
    ndarray, shape (m, 3), complex
        Normal to the reflected direction ``k − 2 (k·n) n``.
    """
    s, p_in, p_out = reflection_frames(k, n)
    return (rs * _dot(e, s))[..., None] * s + (rp * _dot(e, p_in))[..., None] * p_out


def mirror_sphere_stokes(o: np.ndarray, d: np.ndarray, up: np.ndarray, centre, radius: float, eta: float,
                         k: float, lamp_spec: LampSpec,
                         facing: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Stokes S0, S1, S2 that camera rays receive by one reflection on a conductor ball from a sphere lamp.

    Each ray ``o + t d`` that meets the ball (before the lamp, which may hide it) reflects to ``r = d − 2 (d·N) N``;
    where ``r`` meets the lamp's sphere (radius ``lamp_spec.radius`` about ``lamp_spec.position``) the ray receives
    the lamp's radiance ``1/(π a²)`` per unit intensity, times the beam (:func:`~.closed_form.beam`), through the
    filter along the light's propagation direction ``−r`` (lamp → ball: :func:`~.closed_form.lamp_fields`'s
    incoherent linear states), each state reflected as a field with the conductor's complex ``rs``, ``rp`` at
    ``cos θi = r·N`` and the Stokes vectors of the states added. Elsewhere 0 (no other light: the ball seen against
    black). An unpolarized lamp is a filter of extinction ratio 1 (two orthogonal states of weight ½: S0 the lamp's
    whole radiance; ``polarizer_axis`` must still not be along ``facing``).

    Parameters
    ----------
    o : ndarray, shape (3,) or (n, 3)
        Ray origins (m).
    d : ndarray, shape (n, 3)
        Unit ray directions (camera → scene).
    up : ndarray, shape (3,)
        The camera's up (``to_world``'s second column): the analyzer frame's reference.
    centre : array_like, shape (3,)
        The ball's centre (m).
    radius : float
        The ball's radius (m).
    eta, k : float
        The conductor's complex index ``η = eta + i·k`` (Mitsuba's ``conductor`` ``eta`` and ``k``).
    lamp_spec : LampSpec
        The lamp: ``position``, ``radius`` (> 0), its filter (``polarizer_axis``, ``polarizer_extinction_ratio``)
        and beam (``anisotropy_k``, ``anisotropy_axis``); ``intensity`` is not used (per unit intensity).
    facing : ndarray, shape (3,)
        Unit normal of the lamp's filter, from the lamp towards the point it faces.

    Returns
    -------
    stokes : ndarray, shape (3, n)
        S0, S1, S2 (radiance per unit lamp intensity, W/(m² sr) per W/sr) in each ray's analyzer frame.
    sees_lamp : ndarray, shape (n,), bool
        The rays whose reflection meets the lamp.
    on_ball : ndarray, shape (n,), bool
        The rays that meet the ball (and not the lamp first).

    Raises
    ------
    ValueError
        A point lamp (``radius`` 0): its image in a mirror is a point, which no pixel-centre ray meets.
    """
    a = lamp_spec.radius
    if a <= 0:
        raise ValueError("mirror_sphere_stokes: the lamp needs a radius > 0 (a point lamp's image is a point)")
    d = np.asarray(d, float)
    o = np.broadcast_to(np.asarray(o, float), d.shape)
    lamp = np.asarray(lamp_spec.position, float)
    t, N = sphere_hits(o, d, centre, radius)
    on_ball = np.isfinite(t) & (t < sphere_hits(o, d, lamp, a)[0])
    ray, N = d[on_ball], N[on_ball]
    X = o[on_ball] + t[on_ball, None] * ray
    r = ray - 2.0 * _dot(ray, N)[:, None] * N
    meets = np.isfinite(sphere_hits(X, r, lamp, a)[0])
    sees_lamp = np.zeros(len(d), bool)
    sees_lamp[np.flatnonzero(on_ball)[meets]] = True
    r, N = r[meets], N[meets]
    light = -r  # the light's propagation, lamp → ball
    rs, rp = fresnel_amplitudes(np.clip(_dot(r, N), 0.0, 1.0), complex(eta, k))
    x, y = analyzer_frame(-ray[meets], up)
    S = np.zeros((3, len(light)))
    for e, w in lamp_fields(lamp_spec, facing, light):
        E = _conductor_field(light, N, e, rs, rp)
        ex, ey = np.sum(E * x, axis=-1), np.sum(E * y, axis=-1)
        xx, yy = abs(ex) ** 2, abs(ey) ** 2
        S += w * np.stack([xx + yy, xx - yy, 2.0 * (ex * ey.conj()).real])  # S3 = ∓2 Im(ex ey*) left out
    stokes = np.zeros((3, len(d)))
    stokes[:, sees_lamp] = S * beam(lamp_spec, facing, light) / (np.pi * a * a)
    return stokes, sees_lamp, on_ball


def lamp_image_centre(camera_position, centre, radius: float, lamp_position) -> np.ndarray:
    """The point of a mirror ball where the reflection law sends the lamp's centre to the camera.

    The specular point of a convex mirror lies in the plane of the camera ``C``, the centre ``O`` and the lamp
    ``L``, at ``O + R n(φ)`` with ``n(φ) = cos φ u + sin φ w`` (``u`` towards ``C``, ``w`` the in-plane direction
    towards ``L`` normal to ``u``, ``β`` the angle of ``L`` from ``u``), on the arc that both see:
    ``β − arccos(R/|L − O|) ≤ φ ≤ arccos(R/|C − O|)``, within [0, β]. There ``φ`` is the root of the bisector
    condition (``n`` halves the angle between the directions to ``C`` and to ``L``: the sum of the unit vectors from
    the point to them has no component along the tangent), which is positive at the arc's start (the lamp's horizon,
    or φ = 0) and negative at its end (the camera's horizon, or φ = β), solved by ``brentq``.

    Parameters
    ----------
    camera_position, centre, lamp_position : array_like, shape (3,)
        ``C``, ``O`` and ``L`` (m), both outside the ball.
    radius : float
        The ball's radius ``R`` (m).

    Returns
    -------
    ndarray, shape (3,)
        The point (m); project it with :func:`nearlight.physics.camera.project`.

    Raises
    ------
    ValueError
        No point of the ball is seen by both the camera and the lamp (the lamp is behind the ball, near its line
        through the camera): the ball shows no image of the lamp's centre.
    """
    C, O, L = (np.asarray(p, float) for p in (camera_position, centre, lamp_position))
    u = _unit(C - O)
    across = (L - O) - np.dot(L - O, u) * u
    span = np.linalg.norm(across)
    beta = np.arctan2(span, np.dot(L - O, u))
    lo = max(0.0, beta - np.arccos(radius / np.linalg.norm(L - O)))
    hi = min(beta, np.arccos(radius / np.linalg.norm(C - O)))
    if beta < 1e-12:  # the lamp on the camera's side of its line through the centre: the point within R·β of this
        return O + radius * u
    if lo >= hi:
        raise ValueError("lamp_image_centre: no point of the ball is seen by both the camera and the lamp")
    w = across / span

    def bisector(phi: float) -> float:
        X = O + radius * (np.cos(phi) * u + np.sin(phi) * w)
        tangent = -np.sin(phi) * u + np.cos(phi) * w
        return float(np.dot(_unit(C - X) + _unit(L - X), tangent))

    phi = brentq(bisector, lo, hi, xtol=ANGLE_XTOL, rtol=4 * np.finfo(float).eps)
    return O + radius * (np.cos(phi) * u + np.sin(phi) * w)


def lambert_card_radiance(P: np.ndarray, N: np.ndarray, albedo: float, lamp_spec: LampSpec,
                          facing: np.ndarray) -> np.ndarray:  # fmt: skip
    """S0 of a Lambertian card lit by the lamp as a point at its centre, ``albedo/π · f · b · max(cos θ, 0)/r²``.

    ``f`` is the filter's transmitted fraction, ``½ (1 + 1/ε)`` (½ for the ideal polarizer, 1 for ε = 1: no
    filter), ``b`` the beam along ``k`` (lamp → point; :func:`~.closed_form.beam`), ``θ`` the angle between ``N``
    and the direction to the lamp, ``r`` its distance. The card depolarizes: S1 = S2 = 0.

    A sphere lamp (radius ``a``, radiance ``I/(π a²)``) gives exactly this where its centre is more than ``a``
    above the card's plane at ``P`` (``(L − P)·N > a``) and its beam is isotropic: a uniform sphere wholly above a
    Lambertian point's horizon irradiates it as a point source of the same intensity at its centre (Nusselt's
    analog: the cone of half-angle α, ``sin α = a/r``, projects onto the card's plane as an ellipse of area
    ``π sin²α cos θ``, the projected solid angle; times the radiance, ``I cos θ/r²``). Nearer the plane part of the
    sphere is below the horizon and the point formula is too low (0 once the centre is below the plane); with a
    beam, it is the point-lamp approximation.

    Parameters
    ----------
    P, N : ndarray, shape (n, 3)
        Card points (m) and unit normals (the lit side).
    albedo : float
        Diffuse reflectance in [0, 1].
    lamp_spec : LampSpec
        The lamp: ``position``, filter and beam (``intensity`` and ``radius`` are not used).
    facing : ndarray, shape (3,)
        Unit normal of the lamp's filter, from the lamp towards the point it faces.

    Returns
    -------
    ndarray, shape (n,)
        Radiance per unit lamp intensity (W/(m² sr) per W/sr).
    """
    to = np.asarray(lamp_spec.position, float) - np.asarray(P, float)
    r2 = _dot(to, to)
    k = -to / np.sqrt(r2)[:, None]
    transmitted = sum(w for _, w in lamp_fields(lamp_spec, facing, k))
    cos = np.maximum(_dot(np.asarray(N, float), -k), 0.0)
    return albedo / np.pi * transmitted * beam(lamp_spec, facing, k) * cos / r2
