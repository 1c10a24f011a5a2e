"""Estimator: lamp position and specular reflectance from one capture (numpy/scipy only).

Never imports Mitsuba or Dr.Jit: it reads a capture (format v1 or v2) and nothing
else, so it runs on real captures and in tests without a renderer.

Public API: :func:`estimate`, :class:`Estimate`, :data:`METHODS`,
:func:`load_method`, :func:`render_specular`, :func:`separate`, :func:`separate_capture`.
"""

from .api import METHODS, estimate, load_method
from .prediction import render_specular
from .result import Estimate
from .separation import separate, separate_capture

__all__ = ["METHODS", "Estimate", "estimate", "load_method", "render_specular", "separate", "separate_capture"]
