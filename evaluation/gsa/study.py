"""Global sensitivity analysis: continuous inputs, a sampled design, the sweep engine, SALib's indices.

A GSA file (``docs/global-sensitivity.md``) is a sweep file without ``axes``
and ``profiles`` and with four more keys: ``inputs`` (name -> distribution),
``designs`` (name -> ``{method: sobol | morris, n, seed, ...}``), ``noise``
(the camera noise that ``noise.FIELD`` inputs vary) and ``metrics`` (the
result columns analysed). Each design is sampled
by SALib (:func:`sample`), each sample is turned into one configuration of an
ordinary sweep (:func:`load_study`: one :func:`~nearlight.evaluation.engine.sweep.load_sweep`
per sample, so every scene key is applied and checked exactly as in a sweep),
the configurations run on the sweep engine (cached, resumable, on Dask), and
the rows are analysed by SALib in sample order (:func:`analyse`).

What an input may drive, by its name:

- a built-in axis taking a number: ``lamp_distance``, ``roughness``,
  ``range_noise`` (applied by the renderer's ``apply_axis`` and the engine,
  as in a sweep), or one taking labels: ``bsdf``, ``object``,
  ``polarization``, ``analyzer_angles``, ``realism``;
- ``noise.FIELD``: one field of the camera noise (``full_well``,
  ``read_noise``, ``bits``), the others from the file's ``noise``;
- ``viewing_angle`` (deg from the object's normal) and ``camera_distance``
  (m from ``camera.look_at``), Mitsuba scenes: the camera is moved in the
  plane of the normal and its base position (:func:`camera_position`);
- any dotted scene key taking a number (``lamp.radius``,
  ``nuisances.analyzer.jitter_deg``).

Identical configurations (a Morris trajectory may revisit a grid point) are
one task: each sample keeps the ids of its tasks. A sample whose row failed
or whose metric is not finite drops its whole block (a Morris trajectory, or
the ``k + 2`` rows of one Saltelli base sample): the estimators average over
blocks, so the indices stay unbiased over fewer blocks (the report says how
many were used).

A Sobol' design may have ``replicates``: independently scrambled Saltelli
samples of ``n`` base samples each, seeds ``seed``, ``seed + 1``, … (randomised
quasi-Monte Carlo replicates, Owen 1997). Each runs as a sweep of its own in
``seed-<s>/`` of the design's results folder, so adding a replicate to a
finished study runs only the new one; the indices pool every replicate's blocks
(N = replicates · n), and the report shows each replicate alone beside the
pooled indices: the same study under another scrambling seed.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from ...errors import UserError
from ...files.dotted import set_dotted
from ...files.schema import validate
from ...files.yamlfile import load_yaml_mapping
from ..engine.renderers import SCENE_FILE_RENDERERS
from ..engine.sweep import Sweep, SweepFile, axis_label, load_sweep
from ..scoring.metrics import ESTIMATE_COLUMNS, METRICS

#: Built-in axes an input may drive with a number (as the sweep axis of that name).
NUMBER_AXES = ("lamp_distance", "roughness", "range_noise")
#: Built-in axes an input may drive with a list of labels (a categorical input).
LABEL_AXES = ("bsdf", "object", "polarization", "analyzer_angles", "realism")
#: Inputs that move the camera (Mitsuba scenes): :func:`camera_position`.
CAMERA_INPUTS = ("viewing_angle", "camera_distance")
#: Distributions of a numeric input: SALib's name for each.
DISTRIBUTIONS = {"uniform": "unif", "loguniform": "logunif", "normal": "norm"}
#: The columns of a Sobol' design's indices (:func:`analyse`).
SOBOL_COLUMNS = ("S1", "S1_conf", "S1_lo", "S1_hi", "S1_floor", "ST", "ST_conf", "ST_lo", "ST_hi", "ST_floor")
#: The output "did the method give no answer?": 1 where a task's row is not ``ok`` (the estimate broke a sanity rule,
#: status ``failed``, or the method stopped with its one-line reason, status ``error``: "E_p(t) has no minimum before
#: t_max", "2 separate highlights"), 0 where it answered; the failures the sweep reports and ``compare`` count. A
#: study can ask which inputs make a method fail; the metrics' Morris steps lose both ends of every failure.
FAILED = "failed"
#: Metrics analysed when the file names none (columns of the result rows).
DEFAULT_METRICS = ("lamp_position_error_m", "sigma_rel_error", "ks_rel_error")


class _Input(BaseModel):
    model_config = ConfigDict(extra="forbid")
    dist: Literal["uniform", "loguniform", "normal", "labels"] | None = None
    low: float | None = None
    high: float | None = None
    mean: float | None = None
    sd: float | None = None
    values: list[Any] | dict[str, Any] | None = None

    @model_validator(mode="after")
    def _shape(self) -> "_Input":
        if self.dist is None:
            self.dist = "labels" if self.values is not None else "normal" if self.mean is not None else "uniform"
        if self.dist == "labels":
            if not self.values or len(self.values) < 2:
                raise ValueError("expected values: a list (or mapping) of at least 2 labels")
        elif self.dist == "normal":
            if self.mean is None or self.sd is None or not self.sd > 0:
                raise ValueError("a normal input needs mean and sd > 0")
        else:
            if self.low is None or self.high is None or not self.low < self.high:
                raise ValueError(f"a {self.dist} input needs low < high")
            if self.dist == "loguniform" and not self.low > 0:
                raise ValueError("a loguniform input needs low > 0")
        return self


class _Design(BaseModel):
    model_config = ConfigDict(extra="forbid")
    method: Literal["sobol", "morris"]
    n: int = Field(ge=1)
    seed: int = Field(default=0, ge=0)
    levels: int = Field(default=4, ge=2)
    resamples: int = Field(default=1000, ge=10)
    conf_level: float = Field(default=0.95, gt=0, lt=1)
    methods: list[str] | None = None
    replicates: int = Field(default=1, ge=1)

    @model_validator(mode="after")
    def _power_of_two(self) -> "_Design":
        if self.method == "sobol" and self.n & (self.n - 1):
            raise ValueError(f"a sobol design needs n a power of 2 (Sobol' points keep their balance only then), got {self.n}")
        if self.method == "morris" and self.replicates > 1:
            raise ValueError("replicates: a morris design has none (more trajectories are a larger n)")
        return self


class _GSAFile(SweepFile):
    """A sweep file's keys (one schema: :class:`~nearlight.evaluation.engine.sweep.SweepFile`) without its grid,
    ``axes`` and ``profiles``, plus the GSA's own."""

    methods: list[Any] = Field(min_length=1)  # passed on to load_sweep as written, which checks them
    noise: dict[str, Any] | None = None
    metrics: list[str] = Field(default_factory=lambda: list(DEFAULT_METRICS), min_length=1)
    inputs: dict[str, _Input] = Field(min_length=2)
    designs: dict[str, _Design] = Field(min_length=1)

    @field_validator("axes", "profiles")
    @classmethod
    def _no_grid(cls, v: dict, info: ValidationInfo) -> dict:
        if v:
            raise ValueError(f"a GSA file has `inputs` and `designs` instead of a sweep's {info.field_name}")
        return v


@dataclasses.dataclass(frozen=True)
class Input:
    """One input of a study: what it drives and its distribution.

    Attributes
    ----------
    name : str
        What it drives (see the module docstring).
    dist : {"uniform", "loguniform", "normal", "labels"}
    bounds : tuple of float
        SALib's bounds: ``(low, high)``, ``(mean, sd)`` for ``normal``,
        ``(0, n)`` for ``n`` labels (a sample ``u`` picks label ``floor(u)``).
    labels : list of (label, value) or None
        The labels of a categorical input, in order.
    """

    name: str
    dist: str
    bounds: tuple[float, float]
    labels: list[tuple[Any, Any]] | None = None

    def value(self, x: float) -> Any:
        """The value a sample ``x`` (SALib's, in the input's units) gives the input."""
        if self.labels is None:
            return float(x)
        return self.labels[min(int(math.floor(x)), len(self.labels) - 1)][1]

    def label(self, x: float) -> Any:
        """The table value of sample ``x``: the number, or the label of a categorical input."""
        if self.labels is None:
            return float(x)
        return self.labels[min(int(math.floor(x)), len(self.labels) - 1)][0]


@dataclasses.dataclass(frozen=True)
class Design:
    """A sampling design: SALib's ``method`` with base sample count ``n`` (Saltelli's N, or the number
    of Morris trajectories), its seed, Morris's grid ``levels``, the bootstrap ``resamples`` and
    confidence level, the methods it runs (None: all) and its Sobol' ``replicates`` (samples of ``n``
    each, seeds ``seed``, ``seed + 1``, …; module docstring). Sobol' designs are first-order and total
    indices only: second order would cost ``n·(2k + 2)`` runs instead of ``n·(k + 2)``, and ``ST − S1``
    already shows how much of an input's share is interaction."""

    name: str
    method: str
    n: int
    seed: int = 0
    levels: int = 4
    resamples: int = 1000
    conf_level: float = 0.95
    methods: tuple[str, ...] | None = None
    replicates: int = 1

    @property
    def seeds(self) -> tuple[int, ...]:
        """The seed of each replicate."""
        return tuple(range(self.seed, self.seed + self.replicates))

    @property
    def blocks(self) -> int:
        """Independent blocks of the whole design: ``n`` per replicate."""
        return self.n * self.replicates

    def block(self, k: int) -> int:
        """Rows of one independent block of the sample (a Morris trajectory, a Saltelli base sample)."""
        if self.method == "morris":
            return k + 1
        return k + 2


@dataclasses.dataclass(frozen=True)
class Replicate:
    """One replicate of a design: its seed, its results folder and its sweep.

    Attributes
    ----------
    seed : int
    folder : str
        Its results folder, relative to the design's (``"."``: a design of one replicate runs there).
    sweep : Sweep
        Its sampled configurations as one sweep (identical tasks once).
    """

    seed: int
    folder: str
    sweep: Sweep


@dataclasses.dataclass(frozen=True)
class DesignRun:
    """One design of a study, ready to run.

    Attributes
    ----------
    design : Design
    samples : ndarray, shape (n_samples, k)
        SALib's sample, in the inputs' units (categorical: ``[0, n)``); the replicates' one after the other.
    replicates : tuple of Replicate
        One sweep per replicate (one for a Morris design).
    sample_tasks : list of dict
        Per sample, method label -> the ids of its tasks (one per seed that matters).
    """

    design: Design
    samples: np.ndarray
    replicates: tuple[Replicate, ...]
    sample_tasks: list[dict[str, list[str]]]

    @property
    def sweep(self) -> Sweep:
        """The first replicate's sweep (every replicate's has the same methods and renderer)."""
        return self.replicates[0].sweep

    @property
    def tasks(self) -> int:
        """Tasks of every replicate."""
        return sum(len(r.sweep.tasks) for r in self.replicates)


@dataclasses.dataclass(frozen=True)
class Study:
    """A validated GSA file: its name, source, inputs, metrics and the designs to run."""

    name: str
    source: str
    inputs: list[Input]
    metrics: list[str]
    runs: dict[str, DesignRun]


def problem(inputs: list[Input]) -> dict[str, Any]:
    """SALib's problem definition of ``inputs`` (names, bounds, distributions)."""
    return {
        "num_vars": len(inputs),
        "names": [i.name for i in inputs],
        "bounds": [list(i.bounds) for i in inputs],
        "dists": ["unif" if i.dist == "labels" else DISTRIBUTIONS[i.dist] for i in inputs],
    }


def sample(inputs: list[Input], design: Design, seed: int | None = None) -> np.ndarray:
    """SALib's sample of ``design`` over ``inputs`` (with ``seed``, one replicate's; default the design's).

    Returns
    -------
    ndarray, shape (n_samples, k)
        ``sobol``: Saltelli's scheme (:func:`SALib.sample.sobol.sample`, scrambled),
        ``n`` blocks of ``k + 2`` rows; ``n`` a power of 2.
        ``morris``: ``n`` trajectories of ``k + 1`` rows on a ``levels`` grid
        (:func:`SALib.sample.morris.sample`).
    """
    from SALib.sample import morris, sobol

    prob = problem(inputs)
    seed = design.seed if seed is None else seed
    if design.method == "sobol":
        return sobol.sample(prob, design.n, calc_second_order=False, seed=seed)
    return morris.sample(prob, design.n, num_levels=design.levels, seed=seed)


def analyse(inputs: list[Input], design: Design, X: np.ndarray, Y: np.ndarray) -> tuple[list[dict[str, Any]], int]:
    """The indices of the outputs ``Y`` of the sample ``X``: Sobol' after dropping blocks with a non-finite output,
    Morris step by step (:mod:`nearlight.evaluation.gsa.morris`: a step with a non-finite end is left out).

    Parameters
    ----------
    inputs : list of Input
    design : Design
    X : ndarray, shape (n_samples, k)
        The sample (:func:`sample`), in its order.
    Y : ndarray, shape (n_samples,)
        The output of each sample (NaN: failed).

    Returns
    -------
    rows : list of dict
        One per input: ``input`` and, for ``sobol``, :data:`SOBOL_COLUMNS`
        (:func:`nearlight.evaluation.gsa.sobol.sobol_indices`: each index, its
        percentile bootstrap interval ``_lo`` … ``_hi`` at ``design.conf_level``
        and its half-width ``_conf``, and the chance floor ``_floor``, the same
        for every input); for ``morris``, ``mu``, ``mu_star``,
        ``mu_star_conf``, ``sigma`` (in the output's units per unit of the
        input's range: SALib's elementary effects on the unit hypercube) and
        ``steps`` (the input's steps with both ends answered; NaN indices
        below 2). Sobol': all NaN when fewer than 2 blocks are left or the
        outputs do not vary.
    blocks : int
        Blocks with every output finite (of ``len(X) / design.block(k)``): Sobol' analyses these only.
    """
    from .morris import morris_indices
    from .sobol import sobol_indices

    k = len(inputs)
    size = design.block(k)
    Y = np.asarray(Y, dtype=float)
    keep = np.isfinite(Y.reshape(-1, size)).all(axis=1)
    names = [i.name for i in inputs]
    if design.method == "sobol":
        keys = SOBOL_COLUMNS
        if keep.sum() < 2 or np.var(Y[np.repeat(keep, size)]) == 0:
            return [{"input": n, **dict.fromkeys(keys, math.nan)} for n in names], int(keep.sum())
        res = sobol_indices(Y[np.repeat(keep, size)], k, resamples=design.resamples, conf_level=design.conf_level,
                            seed=design.seed)  # fmt: skip
        res = {key: np.broadcast_to(res[key], (k,)) for key in keys}
    else:
        keys = ("mu", "mu_star", "mu_star_conf", "sigma", "steps")
        res = morris_indices(X, Y, design.levels, resamples=design.resamples, conf_level=design.conf_level,
                             seed=design.seed)  # fmt: skip
    return [{"input": n, **{key: float(res[key][j]) for key in keys}} for j, n in enumerate(names)], int(keep.sum())


def camera_position(scene: Mapping[str, Any], *, viewing_angle: float | None, camera_distance: float | None) -> list[float]:
    """Where the camera of a Mitsuba scene sits for a viewing angle and distance.

    The camera stays in the plane of the object's normal ``n`` (local +z of
    its placement, :func:`nearlight.generator.scene.placement`) and its base
    position, on the same side: ``look_at + d·(cos θ·n + sin θ·u)``, ``u``
    the unit part of the base camera ray perpendicular to ``n``.

    Parameters
    ----------
    scene : mapping
        The scene (``camera.position``, ``camera.look_at``, ``object``).
    viewing_angle : float or None
        θ, degrees from the normal; None keeps the base camera's.
    camera_distance : float or None
        d, metres from ``camera.look_at``; None keeps the base camera's.

    Returns
    -------
    list of float, shape (3,)
    """
    from ...generator import load_scene
    from ...generator.scene import placement

    parsed = load_scene(dict(scene))
    n = placement(parsed.object)[:3, 2]
    n = n / np.linalg.norm(n)
    look_at = np.asarray(parsed.camera.look_at, dtype=float)
    ray = np.asarray(parsed.camera.position, dtype=float) - look_at
    perp = ray - np.dot(ray, n) * n
    if np.linalg.norm(perp) < 1e-12 * np.linalg.norm(ray):
        raise UserError("viewing_angle: the base camera looks along the object's normal: no plane to tilt it in "
                        "(move camera.position off the normal)")  # fmt: skip
    u = perp / np.linalg.norm(perp)
    theta = math.atan2(float(np.dot(ray, u)), float(np.dot(ray, n))) if viewing_angle is None else math.radians(viewing_angle)
    d = float(np.linalg.norm(ray)) if camera_distance is None else float(camera_distance)
    return (look_at + d * (math.cos(theta) * n + math.sin(theta) * u)).tolist()


def _inputs(path: str, spec: _GSAFile) -> list[Input]:
    out = []
    for name, inp in spec.inputs.items():
        where = f"{path}: inputs.{name}"
        is_labels = inp.dist == "labels"
        if name in LABEL_AXES and not is_labels:
            raise UserError(f"{where}: the {name} axis takes labels: give values: [...]")
        if name not in LABEL_AXES and "." not in name and name not in NUMBER_AXES + CAMERA_INPUTS:
            raise UserError(f"{where}: unknown input (expected one of {', '.join(NUMBER_AXES + LABEL_AXES + CAMERA_INPUTS)}, "
                            "noise.FIELD or a dotted scene key)")  # fmt: skip
        if name.startswith("noise.") and spec.noise is None:
            raise UserError(f"{where}: needs the file's noise (the camera noise whose field it varies)")
        if name in CAMERA_INPUTS and spec.renderer not in SCENE_FILE_RENDERERS:
            raise UserError(f"{where}: moves the camera of a Mitsuba scene; with renderer: analytic, "
                            "drive camera_position as a dotted key")  # fmt: skip
        if is_labels:
            values = inp.values
            items = list(values.items()) if isinstance(values, dict) else [(axis_label(v), v) for v in values]
            out.append(Input(name, "labels", (0.0, float(len(items))), items))
        elif inp.dist == "normal":
            out.append(Input(name, "normal", (float(inp.mean), float(inp.sd))))
        else:
            out.append(Input(name, inp.dist, (float(inp.low), float(inp.high))))
    return out


def _sample_doc(base: dict[str, Any], spec: _GSAFile, inputs: list[Input], x: np.ndarray, base_scene: dict) -> dict:
    """The sweep file (a mapping) of one sample: one value per axis, so one configuration."""
    axes: dict[str, Any] = {}
    noise = copy.deepcopy(spec.noise)
    camera: dict[str, float] = {}
    for inp, xi in zip(inputs, x):
        value = inp.value(xi)
        if inp.name.startswith("noise."):
            noise[inp.name.partition(".")[2]] = value
        elif inp.name in CAMERA_INPUTS:
            camera[inp.name] = value
        elif inp.labels is not None:
            axes[inp.name] = {str(inp.label(xi)): value}
        else:
            axes[inp.name] = [value]
    if camera:
        axes["camera.position"] = [camera_position(base_scene, viewing_angle=camera.get("viewing_angle"),
                                                   camera_distance=camera.get("camera_distance"))]  # fmt: skip
    if noise is not None:
        axes["noise"] = [noise]
    return {**base, "axes": axes}


def load_study(source: str | Path, *, settings: Mapping[str, Any] = (), design: str | None = None) -> Study:
    """Read a GSA file, sample each design with SALib and expand each sample into sweep tasks.

    Parameters
    ----------
    source : path-like
        The GSA file (YAML).
    settings : mapping, optional
        ``{dotted.key: value}`` applied to the file first (``--set``, e.g.
        ``{"designs.screening.n": 2}`` for a trial run).
    design : str, optional
        Only this design (default: every design of the file).

    Returns
    -------
    Study

    Raises
    ------
    UserError
        One line naming the file and key.
    """
    p = Path(source)
    path = str(p)
    doc = load_yaml_mapping(p, what="GSA file", keys="name, scene, inputs, designs, methods")
    for key, value in dict(settings).items():
        set_dotted(doc, key, value, where=f"--set {key}")
    spec = validate(_GSAFile, doc, where=path)
    inputs = _inputs(path, spec)

    for name in spec.metrics:
        if name not in (*METRICS, *ESTIMATE_COLUMNS, FAILED):
            raise UserError(f"{path}: metrics: unknown metric {name!r} (expected one of {', '.join(METRICS)}, "
                            f"or {FAILED})")  # fmt: skip
    if design is not None and design not in spec.designs:
        raise UserError(f"--design {design}: not a design of {path} (it has {', '.join(spec.designs)})")

    scene = spec.scene
    if isinstance(scene, str) and not Path(scene).is_absolute():
        scene = str(p.parent / scene)
    base = {"name": spec.name, "description": spec.description, "renderer": spec.renderer, "scene": scene,
            "set": spec.set, "seeds": spec.seeds, "crlb": spec.crlb}  # fmt: skip
    base_scene = load_sweep({**base, "methods": spec.methods}, check_methods=True).tasks[0].scene  # no axes: one
    runs = {}
    for name, d in spec.designs.items():
        if design is not None and name != design:
            continue
        dz = Design(name=name, **{**d.model_dump(), "methods": tuple(d.methods) if d.methods else None})
        for inp in inputs:  # Morris's grid of `levels` points meets n labels equally often iff n divides it
            if dz.method == "morris" and inp.labels is not None and dz.levels % len(inp.labels):
                raise UserError(f"{path}: designs.{name}.levels: {dz.levels} is not a multiple of the "
                                f"{len(inp.labels)} labels of input {inp.name} (its labels would not be equally likely)")  # fmt: skip
        methods = _methods(path, name, spec.methods, dz.methods)
        parts = [_expand(path, {**base, "name": f"{spec.name}-{name}", "methods": methods}, spec, inputs, dz, seed,
                         base_scene) for seed in dz.seeds]  # fmt: skip
        runs[name] = DesignRun(dz, np.concatenate([p[0] for p in parts]), tuple(p[1] for p in parts),
                               [ids for p in parts for ids in p[2]])  # fmt: skip
    return Study(spec.name, path, inputs, list(spec.metrics), runs)


def _methods(path: str, design: str, methods: list[Any], chosen: tuple[str, ...] | None) -> list[Any]:
    """The file's methods that design ``design`` runs (``chosen``: their labels; None: all)."""
    if chosen is None:
        return methods
    label = {(m if isinstance(m, str) else m.get("name") or m.get("method")): m for m in methods}
    for name in chosen:
        if name not in label:
            raise UserError(f"{path}: designs.{design}.methods: {name!r} is not a method of the file "
                            f"(it has {', '.join(label)})")  # fmt: skip
    return [label[name] for name in chosen]


def _expand(path: str, base: dict, spec: _GSAFile, inputs: list[Input], design: Design, seed: int,
            base_scene: dict) -> tuple[np.ndarray, Replicate, list[dict[str, list[str]]]]:  # fmt: skip
    """One replicate's sample (seed ``seed``), its sweep (a sweep per sample, their tasks merged, identical tasks
    once) and the task ids of each sample."""
    X = sample(inputs, design, seed)
    tasks: list = []
    seen: set[str] = set()
    axes: dict[str, dict[str, Any]] = {}
    sample_tasks: list[dict[str, list[str]]] = []
    first = None
    for i, x in enumerate(X):
        try:
            one = load_sweep(_sample_doc(base, spec, inputs, x, base_scene), check_methods=False)
        except UserError as exc:
            raise UserError(f"{path}: designs.{design.name}: {_which(design, seed)}sample {i} ({_describe(inputs, x)}): "
                            f"{str(exc).removeprefix('<sweep>: ')}") from None
        first = first or one
        ids: dict[str, list[str]] = {}
        for t in one.tasks:
            ids.setdefault(t.method.label, []).append(t.task_id)
            if t.task_id not in seen:
                seen.add(t.task_id)
                tasks.append(dataclasses.replace(t, index=len(tasks)))
        for name, values in one.axes.items():
            for label, value in values:
                axes.setdefault(name, {}).setdefault(str(label), (label, value))
        sample_tasks.append(ids)
    name = base["name"] if design.replicates == 1 else f"{base['name']}-seed-{seed}"
    sweep = Sweep(name, path, first.renderer, {n: list(v.values()) for n, v in axes.items()}, first.seeds,
                  first.methods, tasks, first.crlb)  # fmt: skip
    folder = "." if design.replicates == 1 else f"seed-{seed}"
    return X, Replicate(seed, folder, sweep), sample_tasks


def _which(design: Design, seed: int) -> str:
    return "" if design.replicates == 1 else f"replicate seed {seed}: "


def _describe(inputs: list[Input], x: np.ndarray) -> str:
    return ", ".join(f"{i.name}={i.label(v)}" if i.labels else f"{i.name}={v:.4g}" for i, v in zip(inputs, x))


def outputs(run: DesignRun, results: Any, metric: str, method: str) -> np.ndarray:
    """The output of each sample of ``run`` for ``metric`` and ``method``: the mean over the sample's seeds.

    Parameters
    ----------
    run : DesignRun
    results : pandas.DataFrame
        The sweep's rows (``results.parquet``).
    metric : str
        A numeric column of the rows, or :data:`FAILED`.
    method : str
        A method label.

    Returns
    -------
    ndarray, shape (n_samples,)
        NaN where a task is missing, failed, or its metric is not finite (:data:`FAILED`: 0 where the method
        answered, 1 where it did not, NaN where the task is missing).
    """
    if metric == FAILED:
        values = (results.set_index("task_id")["status"] != "ok").astype(float).to_dict()
    else:
        values = results[results["status"] == "ok"].set_index("task_id")[metric].astype(float).to_dict()
    out = np.full(len(run.sample_tasks), math.nan)
    for i, ids in enumerate(run.sample_tasks):
        got = [values.get(t, math.nan) for t in ids.get(method, [])]
        if got and all(math.isfinite(v) for v in got):
            out[i] = float(np.mean(got))
    return out
