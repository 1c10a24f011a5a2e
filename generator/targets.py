"""Calibration targets beside the object: their Mitsuba shapes, the object ids, and what the rig knows of them.

A scene's ``targets`` (:class:`~nearlight.generator.scene.MirrorSphere`,
:class:`~nearlight.generator.scene.MatteCard`) are rendered in the same Mitsuba
scene as the object, so they cast shadows on it and hide it as real ones do
(and, with ``capture.max_depth`` > 2, light it by interreflection):

- a mirror sphere is Mitsuba's ``sphere`` with a ``conductor`` BSDF of complex
  index ``eta + i k`` (Fresnel's Mueller matrix of a metal: it turns the lamp's
  linear polarization elliptical); it shows the lamp's image only when the
  lamp is a shape rays can hit (``lamp.intersectable``);
- a matte card is a ``rectangle`` with a ``diffuse`` BSDF of reflectance
  ``albedo`` (fully depolarizing), one-sided like a board.

Every render pass that is about the object (the specular and diffuse parts)
has the targets black: they block light and hide the object but add none. The
light of everything other than the object (the targets, and a lamp the
camera sees directly) is its own pass, ``others``
(:func:`nearlight.generator.render._render_arrays`).

Ids (:func:`object_names`, :mod:`nearlight.capture.targets`): ``object`` 1,
``targets.<k>`` ``k + 2``, then every intersectable lamp; each pixel's is the
object its pixel-centre ray meets first
(:func:`nearlight.generator.render.object_ids`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..capture.targets import OBJECT, RigTarget
from .scene import MatteCard, MirrorSphere, Scene, lamp_name, placement

#: Mitsuba BSDF that absorbs everything (a target in a pass about the object).
BLACK = {"type": "diffuse", "reflectance": {"type": "uniform", "value": 0.0}}


def shape_name(k: int) -> str:
    """The Mitsuba shape id of target ``k``."""
    return f"target{k}"


def lamp_shape_name(i: int) -> str:
    """The Mitsuba id of lamp ``i``'s shape (an intersectable lamp): lamp 0's dict keeps the one-lamp scene's key."""
    return "lamp" if i == 0 else f"lamp{i}"


def target_shapes(scene: Scene, *, lit: bool) -> dict[str, dict[str, Any]]:
    """The targets' Mitsuba shape dicts (``to_world`` as 4×4 nested lists), their own BSDFs when ``lit``, else
    black."""
    out = {}
    for k, target in enumerate(scene.targets):
        if isinstance(target, MirrorSphere):
            bsdf = {"type": "conductor", "eta": target.eta, "k": target.k}
            shape = {"type": "sphere", "center": list(target.position), "radius": target.radius}
        else:
            bsdf = {"type": "diffuse", "reflectance": {"type": "uniform", "value": target.albedo}}
            w, h = target.size
            shape = {"type": "rectangle", "to_world": (placement(target) @ np.diag([w / 2, h / 2, 1.0, 1.0])).tolist()}
        out[shape_name(k)] = {**shape, "bsdf": bsdf if lit else BLACK}
    return out


def object_names(scene: Scene) -> tuple[str, ...]:
    """The capture's ``objects``: the object, each target, each intersectable lamp (id = index + 1)."""
    lamps = [lamp_name(i, len(scene.lamps)) for i, lamp in enumerate(scene.lamps) if lamp.intersectable]
    return (OBJECT, *(f"targets.{k}" for k in range(len(scene.targets))), *lamps)


def needs_ids(scene: Scene) -> bool:
    """Whether the capture says which pixel is which: a scene with targets or an intersectable lamp (a scene of
    the object alone is written as before)."""
    return bool(scene.targets) or any(lamp.intersectable for lamp in scene.lamps)


def target_truth(scene: Scene) -> list[dict[str, Any]]:
    """``truth.targets``: every target's true geometry and material (world, metres)."""
    out = []
    for k, target in enumerate(scene.targets):
        doc = target.model_dump(mode="json")
        doc.pop("calibration_error_m")
        doc = {"name": f"targets.{k}", **doc}
        if isinstance(target, MatteCard):
            doc["normal"] = placement(target)[:3, 2].tolist()
        out.append(doc)
    return out


def rig_targets(scene: Scene) -> tuple[RigTarget, ...]:
    """``rig.targets`` of the clean render: the true geometry with each target's stated error (the per-capture
    calibration error is drawn by :func:`calibrated`)."""
    out = []
    for k, target in enumerate(scene.targets):
        common = {"name": f"targets.{k}", "type": target.type, "centre": tuple(map(float, target.position)),
                  "centre_error_m": target.calibration_error_m}  # fmt: skip
        if isinstance(target, MirrorSphere):
            out.append(RigTarget(**common, radius=target.radius))
        else:
            normal = placement(target)[:3, 2]
            out.append(RigTarget(**common, normal=tuple(map(float, normal)), size=tuple(map(float, target.size))))
    return tuple(out)


def target_rng(seed: int) -> np.random.Generator:
    """The targets' calibration stream of a capture's seed: child 3 of ``np.random.SeedSequence(seed)`` (children
    0–2 are the camera noise, range noise and nuisance streams, :mod:`nearlight.generator.nuisances`)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed)).spawn(4)[3])


def calibrated(targets: tuple[RigTarget, ...], seed: int) -> tuple[tuple[RigTarget, ...], list[list[float]]]:
    """The targets as a lab calibrated them for capture ``seed``: each centre moved by a normal draw of its
    stated error per axis (three standard normals per target, in order, whatever the errors are).

    Returns
    -------
    targets : tuple of RigTarget
        The calibrated targets (the stated errors unchanged).
    offsets : list of [dx, dy, dz]
        What was drawn, metres (``truth.nuisances.targets``).
    """
    rng = target_rng(seed)
    out, offsets = [], []
    for target in targets:
        offset = rng.standard_normal(3) * target.centre_error_m
        offsets.append(offset.tolist())
        centre = tuple(float(c) for c in np.asarray(target.centre) + offset)
        out.append(RigTarget(**{**target.__dict__, "centre": centre}))
    return tuple(out), offsets
