"""A range sensor's error on P (nearlight.generator.range_sensor): along the ray, on the stated lattice."""

from __future__ import annotations

import numpy as np
import pytest

from nearlight.generator.analytic import analytic_capture
from nearlight.generator.range_sensor import perturb_range


@pytest.fixture(scope="module")
def board():
    return analytic_capture(shape="board", width=80, height=60)


def _depths(cap, clean, axis):
    rel = np.asarray(cap.P, float) - clean.camera.position
    return rel @ np.asarray(clean.camera.to_world)[:3, 2] if axis == "z" else np.linalg.norm(rel, axis=-1)


@pytest.mark.parametrize("axis", ["ray", "z"])
def test_quantised_depths_sit_on_the_lattice_and_move_along_the_ray(board, axis):
    q = 1e-3
    cap = perturb_range(board, quantum_m=q, axis=axis, seed=4)
    ok = board.surface_mask
    offset = cap.meta["noise"]["range"]["offset_m"]
    assert 0.0 <= offset < q
    k = (_depths(cap, board, axis)[ok] - offset) / q
    # float32 P at ~0.6 m: depths to ~1e-7 m, i.e. 1e-4 of a step
    assert np.max(np.abs(k - np.rint(k))) < 1e-3
    err = _depths(cap, board, axis)[ok] - _depths(board, board, axis)[ok]
    assert np.max(np.abs(err)) <= q / 2 + 1e-6
    before = board.P[ok] - board.camera.position
    after = np.asarray(cap.P, float)[ok] - board.camera.position
    cosine = np.sum(before * after, -1) / np.linalg.norm(before, axis=-1) / np.linalg.norm(after, axis=-1)
    assert np.min(cosine) > 1 - 1e-9  # same direction: the error is along each ray
    assert cap.N is None and np.array_equal(cap.extra["truth_N"], board.N, equal_nan=True)


def test_noise_has_the_stated_deviation_and_depends_on_the_seed_only(board):
    a = perturb_range(board, sigma_m=2e-4, axis="z", seed=7)
    b = perturb_range(board, sigma_m=2e-4, axis="z", seed=7)
    c = perturb_range(board, sigma_m=2e-4, axis="z", seed=8)
    ok = board.surface_mask
    err = _depths(a, board, "z")[ok] - _depths(board, board, "z")[ok]
    # ~4800 draws: the sample s.d. within 5 % of 0.2 mm (4 standard errors of a sample s.d., 1/sqrt(2n) = 1 %)
    assert np.std(err) == pytest.approx(2e-4, rel=0.05)
    assert np.array_equal(a.P, b.P, equal_nan=True) and not np.array_equal(a.P, c.P, equal_nan=True)


def test_no_error_is_the_capture_itself_and_bad_arguments_are_refused(board):
    assert perturb_range(board, seed=1) is board
    with pytest.raises(ValueError, match="axis"):
        perturb_range(board, quantum_m=1e-3, axis="x")
    with pytest.raises(ValueError, match=">= 0"):
        perturb_range(board, sigma_m=-1.0)
    with pytest.raises(ValueError, match="to_world"):
        perturb_range(board.replace(camera=board.camera.__class__(position=board.camera.position)), quantum_m=1e-3,
                      axis="z")
