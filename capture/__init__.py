"""Capture format v1: what the generator writes, a real rig records and the estimator reads.

Specified in ``docs/capture-format.md``; :mod:`nearlight.capture.format` is its
one reference implementation (reading, writing, the :class:`Capture` and
:class:`Camera` records).
"""

from .format import EXR_NAME, FORMAT, JSON_NAME, Camera, Capture, capture_json, read_capture, write_capture

__all__ = ["EXR_NAME", "FORMAT", "JSON_NAME", "Camera", "Capture", "capture_json", "read_capture", "write_capture"]
