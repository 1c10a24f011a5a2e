"""Which object each pixel sees, and the calibration targets a rig knows (capture format v2, additive).

A capture of a scene with calibration targets (mirror spheres, matte cards:
``docs/scene-files.md``) says which pixel is which:

- the EXR layer ``object_id`` (one channel, small integers stored as
  float32): 0 where the pixel sees nothing, else ``i + 1`` for the pixel
  seeing ``objects[i]``;
- ``capture.json``'s ``objects``: the names, ``"object"`` (the object under
  study, always there), ``"targets.<k>"`` (target ``k`` of the scene) and
  ``"lamp"`` / ``"lamps.<i>"`` (a lamp a ray can hit, seen directly);
- ``rig.targets``: what a lab knows of each target by calibration: its
  ``type``, its calibrated ``centre`` (world, m) with the stated 1σ error per
  axis ``centre_error_m``, and its shape (a sphere's ``radius``; a card's
  ``normal`` and ``size``). The true geometry is in ``truth.targets``.

Both keys are optional: a capture without them is read as before, every
pixel with a finite ``P`` being the object's.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UserError
from ..files.schema import all_numbers, is_number

#: The name of the object under study in ``objects``.
OBJECT = "object"
#: The EXR layer of object ids.
ID_LAYER = "object_id"
#: Target types and the shape keys each has in ``rig.targets`` (besides ``name``, ``type``, ``centre``,
#: ``centre_error_m``).
TARGET_KEYS = {"mirror_sphere": ("radius",), "matte_card": ("normal", "size")}


@dataclasses.dataclass(frozen=True)
class RigTarget:
    """One calibration target as the rig knows it (``rig.targets[k]``).

    Attributes
    ----------
    name : str
        ``targets.<k>``: its name in ``objects``.
    type : {"mirror_sphere", "matte_card"}
    centre : tuple of float, shape (3,)
        Calibrated centre, world, metres.
    centre_error_m : float
        Stated 1σ error of ``centre`` per axis, metres (0: exact).
    radius : float or None
        A sphere's radius, metres.
    normal : tuple of float, shape (3,), or None
        A card's unit normal (the side it faces), world.
    size : tuple of float, shape (2,), or None
        A card's width and height, metres.
    """

    name: str
    type: str
    centre: tuple[float, float, float]
    centre_error_m: float = 0.0
    radius: float | None = None
    normal: tuple[float, float, float] | None = None
    size: tuple[float, float] | None = None

    def to_json(self) -> dict[str, Any]:
        """The ``rig.targets`` entry."""
        doc: dict[str, Any] = {"name": self.name, "type": self.type, "centre": [float(c) for c in self.centre],
                               "centre_error_m": float(self.centre_error_m)}  # fmt: skip
        for key in TARGET_KEYS[self.type]:
            value = getattr(self, key)
            doc[key] = float(value) if key == "radius" else [float(c) for c in value]
        return doc


def read_objects(x: Any, where: Path) -> tuple[str, ...]:
    """``objects`` of a ``capture.json``: distinct non-empty names including ``"object"`` (absent: ``()``)."""
    if x is None:
        return ()
    if not (isinstance(x, list) and x and all(isinstance(n, str) and n for n in x)):
        raise UserError(f"{where}: objects: expected a non-empty list of names (\"object\", \"targets.0\", ...), "
                        f"got {x!r}")  # fmt: skip
    if len(set(x)) != len(x):
        raise UserError(f"{where}: objects: names must be distinct, got {x!r}")
    if OBJECT not in x:
        raise UserError(f"{where}: objects: must name \"object\" (the object under study), got {x!r}")
    return tuple(x)


def read_object_id(layer: np.ndarray | None, objects: tuple[str, ...], where: Path) -> np.ndarray | None:
    """The ``object_id`` layer as ``[H, W]`` int32, checked against ``objects``.

    Raises
    ------
    UserError
        The layer without ``objects`` in ``capture.json`` (or the reverse), or a value that is not an integer
        from 0 to ``len(objects)``.
    """
    if layer is None:
        if objects:
            raise UserError(f"{where}: channel {ID_LAYER} missing (capture.json lists objects)")
        return None
    if not objects:
        raise UserError(f"{where}: channel {ID_LAYER}: capture.json has no objects list to say what its ids are")
    ok = np.isfinite(layer) & (layer == np.round(layer)) & (layer >= 0) & (layer <= len(objects))
    if not ok.all():
        bad = layer[~ok].flat[0]
        raise UserError(f"{where}: channel {ID_LAYER}: expected integers 0 to {len(objects)} (the objects listed), "
                        f"got {bad!r}")  # fmt: skip
    return layer.astype(np.int32)


def read_rig_targets(x: Any, where: Path) -> tuple[RigTarget, ...]:
    """``rig.targets`` of a v2 ``capture.json`` (absent: no targets)."""
    if x is None:
        return ()
    if not isinstance(x, list):
        raise UserError(f"{where}: rig.targets: expected a list of targets, got {x!r}")
    out = []
    for k, doc in enumerate(x):
        key = f"rig.targets[{k}]"
        if not isinstance(doc, dict):
            raise UserError(f"{where}: {key}: expected an object, got {doc!r}")
        kind = doc.get("type")
        if kind not in TARGET_KEYS:
            raise UserError(f"{where}: {key}.type: expected one of {', '.join(TARGET_KEYS)}, got {kind!r}")
        allowed = {"name", "type", "centre", "centre_error_m", *TARGET_KEYS[kind]}
        unknown = sorted(set(doc) - allowed)
        if unknown:
            raise UserError(f"{where}: {key}.{unknown[0]}: unknown key for a {kind}")
        name = doc.get("name")
        if not (isinstance(name, str) and name):
            raise UserError(f"{where}: {key}.name: expected its name in objects (e.g. \"targets.{k}\"), got {name!r}")
        error = doc.get("centre_error_m", 0.0)
        if not (is_number(error) and error >= 0):
            raise UserError(f"{where}: {key}.centre_error_m: expected a number >= 0 (metres), got {error!r}")
        fields: dict[str, Any] = {"centre": _vec(doc.get("centre"), 3, where, f"{key}.centre")}
        if kind == "mirror_sphere":
            radius = doc.get("radius")
            if not (is_number(radius) and radius > 0):
                raise UserError(f"{where}: {key}.radius: expected a number > 0 (metres), got {radius!r}")
            fields["radius"] = float(radius)
        else:
            normal = _vec(doc.get("normal"), 3, where, f"{key}.normal")
            if not np.linalg.norm(normal) > 0:
                raise UserError(f"{where}: {key}.normal: expected a non-zero vector, got {doc['normal']!r}")
            size = _vec(doc.get("size"), 2, where, f"{key}.size")
            if not min(size) > 0:
                raise UserError(f"{where}: {key}.size: expected 2 numbers > 0 (metres), got {doc['size']!r}")
            fields.update(normal=tuple(normal / np.linalg.norm(normal)), size=size)
        out.append(RigTarget(name=name, type=kind, centre_error_m=float(error), **fields))
    return tuple(out)


def _vec(x: Any, n: int, where: Path, key: str) -> tuple[float, ...]:
    if not (isinstance(x, list) and len(x) == n and all_numbers(x) and np.all(np.isfinite(np.asarray(x, float)))):
        raise UserError(f"{where}: {key}: expected {n} numbers, got {x!r}")
    return tuple(float(c) for c in x)
