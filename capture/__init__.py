"""Capture format (v1 read, v2 read and written): what the generator writes, a real rig records and the estimator reads.

Specified in ``docs/capture-format.md``; :mod:`nearlight.capture.format` is its
one reference implementation (reading, writing, the :class:`Capture` and
:class:`Camera`, :class:`Intrinsics`, :class:`LampFilter`, :class:`RangeSensor`, :class:`Rig` and
:class:`Sensor` records).
"""

from .format import (
    EXR_NAME,
    FORMAT,
    FORMAT_V1,
    FORMATS,
    JSON_NAME,
    Camera,
    Capture,
    Intrinsics,
    LampFilter,
    RangeSensor,
    Rig,
    Sensor,
    capture_json,
    read_capture,
    write_capture,
)

__all__ = [
    "EXR_NAME",
    "FORMAT",
    "FORMAT_V1",
    "FORMATS",
    "JSON_NAME",
    "Camera",
    "Capture",
    "Intrinsics",
    "LampFilter",
    "RangeSensor",
    "Rig",
    "Sensor",
    "capture_json",
    "read_capture",
    "write_capture",
]
