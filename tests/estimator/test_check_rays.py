"""``geometry.check_rays``: P checked against the camera on a lattice of pixels (no Mitsuba)."""

import dataclasses

import numpy as np
import pytest

from nearlight.errors import UserError
from nearlight.estimator.geometry import RAY_CHECK_PIXELS, check_rays, pixel_ray_error
from nearlight.generator.analytic import analytic_capture


@pytest.fixture(scope="module")
def board():
    return analytic_capture(shape="board", width=640, height=480, analyzer_angles_deg=[0, 45, 90, 135])


def test_lattice_error_is_the_full_error_at_the_lattice_pixels(board):
    full, behind_full, _, _ = pixel_ray_error(board, 1)
    error, behind, rows, cols = pixel_ray_error(board, 3)
    assert (rows[0], cols[0], rows[1] - rows[0]) == (1, 1, 3)
    assert error.shape == (160, 213)  # 480 / 3 rows, 640 / 3 columns
    np.testing.assert_array_equal(error, full[np.ix_(rows, cols)])  # the same arithmetic per pixel
    np.testing.assert_array_equal(behind, behind_full[np.ix_(rows, cols)])
    # the lattice's median is the image's: both are float32 rounding of P (~1e-5 px), 3 px accepted
    assert np.nanmedian(error) == pytest.approx(np.nanmedian(full), rel=0.05)
    assert np.isfinite(error).sum() >= RAY_CHECK_PIXELS * 0.9


def test_check_rays_refuses_a_P_shifted_by_forty_columns(board):
    check_rays(board)  # the analytic capture's own P passes
    shifted = dataclasses.replace(board, P=np.roll(board.P, 40, axis=1))
    with pytest.raises(UserError, match=r"channel P: rays from camera.position through P miss their pixels by "
                                        r"(39|40|41)\.\d px \(median; at most 32\.0 accepted\)"):
        check_rays(shifted)


def test_check_rays_refuses_a_surface_behind_the_camera(board):
    C = np.asarray(board.camera.position, dtype=np.float32)
    mirrored = dataclasses.replace(board, P=2 * C - board.P)  # every point reflected through the camera
    with pytest.raises(UserError, match=r"channel P: 100% of the surface is behind the camera \(first at row \d+, "
                                        r"column \d+\)") as err:
        check_rays(mirrored)
    row, col = (int(v) for v in err.value.args[0].split("(first at row ")[1].split(")")[0].split(", column "))
    assert row % 3 == 1 and col % 3 == 1 and np.all(np.isfinite(board.P[row, col]))  # a lattice pixel on the surface
