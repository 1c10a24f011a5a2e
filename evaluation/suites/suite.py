"""Benchmark suites: a frozen, versioned set of captures with a manifest of checksums.

A *suite file* (``suites/core-v1.yaml``) is a sweep file ([sweep files](../docs/sweep-files.md))
without ``methods`` plus three keys of its own: ``version`` (an integer), ``categories``
(what a scorecard reports per value; default every axis) and ``cases_hash`` (the
pin: the hash of its list of cases, so a changed definition is refused until it gets a
new name, never an edit). Its *cases* are the sweep's tasks without the method: one
per configuration and seed.

A suite of several scenes with their own cameras (``suites/paper-v1.yaml``) lists them as
``parts``: each part a named sweep (``name``, ``scene``, and its own ``set``, ``axes``,
``seeds``), the suite's top-level ``set``, ``axes`` and ``seeds`` shared by every part. Its
cases are the parts' cases in order, numbered across them; each case's categories name its
part (``part``). A suite without ``parts`` is one unnamed part: one code path builds both.

``nearlight suite build`` renders each case once and writes the built suite, a folder
any plain install reads (no renderer on the score path)::

    DIR/manifest.json                  suite, version, versions, tolerance, per case:
                                       path, categories, sha256 of each file, digests
    DIR/cases/NNN/input/capture.*      what the method sees: the observed capture
                                       (noise, nuisances), without truth
    DIR/cases/NNN/truth/capture.*      the noise-free render with its truth, to score

``nearlight suite verify`` checks every file's sha256 against the manifest and, with
``--against``, compares two builds: files that differ must agree within the
manifest's tolerance on their *digests* (block means of every image layer,
:func:`image_digest`). The protocol and the tolerance: docs/benchmark-suites.md.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
import os
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StrictBool, StrictInt, field_validator

from ... import __version__
from ...capture import read_capture, write_capture
from ...errors import UserError, one_line
from ...files.atomic import write_json
from ...files.digests import file_sha256, stable_hash
from ...files.jsonable import jsonable
from ...files.outputs import CAPTURE_FILES, check_folder, is_capture_dir
from ...files.schema import check_name, check_relative, inside, validate
from ...files.yamlfile import load_yaml_mapping
from ..engine.environment import code_version, collect
from ..engine.run import task_payload
from ..engine.sweep import load_sweep
from ..engine.tasks import noisy_capture
from ..engine.workers import completed, executing

#: The manifest's ``format``.
FORMAT = "nearlight-suite/1"
MANIFEST = "manifest.json"
#: The lock a build holds in its folder (two builds into one folder at once are refused).
LOCK = ".build.lock"
CASES = "cases"
#: Sub-folders of a case: the capture a method sees, and the noise-free capture with the truth.
INPUT, TRUTH = "input", "truth"
#: Keys of a suite file that are not sweep-file keys.
SUITE_KEYS = ("version", "categories", "cases_hash")
#: Keys of a suite file with ``parts``, besides :data:`SUITE_KEYS` (``set``, ``axes``, ``seeds``: shared by
#: every part), and the keys of one part.
PARTS_SUITE_KEYS = ("name", "description", "renderer", "set", "axes", "seeds", "parts")
PART_KEYS = ("name", "scene", "set", "axes", "seeds")
#: The category that names a case's part (in a suite with ``parts``).
PART = "part"
#: Image digests: block means over a DIGEST_GRID x DIGEST_GRID grid of each layer (rows x columns).
DIGEST_GRID = 4
#: Two builds agree on a layer when every block mean differs by at most DIGEST_RTOL times the layer's
#: largest |block mean| (docs/benchmark-suites.md, "Tolerance": float32 last-bit differences between
#: CPUs average out over a block; a silhouette pixel that flips moves a 40x30-pixel block of a 160x120
#: image by at most 1/1200 of its value, about this much for a layer near its peak).
DIGEST_RTOL = 1e-3


@dataclasses.dataclass(frozen=True)
class Case:
    """One capture of a suite: a configuration and seed of one of its parts.

    Attributes
    ----------
    index : int
        Position in the suite, numbered across its parts.
    case_id : str
        Hash of the renderer, scene, noise, range noise and seed, and of the part's name in a suite
        with ``parts`` (stable across machines).
    categories : dict
        ``part`` (its part's name, in a suite with ``parts``), then axis name -> table value (the
        sweep's ``config``).
    task : Task
        The sweep task it came from (its method is not used).
    sweep : Sweep
        Its part's sweep.
    """

    index: int
    case_id: str
    categories: dict[str, Any]
    task: Any
    sweep: Any

    @property
    def path(self) -> str:
        """Folder of the case inside a built suite, relative to it."""
        return f"{CASES}/{self.index:03d}"


@dataclasses.dataclass(frozen=True)
class Suite:
    """A validated suite file: name, version, categories, its parts' sweeps, its cases and their hash.

    ``parts`` maps each part's name to its sweep, in file order; a suite file without ``parts`` has one,
    named None.
    """

    name: str
    version: int
    description: str
    source: str
    categories: list[str]
    parts: dict[str | None, Any]
    cases: list[Case]
    pinned: str | None

    @property
    def cases_hash(self) -> str:
        """Hash of the case ids, in order: the suite's identity."""
        return stable_hash([c.case_id for c in self.cases])

    @property
    def renderer(self) -> Any:
        """The renderer of every part (a suite has one)."""
        return next(iter(self.parts.values())).renderer

    @property
    def render_keys(self) -> list[str]:
        """Distinct physical configurations over all parts, in case order."""
        return list(dict.fromkeys(c.task.render_key for c in self.cases))


def load_suite(path: str | Path, *, check_pin: bool = True) -> Suite:
    """Read a suite file.

    Parameters
    ----------
    path : path-like
        ``suites/NAME.yaml``: sweep keys (no ``methods``) plus ``version``, ``categories``,
        ``cases_hash``; or, for several scenes, ``parts`` (a list of ``{name, scene, set, axes,
        seeds}``) with the shared ``renderer``, ``set``, ``axes``, ``seeds`` at the top level.
    check_pin : bool, optional
        Refuse a file whose cases do not hash to its ``cases_hash`` (a changed definition).

    Raises
    ------
    UserError
        One line naming the file and key.
    """
    p = Path(path)
    doc = load_yaml_mapping(p, what="suite file", keys="name, version, scene, axes, seeds")
    if "methods" in doc:
        raise UserError(f"{p}: methods: a suite has no methods (`nearlight score` names the method)")
    version, categories, pinned = (doc.pop(k, None) for k in SUITE_KEYS)
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise UserError(f"{p}: version: expected a positive integer, got {version!r}")
    name = doc.get("name")
    if not isinstance(name, str) or not name.strip():
        raise UserError(f"{p}: name: expected the suite's name (a non-empty string), got {name!r}")
    parts = {None: _part_sweep(p, doc, None)} if "parts" not in doc else _part_sweeps(p, doc)
    cases: list[Case] = []
    seen: dict[str, int] = {}
    for part, sweep in parts.items():
        for t in sweep.tasks:
            cid = stable_hash([sweep.renderer.name, t.scene, t.noise, t.range_noise, t.seed, *([part] if part else [])])
            if cid in seen:
                raise UserError(f"{p}: {'' if part is None else f'parts.{part}: '}case {len(cases)} ({t.config}) is the "
                                f"same capture as case {seen[cid]}: give each case its own configuration")  # fmt: skip
            seen[cid] = len(cases)
            cases.append(Case(len(cases), cid, {**({PART: part} if part else {}), **t.config}, t, sweep))
    columns = [*([PART] if None not in parts else []), *dict.fromkeys(a for s in parts.values() for a in s.axes)]
    for col in columns:  # a column holds one kind of value (a results table stores it as one type)
        kinds = {type(c.categories[col]).__name__ for c in cases if col in c.categories}
        if len(kinds) > 1:
            raise UserError(f"{p}: axes.{col}: its parts give it values of different kinds ({', '.join(sorted(kinds))}); "
                            f"label them alike (e.g. all as strings)")  # fmt: skip
    if categories is None:
        categories = columns
    if not isinstance(categories, list) or any(c not in columns for c in categories):
        raise UserError(f"{p}: categories: expected a list of the suite's axes ({', '.join(columns)}), got {categories!r}")
    suite = Suite(name, version, str(doc.get("description", "")).strip(), str(p), categories, parts, cases,
                  None if pinned is None else str(pinned))  # fmt: skip
    if check_pin and suite.pinned != suite.cases_hash:
        raise UserError(
            f"{p}: cases_hash: the cases hash to {suite.cases_hash}, the file pins {suite.pinned}; a built suite is "
            f"frozen: give a changed definition a new name and version (then pin cases_hash: {suite.cases_hash})"
        )
    return suite


def _part_sweep(path: Path, doc: Mapping[str, Any], part: str | None) -> Any:
    """The sweep of one part (``doc``: sweep keys without ``methods``), errors naming ``path`` and the part."""
    doc = dict(doc)
    if isinstance(doc.get("scene"), str):  # a scene file is relative to the suite file
        doc["scene"] = str(path.parent / doc["scene"])
    try:
        sweep = load_sweep({**doc, "methods": ["full"], "crlb": False}, check_methods=False)
    except UserError as exc:  # load_sweep names a mapping "<sweep>": name the file (and part) instead
        msg = str(exc)
        where = f"{path}: " + ("" if part is None else f"parts.{part}.")
        raise UserError(where + msg.removeprefix("<sweep>: ") if msg.startswith("<sweep>: ") else msg) from None
    return dataclasses.replace(sweep, source=str(path))


def _part_sweeps(path: Path, doc: Mapping[str, Any]) -> dict[str | None, Any]:
    """Part name -> sweep of a suite file with ``parts``: each part's keys over the shared ones (``set``
    and ``axes`` merged, the part's value winning for a key both name; ``seeds`` the part's if given)."""
    extra = sorted(set(doc) - set(PARTS_SUITE_KEYS))
    if extra:
        raise UserError(f"{path}: {extra[0]}: not a key of a suite with parts (expected {', '.join(PARTS_SUITE_KEYS)}; "
                        f"each part has its own scene)")  # fmt: skip
    parts = doc["parts"]
    if not isinstance(parts, list) or not parts:
        raise UserError(f"{path}: parts: expected a non-empty list of parts ({{name, scene, set, axes, seeds}})")
    shared = {k: doc[k] for k in ("set", "axes") if k in doc}
    for key, value in shared.items():
        if not isinstance(value, dict):
            raise UserError(f"{path}: {key}: expected a mapping, got {value!r}")
    out: dict[str | None, Any] = {}
    for i, part in enumerate(parts):
        if not isinstance(part, dict) or not isinstance(part.get("name"), str) or not part["name"].strip():
            raise UserError(f"{path}: parts[{i}]: expected a mapping with a name (a non-empty string)")
        name = part["name"]
        if name in out:
            raise UserError(f"{path}: parts[{i}].name: {name!r} names two parts")
        bad = sorted(set(part) - set(PART_KEYS))
        if bad:
            raise UserError(f"{path}: parts.{name}.{bad[0]}: unknown key (a part has {', '.join(PART_KEYS)}; the "
                            f"renderer is the suite's)")  # fmt: skip
        if "scene" not in part:
            raise UserError(f"{path}: parts.{name}.scene: missing (a scene file or an inline scene)")
        merged: dict[str, Any] = {"name": f"{doc.get('name')}/{name}", "scene": part["scene"]}
        if "renderer" in doc:
            merged["renderer"] = doc["renderer"]
        if "seeds" in part or "seeds" in doc:
            merged["seeds"] = part.get("seeds", doc.get("seeds"))
        for key in ("set", "axes"):
            own = part.get(key, {})
            if not isinstance(own, dict):
                raise UserError(f"{path}: parts.{name}.{key}: expected a mapping, got {own!r}")
            merged[key] = {**shared.get(key, {}), **own}
        out[name] = _part_sweep(path, merged, name)
        first = next(iter(out.values()))
        if set(out[name].axes) != set(first.axes):  # NaN categories would match nothing in tables and compare
            raise UserError(f"{path}: parts.{name}.axes: {', '.join(out[name].axes) or 'none'}; the first part has "
                            f"{', '.join(first.axes) or 'none'}: every part has the same axes (with its own values), "
                            f"so that every case has a value in every category")  # fmt: skip
    return out


# --------------------------------------------------------------------------- files and digests


def _block_means(a: np.ndarray, grid: int) -> list[float | None]:
    """Block means of ``a`` (shape ``(H, W)`` or ``(H, W, C)``) over a ``grid`` x ``grid`` tiling,
    NaN pixels ignored; a block without a finite pixel is None. Returns a flat list, row-major, channel last."""
    a = np.asarray(a, dtype=float)
    a = a[..., None] if a.ndim == 2 else a
    rows = np.array_split(np.arange(a.shape[0]), grid)
    cols = np.array_split(np.arange(a.shape[1]), grid)
    out: list[float | None] = []
    for r in rows:
        for c in cols:
            block = a[np.ix_(r, c)].reshape(-1, a.shape[2])
            finite = np.isfinite(block)
            n = finite.sum(axis=0)
            s = np.where(finite, block, 0.0).sum(axis=0)
            out += [float(v / k) if k else None for v, k in zip(s, n)]
    return out


def image_digest(capture: Any, *, grid: int = DIGEST_GRID) -> dict[str, list[float | None]]:
    """Tolerant digest of a capture's images: block means of each layer.

    Parameters
    ----------
    capture : Capture
    grid : int
        Blocks per side.

    Returns
    -------
    dict of str to list
        ``stack/<k>`` (each analyzer image, ``(H, W, 3)``), ``P`` (m), ``N``, ``specular``,
        ``diffuse`` and every ``extra`` layer, when present: ``grid**2 * C`` block means each
        (None where a block has no finite pixel, e.g. background in ``P``).
    """
    layers: dict[str, Any] = {"P": capture.P, "N": capture.N, "specular": capture.specular, "diffuse": capture.diffuse}
    if capture.stack is not None:
        layers.update({f"stack/{k}": img for k, img in enumerate(capture.stack)})
    layers.update({f"extra/{k}": v for k, v in sorted(capture.extra.items())})
    return {k: _block_means(v, grid) for k, v in layers.items() if v is not None}


def digest_deviation(a: Mapping[str, list], b: Mapping[str, list]) -> tuple[float, str]:
    """Largest deviation between two digests, relative to each layer's largest |block mean| in ``a``.

    Returns
    -------
    deviation : float
        Max over layers and blocks of ``|a - b| / max|a|``; inf when the layers differ, or a block is
        empty in one and not the other.
    layer : str
        Where it is largest.
    """
    if set(a) != set(b):
        return math.inf, ", ".join(sorted(set(a) ^ set(b)))
    worst, where = 0.0, ""
    for name in a:
        x, y = a[name], b[name]
        if len(x) != len(y) or any((u is None) != (v is None) for u, v in zip(x, y)):
            return math.inf, name
        xs = np.array([u for u in x if u is not None], dtype=float)
        ys = np.array([v for v in y if v is not None], dtype=float)
        if xs.size == 0:
            continue
        scale = float(np.max(np.abs(xs)))
        dev = float(np.max(np.abs(xs - ys))) / scale if scale > 0 else float(np.max(np.abs(ys)) > 0) * math.inf
        if dev > worst:
            worst, where = dev, name
    return worst, where


# --------------------------------------------------------------------------- building


#: Keys of ``capture.json`` (a capture's ``meta``) that hold the truth in another form: the generator's
#: record of the scene it rendered (lamp position, material), written beside every render.
TRUTH_META = ("generator",)


def strip_truth(capture: Any) -> Any:
    """``capture`` as a method may see it: no ``truth``, no ``truth_*`` layer, no :data:`TRUTH_META` key."""
    extra = {k: v for k, v in capture.extra.items() if not k.startswith("truth")}
    meta = {k: v for k, v in capture.meta.items() if k not in TRUTH_META}
    return capture.replace(truth=None, extra=extra, meta=meta)


def build_case(payload: Mapping[str, Any], *, renderer: Any, cache_dir: str | None, folder: str) -> dict[str, Any]:
    """Render one case (or re-use its render) and write its two captures into ``folder``.

    Parameters
    ----------
    payload : mapping
        :func:`nearlight.evaluation.engine.run.task_payload` of the case's task.
    renderer : Renderer
    cache_dir : str or None
        Render cache.
    folder : str
        The case's folder (created; its ``input`` and ``truth`` captures must not exist).

    Returns
    -------
    dict
        ``files`` (path relative to ``folder`` -> sha256) and ``digests`` (``input`` / ``truth`` ->
        :func:`image_digest`).
    """
    clean = renderer.render(payload["scene"], cache_dir=None if cache_dir is None else Path(cache_dir))
    observed = strip_truth(noisy_capture(clean, payload))
    root = Path(folder)
    try:
        write_capture(observed, root / INPUT)
        write_capture(clean, root / TRUTH)
    except BaseException:  # a full disk, Ctrl-C: no half-written case is left (a resumed build writes it whole)
        _remove_partial_case(root)
        raise
    return case_record(root)


def case_record(root: Path) -> dict[str, Any]:
    """``files`` (sha256 of each capture file of the case's ``input`` and ``truth``, relative paths) and
    ``digests`` of a case folder. Only the captures' own files: a scratch folder an interrupted write left
    beside them (``.input.<random>.partial``) is never vouched for."""
    files = {f"{sub}/{name}": file_sha256(root / sub / name) for sub in (INPUT, TRUTH) for name in sorted(CAPTURE_FILES)}
    digests = {sub: image_digest(read_capture(root / sub)) for sub in (INPUT, TRUTH)}
    return {"files": files, "digests": digests}


def _case_done(root: Path) -> bool:
    return is_capture_dir(root / INPUT) and is_capture_dir(root / TRUTH)


def check_build_out(out: str | Path, suite: Suite) -> Path:
    """Raise :class:`UserError` unless ``out`` is creatable, an empty folder, or a build of this suite
    (resumed). Nothing is written."""
    out = check_folder(out, what="suite folder")
    if out.is_dir() and any(p.name != LOCK for p in out.iterdir()):
        manifest = out / MANIFEST
        if not manifest.is_file():
            raise UserError(f"{out}: not empty and not a built suite (no {MANIFEST}); choose another --out")
        try:
            old = json.loads(manifest.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            old = None
        if not isinstance(old, dict) or old.get("format") != FORMAT:
            raise UserError(f"{manifest}: not a manifest written by nearlight suite build; choose another --out")
        if old.get("cases_hash") != suite.cases_hash:
            raise UserError(
                f"{out}: holds suite {old.get('suite')!r} v{old.get('version')} (cases {old.get('cases_hash')}), "
                f"not {suite.name!r} v{suite.version} ({suite.cases_hash}); choose another --out"
            )
    return out


def build_suite(
    suite: Suite, out: str | Path, *, workers: int = 1, scheduler: Any = None, progress: bool = True,
    cache_dir: str | Path | None = None,
) -> tuple[Path, dict[str, int]]:  # fmt: skip
    """Build (or resume building) ``suite`` into ``out``: every case's captures, then ``manifest.json``.

    Parameters
    ----------
    suite : Suite
    out : path-like
        Suite folder (checked with :func:`check_build_out`); cases already written are kept.
    workers, scheduler : optional
        As :func:`nearlight.evaluation.engine.run.run_sweep`.
    progress : bool
        tqdm progress bars on stderr.
    cache_dir : path-like or None
        Render cache (configurations shared by several cases render once); None: none.

    Returns
    -------
    manifest : Path
    counts : dict
        ``built``, ``kept`` (already there), ``rendered`` (renders made).
    """
    out = check_build_out(out, suite)
    out.mkdir(parents=True, exist_ok=True)
    with build_lock(out):
        check_build_out(out, suite)  # again, under the lock: what another build finished meanwhile
        return _build_locked(suite, out, workers=workers, scheduler=scheduler, progress=progress, cache_dir=cache_dir)


@contextlib.contextmanager
def build_lock(out: Path) -> Iterator[None]:
    """Hold ``out/.build.lock`` (an advisory ``flock``) for one build; a second build into ``out`` at the
    same time is refused in one line. The kernel releases the lock when the process ends, also on SIGKILL,
    so a killed build never blocks the next one."""
    import fcntl

    path = out / LOCK
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise UserError(f"{path}: cannot lock the suite folder ({exc.strerror or exc})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserError(f"{out}: another `nearlight suite build` is writing there (it holds {path}); wait for "
                            f"it to finish, or choose another --out") from None  # fmt: skip
        yield
    finally:
        os.close(fd)  # releases the lock


def _build_locked(suite: Suite, out: Path, *, workers: int, scheduler: Any, progress: bool,
                  cache_dir: str | Path | None) -> tuple[Path, dict[str, int]]:  # fmt: skip
    if not (out / MANIFEST).is_file():  # marks the folder as this suite's (incomplete) build: resumable
        write_json(out / MANIFEST, jsonable(manifest_doc(suite, {})))
    renderer = suite.renderer
    cache = None if cache_dir is None else str(cache_dir)
    todo = [c for c in suite.cases if not _case_done(out / c.path)]
    rendered = 0
    records: dict[str, dict] = {}
    with executing(workers, scheduler, running=f"suite build {suite.name}") as executor:
        keys = list(dict.fromkeys(c.task.render_key for c in todo)) if renderer.prerender and cache else []
        if keys:
            scenes = {c.task.render_key: c.task.scene for c in todo}
            futs = [executor.submit(renderer.prepare, scenes[k], cache_dir=Path(cache)) for k in keys]
            for fut in completed(executor, futs, desc=f"{suite.name}: renders", unit="render", progress=progress):
                rendered += bool(fut.result())
        for c in todo:  # a case interrupted half-written is written again (nearlight wrote it)
            _remove_partial_case(out / c.path)
        futs = {executor.submit(build_case, task_payload(c.task, c.sweep), renderer=renderer, cache_dir=cache,
                                folder=str(out / c.path)): c for c in todo}  # fmt: skip
        for fut in completed(executor, futs, desc=f"{suite.name}: cases", unit="case", progress=progress,
                             total=len(suite.cases), initial=len(suite.cases) - len(todo)):  # fmt: skip
            records[futs[fut].case_id] = fut.result()
    for c in suite.cases:
        if c.case_id not in records:
            records[c.case_id] = case_record(out / c.path)
    path = write_json(out / MANIFEST, jsonable(manifest_doc(suite, records)))
    return path, {"built": len(todo), "kept": len(suite.cases) - len(todo), "rendered": rendered}


def _remove_partial_case(root: Path) -> None:
    """Remove what an interrupted build left of one case: only capture folders and the scratch folders of
    their writes (``.input.<random>.partial`` / ``.old``: nearlight's)."""
    for sub in (INPUT, TRUTH):
        if is_capture_dir(root / sub):
            shutil.rmtree(root / sub)
        for scratch in [*root.glob(f".{sub}.*.partial"), *root.glob(f".{sub}.*.old")] if root.is_dir() else []:
            if scratch.is_dir() and not scratch.is_symlink():
                shutil.rmtree(scratch, ignore_errors=True)


def manifest_doc(suite: Suite, records: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The manifest of a built suite (docs/benchmark-suites.md names every field); ``complete`` is
    false, and the cases carry no ``files`` and ``digests``, until every case has its record."""
    return {
        "format": FORMAT,
        "suite": suite.name,
        "version": suite.version,
        "description": suite.description,
        "definition": Path(suite.source).name,
        "cases_hash": suite.cases_hash,
        "renderer": suite.renderer.name,
        "nearlight_version": __version__,
        "generator_version": code_version(),
        "environment": collect(),
        "tolerance": {"digest_grid": DIGEST_GRID, "digest_rtol": DIGEST_RTOL},
        "categories": suite.categories,
        "complete": all(c.case_id in records for c in suite.cases),
        "cases": [
            {
                "id": c.case_id,
                "path": c.path,
                "categories": c.categories,
                "seed": c.task.seed,
                "noisy": c.task.noisy,
                **records.get(c.case_id, {}),
            }
            for c in suite.cases
        ],
    }


# --------------------------------------------------------------------------- reading and verifying


def read_manifest(folder: str | Path) -> dict[str, Any]:
    """The manifest of a built suite folder; :class:`UserError` naming it when missing or damaged."""
    folder = Path(folder)
    path = folder / MANIFEST
    if not folder.is_dir():
        raise UserError(f"{folder}: not a built suite folder (build one: nearlight suite build SUITE.yaml --out DIR)")
    if not path.is_file():
        raise UserError(f"{path}: missing (not a built suite: nearlight suite build SUITE.yaml --out DIR)")
    return read_manifest_file(path)


def read_manifest_file(path: str | Path) -> dict[str, Any]:
    """A suite manifest file, validated (:class:`_Manifest`: every key's type, case ids plain names, case
    folders and file names relative paths inside the suite), one line naming the key otherwise."""
    path = Path(path)
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise UserError(f"{path}: not a readable suite manifest ({one_line(exc)[:120]})") from None
    if isinstance(doc, dict) and doc.get("format") == "nearlight-suite-inputs/1":  # export.FORMAT
        raise UserError(f"{path}: an export of a suite's inputs, without the truth to score against; score with the "
                        "built suite (nearlight suite build)")  # fmt: skip
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise UserError(f"{path}: format: expected {FORMAT!r} (a manifest written by nearlight suite build)")
    if doc.get("complete") is False:
        raise UserError(f"{path}: complete: false, an interrupted build; finish it: nearlight suite build "
                        f"SUITE.yaml --out {path.parent}")  # fmt: skip
    validate(_manifest_models()[0], doc, where=str(path))
    return doc


@functools.cache
def _manifest_models() -> tuple[type, type]:
    """The pydantic models of a manifest (built on first use: pydantic is imported only by readers)."""
    Name = Annotated[str, AfterValidator(check_name)]
    Relative = Annotated[str, AfterValidator(check_relative)]
    Sha256 = Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]
    Number = float | None

    class Tolerance(BaseModel):
        model_config = ConfigDict(extra="allow")
        digest_grid: StrictInt = Field(ge=1)
        digest_rtol: float = Field(ge=0, allow_inf_nan=False, strict=True)

    class CaseEntry(BaseModel):
        model_config = ConfigDict(extra="allow")
        id: Name
        path: Relative
        categories: dict[str, str | float | int | bool | None]
        seed: StrictInt
        noisy: StrictBool
        files: dict[Relative, Sha256] = Field(min_length=1)
        digests: dict[Literal["input", "truth"], dict[str, list[Number]]]

        @field_validator("digests")
        @classmethod
        def _both(cls, v: dict) -> dict:
            if set(v) != {INPUT, TRUTH}:
                raise ValueError(f"expected {INPUT} and {TRUTH}, got {', '.join(sorted(v)) or 'none'}")
            return v

    class Manifest(BaseModel):
        model_config = ConfigDict(extra="allow")
        format: Literal["nearlight-suite/1"]
        suite: str = Field(min_length=1)
        version: StrictInt = Field(ge=1)
        cases_hash: str = Field(min_length=1)
        categories: list[str]
        tolerance: Tolerance
        complete: Literal[True]
        cases: list[CaseEntry] = Field(min_length=1)

        _unique = field_validator("cases")(unique_cases)

    return Manifest, CaseEntry


def suite_cases(suite_dir: Path, manifest: Mapping[str, Any]) -> list[tuple[str, Path]]:
    """(case id, input capture folder) of every case of a suite's manifest (a built suite's or an export's), in
    order."""
    return [(c["id"], Path(suite_dir) / c["path"] / INPUT) for c in manifest["cases"]]


def unique_cases(cls: type, cases: list) -> list:
    """A pydantic validator of a manifest's ``cases`` (a built suite's or an export's): no ``id`` and no ``path``
    names two cases."""
    for key in ("id", "path"):
        seen = [getattr(c, key) for c in cases]
        twice = next((x for x in seen if seen.count(x) > 1), None)
        if twice is not None:
            raise ValueError(f"{key} {twice!r} names two cases")
    return cases




def checksum_problems(folder: str | Path, manifest: Mapping[str, Any]) -> list[str]:
    """One line per file of the manifest that is missing or whose sha256 differs (empty: all good)."""
    folder = Path(folder)
    problems = []
    for case in manifest["cases"]:
        root = inside(folder, case["path"], where=f"{folder / MANIFEST}: cases.{case['id']}.path")
        for rel, sha in case["files"].items():
            f = inside(root, rel, where=f"{folder / MANIFEST}: cases.{case['id']}.files")
            if not f.is_file():
                problems.append(f"{f}: missing")
            elif file_sha256(f) != sha:
                problems.append(f"{f}: checksum mismatch (sha256 differs from {folder / MANIFEST})")
    return problems


def verify_against(manifest: Mapping[str, Any], other: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Compare two builds' manifests case by case.

    Returns
    -------
    list of (verdict, line)
        ``identical`` (every sha256 equal), ``within`` (files differ, digests within ``other``'s
        tolerance), ``differs`` (beyond it, or a case or file only on one side).
    """
    rtol = float(other["tolerance"]["digest_rtol"])
    mine = {c["id"]: c for c in manifest["cases"]}
    out = []
    for ref in other["cases"]:
        c = mine.get(ref["id"])
        if c is None:
            out.append(("differs", f"{ref['path']}: case {ref['id']} missing"))
            continue
        if c["files"] == ref["files"]:
            out.append(("identical", f"{c['path']}: identical"))
            continue
        worst, where = 0.0, ""
        for sub in (INPUT, TRUTH):
            dev, layer = digest_deviation(ref["digests"][sub], c["digests"][sub])
            if dev >= worst:
                worst, where = dev, f"{sub}/{layer}"
        verdict = "within" if worst <= rtol else "differs"
        out.append((verdict, f"{c['path']}: files differ, digests {'within' if verdict == 'within' else 'BEYOND'} "
                             f"tolerance (largest deviation {worst:.2e} of the layer's peak at {where}, tolerance {rtol:g})"))
    for cid in set(mine) - {r["id"] for r in other["cases"]}:
        out.append(("differs", f"{mine[cid]['path']}: case {cid} not in the reference"))
    return out
