"""Sweep files: a base scene, axes with values, seeds and methods, expanded into tasks.

A sweep file (YAML) is validated with pydantic; every mistake is one
:class:`~nearlight.errors.UserError` line naming the file and key. The product
of the axes' values × seeds × methods is the task list, in a fixed order; each
task has a stable id (a hash of what it is), so a re-run finds the tasks already
done. Axes that change what is rendered make *physical configurations*; the
others (``noise``, ``range_noise``, the seed, the method) are applied after
rendering and share the render. A configuration without camera or range noise
is deterministic: it runs once, with the first seed (more seeds would repeat
the same numbers).

See ``docs/sweep-files.md`` for the keys; :data:`AXES` documents each axis.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ...errors import UserError
from ...estimator import load_method
from ...estimator.options import check_options
from ...files.schema import is_number, validate
from ...files.yamlfile import load_yaml_mapping
from ...files.digests import stable_hash
from ...files.dotted import set_dotted
from ...physics.reflectance import LOBES
from .renderers import RENDERERS, SCENE_FILE_RENDERERS, Renderer

#: Built-in axes: name -> (applied after rendering?, meaning).
AXES: dict[str, tuple[bool, str]] = {
    "object": (False, "object shape name (or a mapping merged into the object section)"),
    "bsdf": (False, "specular model: torrance_sparrow | ward (converted from the base material) | a material mapping"),
    "polarization": (False, "specular polarization mode: ideal | fresnel"),
    "roughness": (False, "Torrance-Sparrow sigma, rad; for ward sets alpha = sqrt(2)*roughness (same lobe width)"),
    "analyzer_angles": (False, "number K of analyzer angles, equally spaced over 180 deg (or an explicit list)"),
    "lamp_distance": (False, "lamp distance from the object centre, m, moving the lamp along that ray"),
    "noise": (True, "camera noise settings passed to the generator's add_camera_noise (null: none)"),
    "range_noise": (True, "Gaussian noise on the range image P, standard deviation in m (0: none)"),
    "set": (False, "one-at-a-time design: label -> {dotted.scene.key: value} applied to the scene ({}: the base scene)"),
}
#: Order in which physical axes are applied (bsdf before roughness, lamp distance last).
_APPLY_ORDER = ("object", "bsdf", "polarization", "roughness", "analyzer_angles")


class _Method(BaseModel):
    model_config = ConfigDict(extra="forbid")
    method: str
    name: str | None = None
    options: dict[str, Any] = Field(default_factory=dict)


class _Profile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    set: dict[str, Any] = Field(default_factory=dict)
    axes: dict[str, list[Any] | dict[str, Any]] = Field(default_factory=dict)


class SweepFile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    description: str = ""
    renderer: Literal["mitsuba", "closed-form", "auto", "analytic"] = "mitsuba"
    scene: str | dict[str, Any]
    set: dict[str, Any] = Field(default_factory=dict)
    axes: dict[str, list[Any] | dict[str, Any]] = Field(default_factory=dict)
    seeds: int | list[int] = 1
    methods: list[str | _Method] = Field(min_length=1)
    crlb: bool = True
    profiles: dict[str, _Profile] = Field(default_factory=dict)

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: int | list[int]) -> int | list[int]:
        if isinstance(v, int) and v < 1:
            raise ValueError("expected a positive count or a list of integers")
        if isinstance(v, list) and (not v or len(set(v)) != len(v)):
            raise ValueError("expected a non-empty list of distinct integers")
        if isinstance(v, list) and min(v) < 0:
            raise ValueError(f"expected seeds >= 0 (as capture.seed), got {min(v)}")
        return v


@dataclasses.dataclass(frozen=True)
class Method:
    """One estimator run: a label for the tables, the method spec, its options."""

    label: str
    method: str
    options: dict[str, Any]


@dataclasses.dataclass(frozen=True)
class Task:
    """One (configuration, seed, method): a row of the results.

    Attributes
    ----------
    index : int
        Position in the sweep's task order.
    task_id : str
        Stable hash of ``config``, ``seed`` and ``method``.
    config : dict
        Axis name -> table value (number or label), in axis order.
    scene : dict
        The full scene to render (renderer's format).
    render_key : str
        Hash of ``scene``: tasks with the same key share one render.
    noise : Any
        Camera noise settings, or None.
    range_noise : float
        Range-image noise standard deviation, metres.
    seed : int
    method : Method
    """

    index: int
    task_id: str
    config: dict[str, Any]
    scene: dict[str, Any]
    render_key: str
    noise: Any
    range_noise: float
    seed: int
    method: Method
    #: Whether the task's numbers depend on its seed: camera or range noise, or a
    #: per-shot rig nuisance (analyzer jitter, lamp flicker; :func:`seed_matters`).
    noisy: bool


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A validated sweep: its name, renderer, tasks and a hash of them (``profile``: the one applied, if any)."""

    name: str
    source: str
    renderer: Renderer
    axes: dict[str, list[tuple[Any, Any]]]
    seeds: list[int]
    methods: list[Method]
    tasks: list[Task]
    crlb: bool
    profile: str | None = None

    @property
    def sweep_hash(self) -> str:
        """Hash of the task list: results of one sweep never mix with another's."""
        return stable_hash([t.task_id for t in self.tasks])

    @property
    def render_keys(self) -> list[str]:
        """Distinct physical configurations, in task order."""
        return list(dict.fromkeys(t.render_key for t in self.tasks))


def load_sweep(
    source: str | Path | Mapping[str, Any], *, check_methods: bool = True, profile: str | None = None
) -> Sweep:
    """Read, validate and expand a sweep file.

    Parameters
    ----------
    source : path-like or mapping
        A YAML sweep file, or its content as a dict (then relative scene paths
        are resolved from the current directory).
    check_methods : bool, optional
        Resolve every method now (unknown built-ins and ``module:function``
        that cannot be imported are errors before anything runs).
    profile : str, optional
        A profile of the file's ``profiles``: its ``set`` is applied after the
        file's, its ``axes`` replace the values of those axes (a smaller run of
        the same experiment, e.g. ``quick``). None: the file as written.

    Returns
    -------
    Sweep

    Raises
    ------
    UserError
        One line naming the file and key.
    """
    if isinstance(source, Mapping):
        path, base_dir, doc = "<sweep>", Path.cwd(), dict(source)
    else:
        p = Path(source)
        path, base_dir = str(p), p.parent
        doc = load_yaml_mapping(p, what="sweep file", keys="name, scene, axes, seeds, methods")
    spec = validate(SweepFile, doc, where=path)

    sets, axis_values = _profiled(path, spec, profile)
    renderer = RENDERERS[spec.renderer]()
    base = renderer.load_base(spec.scene, base_dir=base_dir, where=f"{path}: scene")
    for (where, key), value in sets.items():
        set_dotted(base, key, value, where=f"{path}: {where}.{key}")

    axes = {name: _axis_values(path, name, values) for name, values in axis_values.items()}
    for name, values in axes.items():
        if name not in AXES and "." not in name and name != "realism":
            raise UserError(
                f"{path}: axes.{name}: unknown axis (expected one of {', '.join(AXES)} or a dotted scene key)"
            )
        if name == "set":
            _check_set_axis(renderer, base, path, axis_values[name])
        for label, value in values:
            _check_axis_value(path, name, label, value)

    methods = [_method(path, i, m, check_methods) for i, m in enumerate(spec.methods)]
    labels = [m.label for m in methods]
    if len(set(labels)) != len(labels):
        raise UserError(f"{path}: methods: duplicate method name {next(x for x in labels if labels.count(x) > 1)!r}")
    seeds = list(range(spec.seeds)) if isinstance(spec.seeds, int) else list(spec.seeds)

    tasks: list[Task] = []
    scenes: dict[tuple, tuple[dict, str]] = {}
    names = list(axes)
    for combo in itertools.product(*(axes[n] for n in names)):
        chosen = dict(zip(names, combo))
        phys = tuple((n, stable_hash(v[1])) for n, v in chosen.items() if not AXES.get(n, (False,))[0])
        if phys not in scenes:
            scene = _physical_scene(renderer, base, chosen, path)
            scenes[phys] = (scene, renderer.render_key(scene))
        scene, key = scenes[phys]
        config = {n: _column_value(label) for n, (label, _) in chosen.items()}
        noise = chosen["noise"][1] if "noise" in chosen else None
        range_noise = float(chosen["range_noise"][1]) if "range_noise" in chosen else 0.0
        noisy = seed_matters(renderer, scene, noise, range_noise)
        for seed in seeds if noisy else seeds[:1]:
            shot, shot_key = scene, key
            if renderer.renders_per_seed(scene):  # the seed moves the camera: a render per shot
                shot = copy.deepcopy(scene)
                set_dotted(shot, "capture.seed", seed, where=f"{path}: seeds")
                shot_key = renderer.render_key(shot)
            for m in methods:
                tid = stable_hash([spec.renderer, shot, noise, range_noise, seed, m.label, m.method, m.options])
                tasks.append(Task(len(tasks), tid, config, shot, shot_key, noise, range_noise, seed, m, noisy))
    return Sweep(spec.name, path, renderer, axes, seeds, methods, tasks, spec.crlb, profile)


def _profiled(path: str, spec: SweepFile, profile: str | None) -> tuple[dict[tuple[str, str], Any], dict[str, Any]]:
    """The ``set`` items (keyed by ``(where, key)``, in the order applied) and the axes, with ``profile`` applied.

    Every profile is checked, chosen or not: it may only change axes the file has.
    """
    for name, prof in spec.profiles.items():
        for axis in prof.axes:
            if axis not in spec.axes:
                raise UserError(f"{path}: profiles.{name}.axes.{axis}: not an axis of the sweep "
                                f"(a profile changes the values of the file's axes: {', '.join(spec.axes) or 'none'})")
    sets = {("set", k): v for k, v in spec.set.items()}
    if profile is None:
        return sets, dict(spec.axes)
    if profile not in spec.profiles:
        raise UserError(f"{path}: profiles: no profile {profile!r} (the file has {', '.join(spec.profiles) or 'none'})")
    chosen = spec.profiles[profile]
    sets.update({(f"profiles.{profile}.set", k): v for k, v in chosen.set.items()})
    return sets, {**spec.axes, **chosen.axes}


def _axis_values(path: str, name: str, values: list[Any] | dict[str, Any]) -> list[tuple[Any, Any]]:
    """``[(label, value)]``: a list's items label themselves; a mapping's keys are labels."""
    items = list(values.items()) if isinstance(values, dict) else [(axis_label(v), v) for v in values]
    if not items:
        raise UserError(f"{path}: axes.{name}: expected at least one value")
    labels = [str(lab) for lab, _ in items]
    if len(set(labels)) != len(labels):
        raise UserError(f"{path}: axes.{name}: duplicate value {next(x for x in labels if labels.count(x) > 1)!r}")
    kinds = {type(_column_value(lab)) for lab, _ in items}
    if len(kinds) > 1:  # one column type per axis: mixed numbers and labels become labels
        items = [(str(lab), v) for lab, v in items]
    return items


def axis_label(value: Any) -> Any:
    """How an axis value labels itself in the tables: itself when a number, string or bool, ``none`` for
    null, else its compact JSON."""
    if value is None:
        return "none"
    if isinstance(value, (bool, int, float, str)):
        return value
    return json.dumps(value, separators=(",", ":"), sort_keys=True)


def _column_value(label: Any) -> Any:
    return float(label) if isinstance(label, int) and not isinstance(label, bool) else label


def _check_axis_value(path: str, name: str, label: Any, value: Any) -> None:
    where = f"{path}: axes.{name}: {label!r}:"
    if name in ("lamp_distance", "roughness") and not (is_number(value) and value > 0):
        raise UserError(f"{where} expected a positive number")
    if name == "range_noise" and not (is_number(value) and value >= 0):
        raise UserError(f"{where} expected a number >= 0 (metres)")
    if name == "polarization" and value not in ("ideal", "fresnel"):
        raise UserError(f"{where} expected 'ideal' or 'fresnel'")
    if name == "analyzer_angles":
        ok = (isinstance(value, int) and not isinstance(value, bool) and value >= 3) or (
            isinstance(value, list) and len(value) >= 3 and all(is_number(a) for a in value)
        )
        if not ok:
            raise UserError(f"{where} expected an integer >= 3 or a list of >= 3 angles in degrees")
    if name == "noise":
        if not (value is None or isinstance(value, dict)):
            raise UserError(f"{where} expected null or a mapping of camera noise settings")
        if value is not None:
            from ...generator.scene import NoiseSpec

            try:
                NoiseSpec.model_validate(value)
            except ValidationError as exc:
                err = exc.errors()[0]
                raise UserError(f"{where} {'.'.join(map(str, err['loc']))}: {err['msg']}") from None
    if name == "bsdf" and not (isinstance(value, dict) or value in LOBES):
        raise UserError(f"{where} expected one of {', '.join(repr(m) for m in LOBES)} or a material mapping")


def _check_set_axis(renderer: Renderer, base: dict, path: str, labels: Any) -> None:
    """A ``set`` axis is ``{label: {dotted.key: value}}``; each label's scene must be one the renderer accepts,
    and no two labels may set the same (they would be one configuration under two names)."""
    if not isinstance(labels, dict):
        raise UserError(f"{path}: axes.set: expected a mapping of labels to mappings of dotted scene keys")
    seen: dict[str, str] = {}
    for label, overrides in labels.items():
        where = f"{path}: axes.set: {label!r}"
        if not isinstance(overrides, dict) or not all(isinstance(k, str) for k in overrides):
            raise UserError(f"{where}: expected a mapping of dotted scene keys")
        same = seen.setdefault(stable_hash(overrides), label)
        if same != label:
            raise UserError(f"{where}: the same keys and values as {same!r}")
        scene = copy.deepcopy(base)
        _apply_set(scene, label, overrides, path)
        renderer.validate(scene, where=where)


def _apply_set(scene: dict, label: Any, overrides: dict[str, Any], path: str) -> None:
    """Apply the overrides of label ``label`` of the ``set`` axis, as the dotted-key axes are applied."""
    for key, value in overrides.items():
        set_dotted(scene, key, copy.deepcopy(value), where=f"{path}: axes.set: {label!r}")


def seed_matters(renderer: Renderer, scene: dict, noise: Any, range_noise: float) -> bool:
    """Whether a configuration's captures change with the seed: camera or range noise, or (generator
    scenes) a per-shot rig nuisance of the scene or its ``realism`` profile (analyzer jitter, lamp flicker),
    or a camera that moves per shot (``camera.jitter_px``)."""
    if noise is not None or range_noise > 0 or renderer.renders_per_seed(scene):
        return True
    if renderer.name not in SCENE_FILE_RENDERERS:
        return False
    from ...generator.nuisances import draws_from_seed, nuisances_of

    return draws_from_seed(nuisances_of(scene)[1])


def _physical_scene(renderer: Renderer, base: dict, chosen: dict[str, tuple[Any, Any]], path: str) -> dict:
    scene = copy.deepcopy(base)
    for name in _APPLY_ORDER:
        if name in chosen:
            renderer.apply_axis(scene, name, chosen[name][1], where=f"{path}: axes.{name}")
    for name, (_, value) in chosen.items():
        if "." in name or name == "realism":
            set_dotted(scene, name, copy.deepcopy(value), where=f"{path}: axes.{name}")
    if "set" in chosen:
        _apply_set(scene, *chosen["set"], path)
    if "lamp_distance" in chosen:
        renderer.apply_axis(scene, "lamp_distance", chosen["lamp_distance"][1], where=f"{path}: axes.lamp_distance")
    renderer.validate(scene, where=f"{path}: scene")
    return scene


def _method(path: str, i: int, m: str | _Method, check: bool) -> Method:
    spec = _Method(method=m) if isinstance(m, str) else m
    if check:
        check_method(spec.method, spec.options, where=f"{path}: methods[{i}]")
    return Method(spec.name or spec.method, spec.method, dict(spec.options))


def check_method(method: str, options: Mapping[str, Any], *, where: str) -> None:
    """Raise :class:`UserError` unless ``method`` is a method nearlight can run with ``options``, before any work.

    ``method`` is a built-in name (:data:`nearlight.estimator.METHODS`), a
    method of an extra (:data:`nearlight.estimator.api.EXTRA_METHODS`) or a
    plug-in's ``module:function`` (imported now); ``options`` are checked
    against the options its signature declares
    (:func:`nearlight.estimator.options.check_options`). Every message starts
    with ``where`` (a sweep file's ``methods[i]``, the ``--method`` option).
    """
    try:
        check_options(load_method(method), dict(options), method=method)
    except UserError as exc:
        raise UserError(f"{where}: {exc}") from None
