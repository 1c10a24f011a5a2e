"""``physics.polarization.linear_stokes``, the one Stokes fit, block by block (no Mitsuba)."""

import numpy as np
import pytest

from nearlight.errors import UserError
from nearlight.physics.polarization import STOKES_BLOCK, analyzer_matrix, analyzer_stack, linear_stokes


def test_blocks_give_the_whole_least_squares_fit():
    # a float32 stack of 3·STOKES_BLOCK + 7 values per angle (blocks and an odd tail): the block-by-block
    # product is the pseudo-inverse's on the float64 stack to float64 rounding (8 terms: ~1e-15 relative)
    rng = np.random.default_rng(0)
    angles = [0.0, 22.5, 45.0, 67.5, 90.0, 112.5, 135.0, 157.5]
    n = 3 * STOKES_BLOCK + 7
    stack = rng.uniform(0.0, 2.0, (len(angles), n, 1)).astype(np.float32)
    whole = np.linalg.pinv(analyzer_matrix(angles)) @ stack.astype(float).reshape(len(angles), -1)
    got = linear_stokes(stack, angles)
    assert got.shape == (3, n, 1) and got.dtype == np.float64
    np.testing.assert_allclose(got.reshape(3, -1), whole, rtol=0, atol=1e-14)


def test_noise_free_stokes_recovered_from_any_three_angles():
    # a closed form: the stack an ideal analyzer records from known S0, S1, S2 is fitted back exactly
    S = np.array([2.0, 0.6, -0.3])[:, None, None, None] * np.ones((3, 5, 4, 3))
    for angles in ([0, 45, 90, 135], [10, 70, 130], [0, 22.5, 45, 67.5, 90, 112.5, 135, 157.5]):
        stack = analyzer_stack(S, angles)
        np.testing.assert_allclose(linear_stokes(stack, angles), S, rtol=0, atol=1e-13)


def test_fewer_than_three_distinct_angles_is_refused():
    with pytest.raises(UserError, match="at least 3 distinct angles"):
        linear_stokes(np.ones((3, 2, 2)), [0, 90, 180])
