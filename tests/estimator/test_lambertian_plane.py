"""Method ``lambertian-plane``: the lamp from the diffuse fall-off over a plane (closed-form captures, no Mitsuba).

``analytic_capture``'s diffuse is ``kd/π · I/2 · cos θi / r²`` per channel
(the bare lamp's ``I`` halved by its ideal polarizer), written into the
analyzer stack as ``Id/2 + Is cos²(θ − β)`` in float32: the method's model
with ``s_c = kd_c I_c / 2π``, so its lamp is exact to the float32 images'
rounding (relative 6e-8 per reading, ~1e-8 m on the lamp here; the
tolerance, 1e-6 m, is a hundred times that).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import binom, chi2

from nearlight.capture import Capture, Rig
from nearlight.capture.targets import RigTarget
from nearlight.errors import UserError
from nearlight.estimator.lambertian_plane import lambertian_plane_estimate
from nearlight.generator.analytic import analytic_capture
from nearlight.generator.closed_form import beam
from nearlight.generator.noise import add_camera_noise
from nearlight.physics.polarization import analyzer_stack_ideal
from nearlight.physics.reflectance import normalize

#: Float32 images: the lamp is exact to ~1e-8 m (module docstring); a hundred times that.
EXACT_M = 1e-6
#: A matte card's BSDF: no specular lobe.
MATTE = {"model": "torrance_sparrow", "ks": [0.0, 0.0, 0.0], "sigma": 0.1}


def truth(capture: Capture) -> np.ndarray:
    return np.asarray(capture.truth["lamp_position"])


@pytest.mark.parametrize("scene", [
    {},  # the default board, the lamp's foot on it
    {"board_size": 0.3, "lamp_position": (0.10, 0.25, 0.45)},  # the TS board: the lamp's foot off the board
])
def test_isotropic_lamp_is_exact(scene):
    capture = analytic_capture(width=64, height=48, **scene)
    est = lambertian_plane_estimate(capture)
    assert np.linalg.norm(est.lamp_position - truth(capture)) <= EXACT_M  # measured 2e-9 and 4e-9 m
    assert np.isnan(est.ks).all() and np.isnan(est.sigma)
    assert np.isfinite(est.covariance[:3, :3]).all()
    assert np.isnan(est.covariance[3]).all() and np.isnan(est.covariance[:, 3]).all()
    assert est.diagnostics["undetermined"] == ["ks", "sigma"]
    np.testing.assert_allclose(est.stages["fit"]["normal"], [0.0, 0.0, 1.0], atol=1e-12)


def beamed(capture: Capture, k: float, axis: tuple[float, float, float]) -> Capture:
    """``capture`` lit by a cos-power lamp: its diffuse and specular times the generator's beam
    ``max(0, d·a)^k`` (:func:`nearlight.generator.closed_form.beam`), the stack rebuilt from them."""
    P = np.nan_to_num(np.asarray(capture.P, dtype=float))
    b = beam(SimpleNamespace(anisotropy_k=k, anisotropy_axis=axis), None, normalize(P - truth(capture)))
    b = np.where(capture.surface_mask, b, 0.0)[..., None]
    stack = analyzer_stack_ideal(capture.extra["truth_diffuse"] * b, capture.extra["truth_specular"] * b,
                                 np.zeros((capture.height, capture.width)), capture.analyzer_angles_deg)
    return capture.replace(stack=stack.astype(np.float32))


def test_cos_power_lamp_and_exponent_are_exact():
    axis = (0.1, -0.3, -1.0)
    capture = beamed(analytic_capture(width=64, height=48), 4.0, axis)
    est = lambertian_plane_estimate(capture, beam="cos-power")
    fit = est.stages["fit"]
    assert np.linalg.norm(est.lamp_position - truth(capture)) <= EXACT_M  # measured 5e-8 m
    assert fit["k"] == pytest.approx(4.0, rel=1e-5)  # measured 4e-7
    assert np.arccos(min(fit["axis"] @ normalize(np.array(axis)), 1.0)) <= 1e-5  # radians; measured 6e-8
    # the isotropic model cannot explain the beam: its lamp is centimetres off
    assert np.linalg.norm(lambertian_plane_estimate(capture).lamp_position - truth(capture)) > 0.01


def test_covariance_is_honest_under_camera_noise():
    """The lamp error's Mahalanobis distance² under the stated covariance follows χ²(3).

    200 seeds of Poisson–Gaussian camera noise (the generator's, 20 000 e⁻
    full well, 5 e⁻ read noise, 12 bits) on the 64×48 board. The 95 %
    ellipsoid's coverage must lie in the 99 % binomial interval of n = 200
    draws at p = 0.95, 181 to 197 (0.905–0.985): measured 194 (0.97), and
    mean d² 3.04 (χ²(3): 3, whose mean over 200 has s.d. 0.17; bound ± 4 s.d.).
    """
    clean = analytic_capture(width=64, height=48)
    n = 200
    d2 = np.empty(n)
    for seed in range(n):
        noisy = add_camera_noise(clean, noise={"full_well": 20000.0, "read_noise": 5.0, "bits": 12}, seed=seed)
        est = lambertian_plane_estimate(noisy)
        err = est.lamp_position - truth(clean)
        d2[seed] = err @ np.linalg.solve(est.covariance[:3, :3], err)
    low, high = binom.interval(0.99, n, 0.95)
    assert low <= np.sum(d2 <= chi2.ppf(0.95, 3)) <= high
    assert abs(d2.mean() - 3.0) <= 4 * np.sqrt(6.0 / n)


def card_capture(rng: np.random.Generator) -> Capture:
    """The board as the object, with garbage readings, and a tilted matte card in front of it lit by the lamp:
    ``object_id`` 1 on the board, 2 (``targets.0``, a ``matte_card`` of ``rig.targets``) on the card."""
    view = {"width": 96, "height": 72, "look_at": (0.0, 0.0, 0.0)}
    board = analytic_capture(**view)
    centre, normal = (-0.05, 0.02, 0.04), normalize(np.array([0.2, -0.3, 1.0]))
    card = analytic_capture(**view, board_size=0.2, board_centre=centre, board_normal=normal, bsdf=MATTE,
                            kd=(0.7, 0.6, 0.5))
    on_card = card.surface_mask
    ids = np.where(on_card, 2, np.where(board.surface_mask, 1, 0)).astype(np.int32)
    garbage = rng.uniform(0.0, 1.0, board.stack.shape).astype(np.float32)
    return board.replace(
        P=np.where(on_card[..., None], card.P, board.P), N=None,
        stack=np.where(on_card[None, ..., None], card.stack, garbage),
        object_id=ids, objects=("object", "targets.0"),
        rig=Rig(targets=(RigTarget(name="targets.0", type="matte_card", centre=centre, normal=tuple(normal),
                                   size=(0.2, 0.2)),)),
    )


def test_card_surface_reads_only_the_card(rng):
    capture = card_capture(rng)
    est = lambertian_plane_estimate(capture, surface="card")
    assert np.linalg.norm(est.lamp_position - truth(capture)) <= EXACT_M
    np.testing.assert_allclose(est.stages["fit"]["normal"], capture.rig.targets[0].normal, atol=1e-6)


def one_line(exc: pytest.ExceptionInfo) -> str:
    message = str(exc.value)
    assert "\n" not in message
    return message


def test_no_card_is_one_line():
    with pytest.raises(UserError, match="no matte_card") as exc:
        lambertian_plane_estimate(analytic_capture(width=64, height=48), surface="card")
    one_line(exc)


def test_constant_diffuse_is_a_lamp_at_infinity():
    capture = analytic_capture(width=64, height=48, bsdf=MATTE)
    flat = np.where(capture.surface_mask[None, ..., None], np.float32(0.25), capture.stack)
    with pytest.raises(UserError, match="no fall-off") as exc:
        lambertian_plane_estimate(capture.replace(stack=flat))
    one_line(exc)


def test_too_few_pixels_is_one_line():
    with pytest.raises(UserError, match="pixels to fit") as exc:
        lambertian_plane_estimate(analytic_capture(width=64, height=48, board_size=0.02))
    one_line(exc)
