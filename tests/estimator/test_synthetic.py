"""nearlight.generator.analytic: the analytic captures the estimator's tests stand on."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.capture import read_capture, write_capture
from nearlight.physics.reflectance import diffuse_radiance, specular_radiance
from nearlight.generator.analytic import analytic_capture
from nearlight.physics.camera import camera_rays, look_at_matrix


def test_camera_follows_mitsuba_look_at_and_image_orientation():
    to_world = look_at_matrix([0, -1, 0], [0, 0, 0], [0, 0, 1])
    # Mitsuba's look-at: columns left, up, forward, origin.
    np.testing.assert_allclose(to_world[:3, 2], [0, 1, 0])  # forward
    np.testing.assert_allclose(to_world[:3, 1], [0, 0, 1])  # up
    np.testing.assert_allclose(to_world[:3, 0], [-1, 0, 0])  # left = up x forward
    rays = camera_rays(to_world, 4, 2, 90.0)
    # the four central rays straddle the optical axis symmetrically
    centre = rays[:, 1:3].mean(axis=(0, 1))
    np.testing.assert_allclose(centre / np.linalg.norm(centre), [0, 1, 0], atol=1e-12)
    assert rays[0, 0, 0] < 0 < rays[0, -1, 0]  # column 0 looks towards -x (left), the last towards +x
    assert rays[0, 0, 2] > 0 > rays[-1, 0, 2]  # row 0 looks up
    # 90° horizontal field of view, 4 columns: column 0's centre is at 3/4 of tan(45°) to the
    # left, i.e. atan(0.75) = 36.87° off the axis horizontally.
    horizontal = np.degrees(np.arctan2(-rays[0, 0, 0], rays[0, 0, 1]))
    assert horizontal == pytest.approx(np.degrees(np.arctan(0.75)), abs=1e-9)


def test_board_and_sphere_geometry():
    board = analytic_capture(width=64, height=48)
    m = board.surface_mask
    assert 0.2 < m.mean() < 0.9
    np.testing.assert_allclose(board.P[m][:, 2], 0.0, atol=1e-6)  # on the z = 0 board
    assert np.abs(board.P[m][:, :2]).max() <= 0.2 + 1e-6  # inside its 0.4 m square
    np.testing.assert_allclose(board.N[m], np.broadcast_to([0, 0, 1], board.N[m].shape))
    sphere = analytic_capture(shape="sphere", width=64, height=48)
    m = sphere.surface_mask
    d = sphere.P[m] - np.array([0, 0, 0.15])
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 0.15, rtol=1e-5)
    np.testing.assert_allclose(sphere.N[m], d / 0.15, atol=1e-5)
    # visible side only: normals face the camera
    assert np.all(np.sum(sphere.N[m] * (sphere.camera.position - sphere.P[m]), axis=-1) > 0)


def test_images_follow_the_closed_forms_and_ideal_polarization():
    cap = analytic_capture(width=64, height=48, analyzer_angles_deg=(0, 30, 60, 90, 120, 150), phase_deg=30.0)
    m = cap.surface_mask
    P, N = cap.P[m].astype(float), cap.N[m].astype(float)
    lamp = cap.truth["lamp_position"]
    half = np.array(cap.truth["lamp_intensity"]) / 2  # behind the ideal lamp polarizer
    spec = specular_radiance(P, N, cap.camera.position, lamp, half, cap.truth["bsdf"])
    diff = diffuse_radiance(P, N, cap.camera.position, lamp, half, cap.truth["bsdf"]["kd"])
    np.testing.assert_allclose(cap.extra["truth_specular"][m], spec, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(cap.extra["truth_diffuse"][m], diff, rtol=1e-5, atol=1e-6)
    # I(θ) = Id/2 + Is cos²(θ − β): at θ = β (30°) the full specular, at β + 90° none.
    np.testing.assert_allclose(cap.stack[1][m], diff / 2 + spec, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(cap.stack[4][m], diff / 2, rtol=1e-5, atol=1e-6)
    assert np.all(cap.stack[:, ~m] == 0)


def test_ward_and_separated_captures_round_trip(tmp_path):
    ward = {"model": "ward", "rho_s": [0.2, 0.2, 0.2], "alpha": 0.08}
    cap = analytic_capture(width=32, height=24, bsdf=ward, analyzer_angles_deg=None, with_normals=False)
    assert cap.stack is None and cap.N is None and np.all(np.isfinite(cap.specular))
    assert cap.specular.max() > 0
    back = read_capture(write_capture(cap, tmp_path / "c"))
    np.testing.assert_array_equal(back.specular, cap.specular)
    assert back.truth["bsdf"]["model"] == "ward"


def test_unknown_shape():
    with pytest.raises(ValueError, match="shape"):
        analytic_capture(shape="torus")
