"""Sub-pixel camera shift and per-shot jitter (``camera.shift_px``, ``camera.jitter_px``).

Where the pixel grid falls on the highlight is luck on a real bench; the paper's
first stage picks the brightest pixel, so its error depends on it. The camera
turns about its centre so that its optical axis passes through image position
``centre + shift``; with ``jitter_px = a`` shot ``capture.seed`` (a sweep task's
seed) adds the R2 point of index ``seed + 1`` mapped to [-a, a)².
"""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.generator import load_scene, render_clean
from nearlight.generator.render import render_key
from nearlight.physics.camera import look_at_matrix, project, shifted_target

from .test_physics import SCENES

SMALL = {"camera.resolution": [64, 48]}

#: The sub-pixel offsets (u, v) of ``sweeps/paper/first_stage.yaml``'s jitters j0..j7, as its comments print
#: them (3 decimals): the first 8 R2 points over one pixel, derived there independently of this code.
FIRST_STAGE_UV = [(-0.245, -0.430), (-0.490, 0.140), (0.265, -0.290), (0.020, 0.279),
                  (-0.226, -0.151), (-0.471, 0.419), (0.284, -0.011), (0.039, -0.441)]  # fmt: skip


def test_jitter_draws_are_the_r2_points_of_the_first_stage_study():
    cam = load_scene(SCENES / "ts_board.yaml", overrides={"camera.jitter_px": 0.5}).camera
    got = [cam.shift_for(seed) for seed in range(8)]
    np.testing.assert_allclose(got, FIRST_STAGE_UV, atol=5.1e-4)  # the comments' rounding
    assert all(-0.5 <= x < 0.5 for uv in got for x in uv)
    assert load_scene(SCENES / "ts_board.yaml").camera.shift_for(7) == (0.0, 0.0)


@pytest.mark.parametrize("shift", [(0.3, -0.2), (-0.5, 0.5), (0.0, 0.25)])
def test_the_shifted_axis_is_the_old_ray_through_centre_plus_shift(shift):
    pos, look, W, H, fov = np.array([0.0, -0.35, 0.5]), np.zeros(3), 160, 120, 50.0
    old = look_at_matrix(pos, look)
    target = shifted_target(pos, look, (0, 0, 1), fov, W, H, shift)
    # exact by construction: the new look-at point lies on the old camera's ray through centre + shift
    col, row, _ = project(target - pos, old, W, H, fov)
    np.testing.assert_allclose([col, row], [W / 2 + shift[0], H / 2 + shift[1]], atol=1e-9)
    assert np.linalg.norm(target - pos) == pytest.approx(np.linalg.norm(look - pos), rel=1e-12)
    # the scene moves by -shift at the image centre, to first order in the turn (0.5 px is 0.16 deg here):
    # the rest grows as |shift|^2, measured 7e-4 px at (0.3, -0.2) and 2.1e-3 px at (-0.5, 0.5), the largest
    col, row, _ = project(look - pos, look_at_matrix(pos, target), W, H, fov)
    np.testing.assert_allclose([col, row], [W / 2 - shift[0], H / 2 - shift[1]], atol=3e-3)


def test_render_key_moves_with_the_shot_only_when_the_camera_jitters():
    base = load_scene(SCENES / "ts_board.yaml")
    off = load_scene(SCENES / "ts_board.yaml", overrides={"camera.jitter_px": 0.0, "camera.shift_px": [0, 0],
                                                          "capture.seed": 4})  # fmt: skip
    assert render_key(off) == render_key(base)  # off values leave the key (and every old cache) alone
    shots = [load_scene(SCENES / "ts_board.yaml", overrides={"camera.jitter_px": 0.5, "capture.seed": s})
             for s in range(3)]  # fmt: skip
    assert len({render_key(s) for s in shots}) == 3
    same = load_scene(SCENES / "ts_board.yaml", overrides={"camera.shift_px": list(shots[1].camera.shift_for(1))})
    assert render_key(same) == render_key(shots[1])  # the key is the shift the seed makes, not the seed


@pytest.mark.render
def test_a_jittered_render_is_the_camera_turned_onto_the_sub_pixel_point():
    scene = load_scene(SCENES / "ts_board.yaml", overrides={**SMALL, "camera.jitter_px": 0.5, "capture.seed": 2})
    shift = scene.camera.shift_for(2)
    cap = render_clean(scene, progress=False)
    cam = scene.camera
    expected = look_at_matrix(cam.position, cam.target(2), cam.up)
    np.testing.assert_allclose(cap.camera.to_world, expected, atol=1e-6)  # Mitsuba's float32 sensor transform
    # The surface seen at the image centre is the point the unshifted camera saw at centre + shift
    # (P is float32: 1e-7 relative of 0.6 m is 1e-4 px of a 2.6 mm pixel footprint).
    W, H = cam.width, cam.height
    c, r = np.meshgrid([W // 2 - 1, W // 2], [H // 2 - 1, H // 2])
    P = cap.P[r, c].astype(float)
    col, row, _ = project(P - np.asarray(cam.position), look_at_matrix(cam.position, cam.look_at, cam.up), W, H,
                          cam.fov_x_deg)  # fmt: skip
    # centre pixels are within 1 px of the axis, where the turn moves the image by shift to < 0.01 px
    np.testing.assert_allclose(col - (c + 0.5), shift[0], atol=0.01)
    np.testing.assert_allclose(row - (r + 0.5), shift[1], atol=0.01)
