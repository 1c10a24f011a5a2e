"""Fixtures of the estimator's tests: the closed-form board and sphere at 160×120 (``analytic_capture``, no Mitsuba)."""

from __future__ import annotations

import pytest

from nearlight.generator.analytic import analytic_capture


@pytest.fixture(scope="module")
def board():
    return analytic_capture(shape="board", width=160, height=120)


@pytest.fixture(scope="module")
def sphere():
    return analytic_capture(shape="sphere", width=160, height=120)
