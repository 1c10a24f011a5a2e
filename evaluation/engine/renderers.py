"""Renderers a sweep can use: the Mitsuba generator, its closed form, either per scene, or analytic captures.

A renderer knows its scene format (a nested dict), where the keys each sweep
axis changes live in it, how to check a scene, and how to render one. The
``mitsuba`` renderer is the generator (scene files of ``scenes/``, renders
cached on disk by hash); ``closed-form`` renders the same scene files by
arithmetic (:mod:`nearlight.generator.closed_form`: the same capture but for
float rounding, for the scenes it covers); ``auto`` gives each scene to
``closed-form`` when it covers it, to ``mitsuba`` otherwise. The ``analytic``
renderer calls :func:`nearlight.generator.analytic.analytic_capture` (numpy only,
its own scene format: a board or a sphere, ``ideal`` polarization with a constant
phase), for testing the evaluation itself.
"""

from __future__ import annotations

import copy
import inspect
import json
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from ...files.digests import stable_hash
from ...files.dotted import get_dotted, set_dotted
from ...files.schema import is_number
from ...errors import UserError
from ...files.yamlfile import load_yaml_file
from ...physics.reflectance import LOBES, convert_bsdf, roughness_for_ts_sigma


def convert_material(material: dict, model: str) -> dict:
    """Switch a material to another lobe family, keeping the lobe's small-angle width and head-on peak.

    :func:`nearlight.physics.reflectance.convert_bsdf` (Torrance–Sparrow → Ward:
    ``alpha = sqrt(2)·sigma`` and ``rho_s = 4π alpha² ks``); other keys (kd,
    polarization, eta) are kept.
    """
    old = material.get("model", "torrance_sparrow")
    if old == model:
        return dict(material, model=model)
    if old not in LOBES or model not in LOBES:
        raise UserError(f"cannot convert material model {old!r} to {model!r}: give the material as a mapping")
    return convert_bsdf({**material, "model": old}, model)


#: Object keys that place a shape (kept when an ``object`` axis value changes the shape's type).
PLACEMENT_KEYS = ("position", "rotation_deg", "normal")


class Renderer:
    """Scene format and rendering of one renderer (subclasses fill the key names)."""

    name = ""
    lamp_key = ""
    object_key = ""
    material_key = ""
    angles_key = ""
    polarization_key: str | None = None
    #: Renders are slow and cached on disk: render each physical configuration once up front.
    prerender = False
    #: The optional part of nearlight it needs (``pip install 'nearlight[EXTRA]'``), or None.
    extra: str | None = None

    def load_base(self, scene: str | dict, *, base_dir: Path, where: str) -> dict:
        """The base scene as a dict: a mapping as given, or a YAML file relative to ``base_dir``."""
        if isinstance(scene, dict):
            return copy.deepcopy(scene)
        path = Path(scene) if Path(scene).is_absolute() else base_dir / scene
        if not path.is_file():
            raise UserError(f"{where}: no such scene file {str(path)!r}")
        doc = load_yaml_file(path, what="scene file")
        if not isinstance(doc, dict):
            raise UserError(f"{path}: expected a mapping of scene sections")
        return doc

    def object_centre(self, scene: dict) -> np.ndarray:
        """Centre of the object, metres (the origin of the lamp-distance ray)."""
        raise NotImplementedError

    def _one_lamp_key(self, scene: dict, *, where: str) -> str:
        """The key of the one lamp's position: ``lamp_key``, or ``lamps.0.position`` for a one-element
        ``lamps:`` list.

        The ``lamp_distance`` axis puts *the* lamp at a distance from the object centre. A scene with
        several lamps is a one-line error rather than every lamp moved: one distance cannot be every
        lamp's (they may be at different distances), and scaling them all would silently make the axis
        mean something else (a ratio, not metres); sweep them with ``lamps.<i>.position`` instead.
        """
        lamps = scene.get("lamps") if get_dotted(scene, self.lamp_key) is None else None
        if isinstance(lamps, list):
            if len(lamps) == 1:
                return "lamps.0.position"
            raise UserError(f"{where}: lamp_distance: expected a scene with one lamp, this one has {len(lamps)} "
                            "(lamps:); set each lamp with lamps.<i>.position instead")
        return self.lamp_key

    def apply_axis(self, scene: dict, name: str, value: Any, *, where: str) -> None:
        """Change ``scene`` in place for one physical axis value."""
        if name == "object":
            if isinstance(value, dict):
                base = get_dotted(scene, self.object_key.rpartition(".")[0] or self.object_key) or {}
                if "type" in value and value["type"] != base.get("type"):  # another shape: keep only its placement
                    base = {k: v for k, v in base.items() if k in PLACEMENT_KEYS}
                set_dotted(scene, self.object_key.rpartition(".")[0], {**base, **value}, where=where)
            else:
                set_dotted(scene, self.object_key, value, where=where)
        elif name == "bsdf":
            material = dict(get_dotted(scene, self.material_key) or {})
            if isinstance(value, dict):  # the base's diffuse and polarization stay with a lobe family of ours;
                # a Mitsuba BSDF (``model: mitsuba``) is the whole material and has none of those keys
                ours = value.get("model", "torrance_sparrow") in LOBES
                keep = {k: v for k, v in material.items() if ours and k in ("kd", "polarization", "eta")}
                material = {**keep, **value}
            else:
                try:
                    material = convert_material(material, value)
                except UserError as exc:
                    raise UserError(f"{where}: {exc}") from None
            set_dotted(scene, self.material_key, material, where=where)
        elif name == "polarization":
            if self.polarization_key is None:
                if value != "ideal":
                    raise UserError(f"{where}: the {self.name} renderer supports only 'ideal' polarization")
                return
            set_dotted(scene, self.polarization_key, value, where=where)
        elif name == "roughness":
            model = get_dotted(scene, f"{self.material_key}.model", "torrance_sparrow")
            if model in LOBES:  # the axis is the Torrance–Sparrow σ; other families get their equivalent
                set_dotted(scene, f"{self.material_key}.{LOBES[model].roughness_key}",
                           roughness_for_ts_sigma(model, float(value)), where=where)
            else:
                raise UserError(f"{where}: material model {model!r} has no roughness key; use a dotted scene key")
        elif name == "analyzer_angles":
            angles = [180.0 * k / value for k in range(value)] if isinstance(value, int) else list(value)
            set_dotted(scene, self.angles_key, angles, where=where)
        elif name == "lamp_distance":
            key = self._one_lamp_key(scene, where=where)
            centre = self.object_centre(scene)
            lamp = np.asarray(get_dotted(scene, key), dtype=float)
            ray = lamp - centre
            norm = float(np.linalg.norm(ray))
            if not norm > 0:
                raise UserError(f"{where}: the lamp sits at the object centre: no ray to move it along")
            set_dotted(scene, key, (centre + float(value) * ray / norm).tolist(), where=where)
        else:  # pragma: no cover - sweep.AXES lists only the names above
            raise ValueError(name)

    def validate(self, scene: dict, *, where: str) -> None:
        """Raise UserError unless ``scene`` is a valid scene for this renderer."""
        raise NotImplementedError

    def render_key(self, scene: dict) -> str:
        """Hash of what the render depends on."""
        return stable_hash([self.name, scene])

    def prepare(self, scene: dict, *, cache_dir: Path | None) -> bool:
        """Render ``scene`` into the cache if it is not there; True if it rendered."""
        return False

    def on_disk(self, scene: dict) -> bool:
        """Whether ``scene``'s render is made ahead of its tasks and cached on disk (:attr:`prerender`), not made
        by each task."""
        return self.prerender

    def renders_per_seed(self, scene: dict) -> bool:
        """Whether the seed changes the render itself (a camera that moves per shot), not only what follows it."""
        return False

    def render(self, scene: dict, *, cache_dir: Path | None) -> Any:
        """The noise-free capture of ``scene``."""
        raise NotImplementedError

    def used_by(self, scene: dict) -> str:
        """The renderer that renders ``scene`` (a result row's ``renderer``): this one, but for ``auto``."""
        return self.name


class AnalyticRenderer(Renderer):
    """Closed-form captures: scenes are keyword arguments of ``analytic_capture``."""

    name = "analytic"
    lamp_key = "lamp_position"
    object_key = "shape"
    material_key = "bsdf"
    angles_key = "analyzer_angles_deg"

    def load_base(self, scene: str | dict, *, base_dir: Path, where: str) -> dict:
        """The base scene with every ``analytic_capture`` default filled in (so axes can change any of them)."""
        from ...generator.analytic import DEFAULT_BSDF

        doc = super().load_base(scene, base_dir=base_dir, where=where)
        self.validate(doc, where=where)
        full = {k: p.default for k, p in self._params().items()}
        full["bsdf"] = dict(DEFAULT_BSDF)
        full.update(doc)
        return json.loads(json.dumps(full, default=list))

    def apply_axis(self, scene: dict, name: str, value: Any, *, where: str) -> None:
        if name == "object" and isinstance(value, dict):
            scene.update(value)
            return
        super().apply_axis(scene, name, value, where=where)

    def _params(self) -> dict[str, inspect.Parameter]:
        from ...generator.analytic import analytic_capture

        return dict(inspect.signature(analytic_capture).parameters)

    def object_centre(self, scene: dict) -> np.ndarray:
        key = "sphere_centre" if scene["shape"] == "sphere" else "board_centre"
        return np.asarray(scene[key], dtype=float)

    def validate(self, scene: dict, *, where: str) -> None:
        params = self._params()
        for key in scene:
            if key not in params:
                raise UserError(f"{where}: {key}: not an analytic_capture argument (expected one of {', '.join(params)})")
        if scene.get("shape", "board") not in ("board", "sphere"):
            raise UserError(f"{where}: shape: expected 'board' or 'sphere', got {scene['shape']!r}")
        bsdf = scene.get("bsdf")
        if bsdf is not None and not isinstance(bsdf, dict):
            raise UserError(f"{where}: bsdf: expected a mapping with a model key, got {bsdf!r}")
        if bsdf is not None and bsdf.get("model") not in LOBES:
            raise UserError(f"{where}: bsdf.model: expected one of {', '.join(repr(m) for m in LOBES)}, "
                            f"got {bsdf.get('model')!r}")
        for key, value in scene.items():
            kind = self.KINDS.get(key)
            if kind is not None and not _analytic_value_ok(kind, value):
                raise UserError(f"{where}: {key}: expected {self.KIND_TEXT[kind]}, got {value!r}")

    #: What each ``analytic_capture`` argument must be (checked before any task runs).
    KINDS = {"width": "size", "height": "size", "fov_x_deg": "fov", "camera_position": "vec3", "look_at": "vec3|none",
             "up": "vec3", "lamp_position": "vec3", "lamp_intensity": "rgb|number", "kd": "rgb",
             "analyzer_angles_deg": "angles|none", "phase_deg": "number|list", "board_size": "positive",
             "board_centre": "vec3", "board_normal": "vec3", "sphere_centre": "vec3", "sphere_radius": "positive",
             "with_normals": "bool", "shape": "str"}  # fmt: skip
    KIND_TEXT = {"size": "a positive integer (at most 16384)", "fov": "a number of degrees in (0, 180)",
                 "vec3": "3 numbers", "vec3|none": "3 numbers or null", "rgb|number": "a number >= 0 or 3 of them",
                 "rgb": "3 numbers >= 0", "angles|none": "a list of at least 3 angles in degrees, or null",
                 "number|list": "a number or a list of numbers", "positive": "a positive number",
                 "bool": "true or false", "str": "a name"}  # fmt: skip

    def render(self, scene: dict, *, cache_dir: Path | None) -> Any:
        from ...generator.analytic import analytic_capture

        return analytic_capture(**copy.deepcopy(scene))


def _analytic_value_ok(kind: str, v: Any) -> bool:
    """Whether ``v`` is a value of ``kind`` (see ``AnalyticRenderer.KINDS``)."""
    numbers = isinstance(v, (list, tuple)) and all(is_number(x) for x in v)
    return {
        "size": lambda: isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 16384,
        "fov": lambda: is_number(v) and 0 < v < 180,
        "vec3": lambda: numbers and len(v) == 3,
        "vec3|none": lambda: v is None or (numbers and len(v) == 3),
        "rgb|number": lambda: (is_number(v) and v >= 0) or (numbers and len(v) == 3 and min(v) >= 0),
        "rgb": lambda: numbers and len(v) == 3 and min(v) >= 0,
        "angles|none": lambda: v is None or (numbers and len(v) >= 3),
        "number|list": lambda: is_number(v) or (numbers and len(v) > 0),
        "positive": lambda: is_number(v) and v > 0,
        "bool": lambda: isinstance(v, bool),
        "str": lambda: isinstance(v, str),
    }[kind]()


class MitsubaRenderer(Renderer):
    """The generator: scene files of ``scenes/``, Mitsuba 3 renders cached by hash."""

    name = "mitsuba"
    lamp_key = "lamp.position"
    object_key = "object.type"
    material_key = "material"
    angles_key = "capture.analyzer_angles_deg"
    polarization_key = "material.polarization"
    prerender = True
    extra = "render"

    def _scene(self, scene: dict) -> Any:
        from ...generator import load_scene

        return load_scene(copy.deepcopy(scene))

    def object_centre(self, scene: dict) -> np.ndarray:
        return np.asarray(get_dotted(scene, "object.position", [0.0, 0.0, 0.0]), dtype=float)

    def validate(self, scene: dict, *, where: str) -> None:
        try:
            self._scene(scene)
        except UserError as exc:
            raise UserError(f"{where}: {exc}") from None

    def renders_per_seed(self, scene: dict) -> bool:
        return get_dotted(scene, "camera.jitter_px", 0.0) > 0

    def render_key(self, scene: dict) -> str:
        """The generator's render hash (noise and analyzer angles do not change a render; the seed only
        through ``camera.jitter_px``)."""
        from ...generator.render import render_key

        return render_key(self._scene(scene))

    def prepare(self, scene: dict, *, cache_dir: Path | None) -> bool:
        from ...generator import render_clean

        parsed = self._scene(scene)
        hit = cache_dir is not None and (cache_dir / f"{self.render_key(scene)}.npz").is_file()
        render_clean(parsed, cache_dir=cache_dir, progress=False)
        return not hit

    def render(self, scene: dict, *, cache_dir: Path | None) -> Any:
        from ...generator import render_clean

        return render_clean(self._scene(scene), cache_dir=cache_dir, progress=False)


class ClosedFormRenderer(MitsubaRenderer):
    """Scene files rendered in closed form (:mod:`nearlight.generator.closed_form`): Mitsuba's capture by
    arithmetic, numpy only, for the scenes it covers (a scene it does not cover is a one-line error naming the
    key). Milliseconds per render: nothing goes to disk, but each worker process keeps its last
    :attr:`KEEP` renders (the arrays :func:`~nearlight.generator.closed_form.closed_form_arrays` returns) in
    memory by render key, since a sweep's tasks of one render (its seeds, methods, analyzer angles) come
    together; each task's capture is assembled from its own copy, so no task sees another's changes."""

    name = "closed-form"
    prerender = False
    extra = None
    #: Renders a worker process keeps (a 160x120 render is about 2 MB).
    KEEP = 8
    _kept: OrderedDict[str, Any] = OrderedDict()

    def validate(self, scene: dict, *, where: str) -> None:
        from ...generator.closed_form import not_covered

        super().validate(scene, where=where)
        why = not_covered(self._scene(scene))
        if why:
            raise UserError(f"{where}: {why[0]}: the closed-form renderer does not cover it (renderer: auto renders "
                            "such scenes with Mitsuba)")  # fmt: skip

    def render_key(self, scene: dict) -> str:
        from ...generator.closed_form import closed_form_key

        return closed_form_key(self._scene(scene))

    def prepare(self, scene: dict, *, cache_dir: Path | None) -> bool:
        return False

    def render(self, scene: dict, *, cache_dir: Path | None) -> Any:
        from ...generator.closed_form import closed_form_arrays, closed_form_key, render_closed_form

        parsed = self._scene(scene)
        key = closed_form_key(parsed)  # the render, not what is made of it (analyzer angles, seed: assemble's)
        kept = ClosedFormRenderer._kept
        if key in kept:
            kept.move_to_end(key)
        else:
            kept[key] = closed_form_arrays(parsed)
            while len(kept) > self.KEEP:
                kept.popitem(last=False)
        return render_closed_form(parsed, arrays={k: v.copy() for k, v in kept[key].items()})


class AutoRenderer(MitsubaRenderer):
    """Each scene to the closed-form renderer when it covers every key the scene uses
    (:func:`nearlight.generator.closed_form.not_covered`), to Mitsuba otherwise; :meth:`used_by` names the one a
    scene gets (a result row's ``renderer``)."""

    name = "auto"

    def __init__(self) -> None:
        super().__init__()
        self._covers: dict[str, bool] = {}

    def covers(self, scene: dict) -> bool:
        """Whether the closed form renders ``scene`` (parsed once per scene: a sweep asks for each of its tasks)."""
        from ...generator.closed_form import not_covered

        key = stable_hash(scene)
        if key not in self._covers:
            self._covers[key] = not not_covered(self._scene(scene))
        return self._covers[key]

    def chosen(self, scene: dict) -> Renderer:
        """The renderer ``scene`` goes to."""
        return ClosedFormRenderer() if self.covers(scene) else MitsubaRenderer()

    def used_by(self, scene: dict) -> str:
        return self.chosen(scene).name

    def on_disk(self, scene: dict) -> bool:
        return self.chosen(scene).prerender

    def render_key(self, scene: dict) -> str:
        return self.chosen(scene).render_key(scene)

    def prepare(self, scene: dict, *, cache_dir: Path | None) -> bool:
        return self.chosen(scene).prepare(scene, cache_dir=cache_dir)

    def render(self, scene: dict, *, cache_dir: Path | None) -> Any:
        return self.chosen(scene).render(scene, cache_dir=cache_dir)


#: Renderers by the sweep file's ``renderer`` key.
RENDERERS: dict[str, type[Renderer]] = {"analytic": AnalyticRenderer, "mitsuba": MitsubaRenderer,
                                        "closed-form": ClosedFormRenderer, "auto": AutoRenderer}  # fmt: skip
#: Renderers whose scenes are scene files (``scenes/``): the generator's format.
SCENE_FILE_RENDERERS = ("mitsuba", "closed-form", "auto")
