"""The calibration targets' closed forms (generator/targets_closed_form.py) against textbook values, limit cases,
the closed-form renderer's own machinery, and Mitsuba.

Golden values: the conductor's reflectance as pbrt-v3's ``FrConductor`` writes it (Born & Wolf's absorbing-medium
Fresnel equations in real arithmetic), ``R = ((n − 1)² + κ²)/((n + 1)² + κ²)`` at normal incidence, Mitsuba
3.9.1's ``mi.mueller.specular_reflection`` and its own render of a ``conductor`` sphere reflecting an ``area``
sphere lamp. Chrome: ``eta`` 3.18, ``k`` 4.41, Mitsuba's ``data/ior/Cr.eta.spd`` and ``Cr.k.spd`` (luxpop) at
558 nm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nearlight.generator import load_scene
from nearlight.generator.closed_form import (
    beam,
    closed_form_arrays,
    fresnel_amplitudes,
    lamp_fields,
    reflected_states,
    sphere_hits,
    sphere_nodes,
)
from nearlight.generator.scene import LampSpec
from nearlight.generator.targets_closed_form import (
    lamp_image_centre,
    lambert_card_radiance,
    mirror_sphere_stokes,
)
from nearlight.physics.camera import camera_rays, look_at_matrix, project
from nearlight.physics.polarization import analyzer_frame, filter_axes, korger_axis

SCENES = Path(__file__).resolve().parents[2] / "scenes"
CHROME = (3.18, 4.41)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


# --------------------------------------------------------------------------- the conductor's Fresnel amplitudes


def test_conductor_reflectance_is_the_textbooks():
    n, kappa = CHROME
    rs, rp = fresnel_amplitudes(np.array([1.0]), complex(n, kappa))
    normal = ((n - 1) ** 2 + kappa**2) / ((n + 1) ** 2 + kappa**2)  # 0.6365 for chrome
    np.testing.assert_allclose([abs(rs[0]) ** 2, abs(rp[0]) ** 2], normal, rtol=1e-14)
    # pbrt-v3 FrConductor: a² + b² = √((n² − κ² − sin²θ)² + 4n²κ²), a = √((a² + b² + n² − κ² − sin²θ)/2)
    cos = np.cos(np.radians(np.array([5.0, 30.0, 60.0, 80.0, 89.0])))
    sin2 = 1 - cos**2
    t0 = n**2 - kappa**2 - sin2
    a2b2 = np.sqrt(t0**2 + 4 * n**2 * kappa**2)
    a = np.sqrt((a2b2 + t0) / 2)
    Rs = (a2b2 - 2 * a * cos + cos**2) / (a2b2 + 2 * a * cos + cos**2)
    Rp = Rs * (cos**2 * a2b2 - 2 * a * cos * sin2 + sin2**2) / (cos**2 * a2b2 + 2 * a * cos * sin2 + sin2**2)
    rs, rp = fresnel_amplitudes(cos, complex(n, kappa))
    np.testing.assert_allclose(abs(rs) ** 2, Rs, rtol=1e-12)
    np.testing.assert_allclose(abs(rp) ** 2, Rp, rtol=1e-12)
    # κ = 0 in complex arithmetic is the dielectric
    real = fresnel_amplitudes(cos, 1.5)
    np.testing.assert_allclose(fresnel_amplitudes(cos, complex(1.5, 0.0)), real, rtol=1e-14, atol=1e-15)


def test_an_infinitely_absorbing_conductor_is_the_ideal_mirror():
    """κ → ∞: rs, rp → 1 (the frames' mirror, as reflected_states's fresnel_eta=None), as 1/κ."""
    cos = np.cos(np.radians(np.array([0.0, 30.0, 60.0, 85.0])))
    rs, rp = fresnel_amplitudes(cos, complex(3.0, 1e8))
    np.testing.assert_allclose(rs, 1.0, atol=1e-7)
    np.testing.assert_allclose(rp, 1.0, atol=1e-6)  # 2/(κ cos θi) at 85°: 2.3e-7


@pytest.mark.render
@pytest.mark.parametrize("eta, kappa", [CHROME, (0.47, 2.4), (1.0, 6.6), (1.5, 0.0)])  # gold- and aluminium-like, glass
def test_conductor_mueller_matrix_is_mitsubas(eta, kappa):
    """Mitsuba's ``specular_reflection`` is the Mueller matrix of the Jones matrix ``diag(rs, −rp)`` with
    ``S3 = −2 Im(Ex Ey*)``, for ``rs``, ``rp`` of ``η = n + iκ``. Its s/p frames flip p against ours (its mirror is
    ``diag(1, 1, −1, −1)``, ours ``rs = rp = 1``: ``a_s = −rs``, fresnel.h's Fresnel sign), and it conjugates the
    index to ``n − iκ`` before its Fresnel equations, which conjugates both amplitudes: that flips only the sign of
    ``M23`` and ``M32`` (S3's handedness); S0–S2 of linear light do not depend on it. Float32: within 1e-6."""
    import drjit as dr

    from nearlight.generator.llvm import mitsuba

    mi = mitsuba()
    cos = np.cos(np.radians(np.array([0.0, 20.0, 45.0, 70.0, 85.0])))
    want = np.asarray(mi.mueller.specular_reflection(mi.Float(cos), dr.llvm.ad.Complex2f(eta, kappa)))
    want = np.moveaxis(want, -1, 0)  # (4, 4, angles) → (angles, 4, 4)
    rs, rp = fresnel_amplitudes(cos, complex(eta, kappa))
    # Stokes of the coherency vector (x x*, x y*, y x*, y y*), with S3 = −2 Im(x y*)
    A = np.array([[1, 0, 0, 1], [1, 0, 0, -1], [0, 1, 1, 0], [0, -1j, 1j, 0]])
    got = np.array([(A @ np.kron(J, J.conj()) @ np.linalg.inv(A)).real for J in
                    (np.diag([s, -p]) for s, p in zip(rs, rp))])  # fmt: skip
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)


# --------------------------------------------------------------------------- the mirror ball

#: A 5 cm chrome ball 25 cm in front of a 96×72 camera (30°), a 3 cm lamp 13 cm from its centre: the lamp's image
#: covers 96 pixels, 56 of them more than a pixel inside its edge.
BALL = {"centre": np.zeros(3), "radius": 0.05, "camera": np.array([0.0, -0.25, 0.0]), "size": (96, 72), "fov": 30.0,
        "lamp": (0.08, -0.08, 0.06), "lamp_radius": 0.03}  # fmt: skip


def _ball_rays() -> tuple[np.ndarray, np.ndarray]:
    """The pixel-centre rays ``(H·W, 3)`` of :data:`BALL`'s camera and its ``to_world``."""
    to_world = look_at_matrix(BALL["camera"], BALL["centre"], (0.0, 0.0, 1.0))
    return camera_rays(to_world, *BALL["size"], BALL["fov"]).reshape(-1, 3), to_world


def _lamp(**over) -> tuple[LampSpec, np.ndarray]:
    """:data:`BALL`'s lamp and its filter's normal (towards the ball)."""
    spec = LampSpec(position=BALL["lamp"], radius=BALL["lamp_radius"], polarizer_axis=(1.0, 0.0, 1.0), **over)
    return spec, _unit(BALL["centre"] - np.asarray(BALL["lamp"]))


def _reflections(d: np.ndarray, sees: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The light's propagation ``k`` (lamp → ball), the view ``v`` (ball → camera) and the normal of the rays
    ``d[sees]``, by hand."""
    _, N = sphere_hits(BALL["camera"], d[sees], BALL["centre"], BALL["radius"])
    r = d[sees] - 2 * _dot(d[sees], N)[:, None] * N
    return -r, -d[sees], N


def test_the_ball_is_the_ideal_mirror_as_kappa_grows():
    """κ → ∞: the Stokes of the closed-form renderer's mirror (reflected_states, fresnel_eta=None), per state."""
    d, to_world = _ball_rays()
    spec, facing = _lamp(polarizer_extinction_ratio=4.0, anisotropy_k=2.0)
    S, sees, _ = mirror_sphere_stokes(BALL["camera"], d, to_world[:3, 1], BALL["centre"], BALL["radius"], 3.0, 1e9,
                                      spec, facing)  # fmt: skip
    assert sees.sum() == 96
    k, v, _ = _reflections(d, sees)
    x, y = analyzer_frame(v, to_world[:3, 1])
    want = np.zeros((3, sees.sum()))
    for e, w in reflected_states(k, v, lamp_fields(spec, facing, k), fresnel_eta=None):
        ex, ey = _dot(e, x), _dot(e, y)
        want += w * np.stack([ex * ex + ey * ey, ex * ex - ey * ey, 2 * ex * ey])
    want *= beam(spec, facing, k) / (np.pi * spec.radius**2)
    np.testing.assert_allclose(S[:, sees], want, rtol=0, atol=1e-8 * want[0].max())
    assert np.all(S[:, ~sees] == 0)


def test_a_conductor_turns_the_filtered_light_elliptical():
    """Behind the ideal filter the light is linear along Korger's axis, at ψ from the plane of incidence's normal s:
    reflected, ``S0 = ½ (Rs cos²ψ + Rp sin²ψ)`` (times the radiance ``1/(π a²)``), and the linear part is less than
    S0 by the circular part ``S3 = |rs| |rp| sin δ sin 2ψ / 2``, δ the phase between rp and rs (Azzam & Bashara): the
    Jones vector's phase, not its intensities, lowers S1² + S2²."""
    d, to_world = _ball_rays()
    spec, facing = _lamp()
    S, sees, _ = mirror_sphere_stokes(BALL["camera"], d, to_world[:3, 1], BALL["centre"], BALL["radius"], *CHROME,
                                      spec, facing)  # fmt: skip
    k, v, N = _reflections(d, sees)
    s = _unit(np.cross(k, N))
    t = korger_axis(k, filter_axes(spec.polarizer_axis, facing)[1])
    cos_psi, sin_psi = _dot(t, s), _dot(t, np.cross(s, k))
    rs, rp = fresnel_amplitudes(-_dot(k, N), complex(*CHROME))
    radiance = 1 / (np.pi * spec.radius**2)
    S0 = 0.5 * (abs(rs) ** 2 * cos_psi**2 + abs(rp) ** 2 * sin_psi**2) * radiance
    S3 = 0.5 * abs(rs * rp) * np.sin(np.angle(rp / rs)) * 2 * sin_psi * cos_psi * radiance
    np.testing.assert_allclose(S[0, sees], S0, rtol=1e-12)
    np.testing.assert_allclose(np.hypot(S[1, sees], S[2, sees]), np.sqrt(S0**2 - S3**2), rtol=1e-10)
    assert np.abs(S3 / S0).max() > 0.05  # measured 0.098: without the phase the linear part is 0.5 % higher there


def test_an_unpolarized_lamp_reflects_partly_polarized_along_s():
    """An extinction ratio of 1 is no filter: ``S0 = (Rs + Rp)/2 · L`` and the linear part ``(Rs − Rp)/2 · L``
    along s (the plane of incidence's normal), at its angle in the analyzer frame."""
    d, to_world = _ball_rays()
    spec, facing = _lamp(polarizer_extinction_ratio=1.0)
    S, sees, _ = mirror_sphere_stokes(BALL["camera"], d, to_world[:3, 1], BALL["centre"], BALL["radius"], *CHROME,
                                      spec, facing)  # fmt: skip
    k, v, N = _reflections(d, sees)
    Rs, Rp = (abs(r) ** 2 for r in fresnel_amplitudes(-_dot(k, N), complex(*CHROME)))
    radiance = 1 / (np.pi * spec.radius**2)
    s = _unit(np.cross(k, N))
    x, y = analyzer_frame(v, to_world[:3, 1])
    chi = np.arctan2(_dot(s, y), _dot(s, x))
    np.testing.assert_allclose(S[0, sees], (Rs + Rp) / 2 * radiance, rtol=1e-12)
    linear = (Rs - Rp) / 2 * radiance
    np.testing.assert_allclose(S[1, sees], linear * np.cos(2 * chi), rtol=0, atol=1e-12 * radiance)
    np.testing.assert_allclose(S[2, sees], linear * np.sin(2 * chi), rtol=0, atol=1e-12 * radiance)


def test_the_lamp_image_centre_is_in_the_lamps_image():
    """The camera ray through the specular point of the lamp's centre sees the lamp; its pixel is lit."""
    d, to_world = _ball_rays()
    spec, facing = _lamp()
    _, sees, on_ball = mirror_sphere_stokes(BALL["camera"], d, to_world[:3, 1], BALL["centre"], BALL["radius"],
                                            *CHROME, spec, facing)  # fmt: skip
    X = lamp_image_centre(BALL["camera"], BALL["centre"], BALL["radius"], BALL["lamp"])
    col, row, z = project(X - BALL["camera"], to_world, *BALL["size"], BALL["fov"])
    assert z > 0 and sees.reshape(BALL["size"][::-1])[int(row), int(col)]
    assert on_ball.sum() > 3000 and not (sees & ~on_ball).any()


def test_a_lamp_in_front_of_the_ball_hides_it_and_a_point_lamp_is_an_error():
    d, to_world = _ball_rays()
    spec = LampSpec(position=(0.0, -0.15, 0.0), radius=0.02)  # on the optical axis, between camera and ball
    _, _, on_ball = mirror_sphere_stokes(BALL["camera"], d, to_world[:3, 1], BALL["centre"], BALL["radius"], *CHROME,
                                         spec, np.array([0.0, 1.0, 0.0]))  # fmt: skip
    hidden = np.isfinite(sphere_hits(BALL["camera"], d, spec.position, spec.radius)[0])
    assert hidden.sum() > 100 and not (on_ball & hidden).any()
    with pytest.raises(ValueError, match="radius > 0"):
        mirror_sphere_stokes(BALL["camera"], d, to_world[:3, 1], BALL["centre"], BALL["radius"], *CHROME,
                             LampSpec(position=BALL["lamp"]), np.array([0.0, 1.0, 0.0]))  # fmt: skip


# --------------------------------------------------------------------------- the specular point


def test_the_specular_point_reflects_the_lamp_centre_to_the_camera(rng):
    """Random placements, a few with the lamp hidden behind the ball (no point that both see: an error)."""
    hidden = 0
    for _ in range(200):
        centre, radius = rng.normal(size=3) * 0.1, rng.uniform(0.01, 0.1)
        camera = centre + _unit(rng.normal(size=3)) * rng.uniform(0.2, 1.0)
        lamp = centre + _unit(rng.normal(size=3)) * rng.uniform(radius * 1.5, 1.0)
        beta = np.arccos(np.dot(_unit(camera - centre), _unit(lamp - centre)))
        horizons = [np.arccos(radius / np.linalg.norm(p - centre)) for p in (camera, lamp)]
        if beta > sum(horizons):
            hidden += 1
            with pytest.raises(ValueError, match="seen by both"):
                lamp_image_centre(camera, centre, radius, lamp)
            continue
        X = lamp_image_centre(camera, centre, radius, lamp)
        N = (X - centre) / radius
        assert abs(np.linalg.norm(X - centre) - radius) < 1e-12
        d = _unit(X - camera)
        r = d - 2 * np.dot(d, N) * N
        to = lamp - X
        assert np.linalg.norm(to - np.dot(to, r) * r) < 1e-9  # the reflected ray passes the lamp centre
        assert np.dot(to, r) > 0 and np.dot(N, -d) > 0  # in front of the mirror, on the side the camera sees
    assert 0 < hidden < 40


def test_the_specular_point_of_symmetric_and_collinear_placements():
    # camera and lamp mirror images of each other about the plane x = 0: the point is on that plane, towards them
    X = lamp_image_centre((-0.3, 0.4, 0.0), (0.0, 0.0, 0.0), 0.05, (0.3, 0.4, 0.0))
    np.testing.assert_allclose(X, [0.0, 0.05, 0.0], atol=1e-15)
    # the lamp on the line from the camera through the centre, on the camera's side: the nearest point
    X = lamp_image_centre((0.0, -0.5, 0.0), (0.0, 0.0, 0.1), 0.05, (0.0, -0.2, 0.06))
    np.testing.assert_allclose(X, (0.0, 0.0, 0.1) + 0.05 * _unit(np.array([0.0, -0.5, -0.1])), atol=1e-15)
    with pytest.raises(ValueError, match="seen by both"):  # straight behind the ball
        lamp_image_centre((0.0, -0.5, 0.0), (0.0, 0.0, 0.0), 0.05, (0.0, 0.5, 0.0))


# --------------------------------------------------------------------------- the Lambertian card


def test_a_lambertian_card_is_the_closed_form_renderers_diffuse():
    """A board under a beamed lamp behind a diattenuator (ε = 20): the closed-form renderer's diffuse image (checked
    against Mitsuba in test_closed_form.py) is ``kd · I · lambert_card_radiance`` per channel."""
    over = {"camera.resolution": [48, 36], "lamp.polarizer_extinction_ratio": 20.0, "lamp.anisotropy_k": 4.0}
    scene = load_scene(SCENES / "ts_board.yaml", overrides=over)
    arrays = closed_form_arrays(scene)
    m = np.isfinite(arrays["P"]).all(-1)
    L = lambert_card_radiance(arrays["P"][m], arrays["N"][m], 1.0, scene.lamp, scene.lamp_facing)
    want = arrays["stokes_diffuse"][0][m]
    got = L[:, None] * np.asarray(scene.material.kd) * np.asarray(scene.lamp.intensity)
    np.testing.assert_allclose(got, want, rtol=1e-6)  # the renderer's images are float32
    assert np.all(arrays["stokes_diffuse"][1:] == 0)


def test_lamberts_cosine_over_r_squared():
    P = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, 0.5], [0.3, 0.0, 0.0]])
    N = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    spec = LampSpec(position=(0.0, 0.0, 0.4))
    facing = np.array([0.0, 0.0, -1.0])
    got = lambert_card_radiance(P, N, 0.8, spec, facing)
    # ½ (ideal filter) · 0.8/π · cos θ / r²: 1/0.4², 0.4/0.5³, then the lamp below the horizon (0) and behind (0)
    want = 0.5 * 0.8 / np.pi * np.array([1 / 0.16, 0.4 / 0.125, 0.0, 0.0])
    np.testing.assert_allclose(got, want, rtol=1e-14)
    leaky = lambert_card_radiance(P, N, 0.8, LampSpec(position=(0.0, 0.0, 0.4), polarizer_extinction_ratio=4.0), facing)
    np.testing.assert_allclose(leaky, want * (1 + 1 / 4), rtol=1e-14)


def test_a_sphere_lamp_above_the_card_is_a_point_lamp_and_not_nearer():
    """Nusselt: a uniform sphere lamp wholly above a point's horizon gives it the point lamp's irradiance; the
    closed-form renderer's quadrature over the sphere (sphere_nodes, exact here: cos θi is linear in the direction,
    whose transverse part the φ rule integrates to 0) agrees to rounding. With the centre at height a/2 part of the
    sphere is below the horizon: the point formula, which integrates cos θi where the light integrates
    max(cos θi, 0), is low."""
    a = 0.03
    P = np.stack([np.linspace(-0.2, 0.2, 9), np.zeros(9), np.zeros(9)], axis=1)
    N = np.tile([0.0, 0.0, 1.0], (9, 1))

    def both(height: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        spec = LampSpec(position=(0.3, 0.0, height), radius=a)  # 0.1–0.5 m from the points
        quad = np.zeros(len(P))
        for points, weight in sphere_nodes(P, np.asarray(spec.position), a, n):
            quad += weight * np.maximum(_dot(N, _unit(points - P)), 0.0)
        return 0.5 / np.pi * quad, lambert_card_radiance(P, N, 1.0, spec, np.array([0.0, 0.0, -1.0]))

    for height in (1.001 * a, 2 * a, 10 * a):
        quad, point = both(height, 4)
        np.testing.assert_allclose(point, quad, rtol=1e-12)
    quad, point = both(a / 2, 64)
    low = 1 - point / quad
    assert np.all((low > 0.05) & (low < 0.1)), low  # measured 7.4–7.9 %


# --------------------------------------------------------------------------- against Mitsuba


@pytest.mark.render
def test_the_mirror_ball_is_mitsubas():
    """Mitsuba's ``sphere`` with its ``conductor`` (chrome) reflecting its own unpolarized ``sphere`` ``area`` lamp
    (radiance L), ``path`` with max_depth 2, one pixel-centre sample (exact: a delta BSDF reflecting a uniform
    emitter): per pixel S0, S1, S2 against :func:`mirror_sphere_stokes` with an extinction ratio of 1 (no filter)
    times ``L π a²``, in the analyzer frame (trace_stokes's sensor frame). Pixels within one pixel of the predicted
    edge of the lamp's image are left out (a pixel centre that near the edge may fall either side in float32); all
    others agree within 1e-5 of the peak S0 (measured 2.4e-7: float32), and are 0 in both off the image."""
    from scipy.ndimage import binary_erosion

    from nearlight.generator.llvm import mitsuba
    from nearlight.generator.render import trace_stokes

    mi = mitsuba()
    (W, H), radiance = BALL["size"], 2.0
    mscene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 2},
        "sensor": {"type": "perspective", "fov": BALL["fov"], "fov_axis": "x",
                   "to_world": mi.ScalarTransform4f().look_at(origin=BALL["camera"], target=BALL["centre"],
                                                               up=[0.0, 0.0, 1.0]),
                   "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"},
                            "pixel_format": "luminance"}},
        "ball": {"type": "sphere", "center": BALL["centre"], "radius": BALL["radius"],
                 "bsdf": {"type": "conductor", "eta": CHROME[0], "k": CHROME[1]}},
        "lamp": {"type": "sphere", "center": BALL["lamp"], "radius": BALL["lamp_radius"],
                 "emitter": {"type": "area", "radiance": radiance}},
    })  # fmt: skip
    got = trace_stokes(mi, mscene, spp=1, seed=0)
    to_world = np.asarray(mscene.sensors()[0].world_transform().matrix, float).reshape(4, 4)
    d = camera_rays(to_world, W, H, BALL["fov"]).reshape(-1, 3)
    spec, facing = _lamp(polarizer_extinction_ratio=1.0)
    S, sees, _ = mirror_sphere_stokes(to_world[:3, 3], d, to_world[:3, 1], BALL["centre"], BALL["radius"], *CHROME,
                                      spec, facing)  # fmt: skip
    want = S.reshape(3, H, W) * radiance * np.pi * spec.radius**2
    sees = sees.reshape(H, W)
    inside = binary_erosion(sees, np.ones((3, 3)))
    outside = binary_erosion(~sees, np.ones((3, 3)), border_value=1)
    assert inside.sum() >= 50
    assert np.all(got[:, outside] == 0)
    peak = want[0].max()
    np.testing.assert_allclose(got[:, inside], want[:, inside], rtol=0, atol=1e-5 * peak)
    assert np.abs(want[1:, inside]).max() > 0.05 * peak  # the polarization the test compares is there
