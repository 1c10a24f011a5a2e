"""Run (or resume) a sweep: render each physical configuration once, run every task, keep every row.

Two phases. First each distinct physical configuration not yet in the render
cache is rendered once (renderers that cache on disk only). Then every task
not yet done runs (its render is a cache hit) and its row is written the moment
it comes back. Work goes to the executors of :mod:`.workers` (this process,
local worker processes, or a Dask cluster): the same function computes the
same row everywhere. With a remote cluster the output folder must be on a file
system the workers share (the render cache lives there). A finished row is
read back as the capture and the estimate it was made from by
:func:`task_captures` and :func:`row_estimate` (the reproduction's figures).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import UserError, one_line
from ...estimator import Estimate
from ...files.yamlfile import load_yaml_file
from ...physics.reflectance import LOBES, convert_bsdf
from ..scoring.metrics import ESTIMATE_COLUMNS, LOBE_COLUMN
from .environment import code_version
from .provenance import record
from .store import SWEEP_JSON, RENDERS, ResultStore, read_sweep_json, set_aside_damaged_parts
from .sweep import Sweep, Task
from .tasks import noisy_capture, run_task
from .workers import completed, executing


@dataclasses.dataclass
class RunSummary:
    """What a run did. Attributes: tasks in the sweep, tasks run now, tasks skipped as
    already done, renders made ahead and cached on disk, tasks that re-used such a render, tasks
    that made their own (closed form, analytic, or no cache), failed tasks, wall seconds, and
    whether the sweep is now complete."""

    tasks: int
    ran: int
    skipped: int
    rendered: int
    reused: int
    own: int
    failed: int
    seconds: float
    complete: bool

    def line(self) -> str:
        """The summary the verbs print: ``ran N task(s), skipped …; renders: …; S s``."""
        own = f", {self.own} task(s) rendered their own" if self.own else ""
        return (f"ran {self.ran} task(s), skipped {self.skipped} already done, {self.failed} failed; renders: "
                f"{self.rendered} rendered, {self.reused} task(s) re-used a render{own}; {self.seconds:.1f} s")


def task_payload(task: Task, sweep: Sweep) -> dict[str, Any]:
    """The plain-data form of a task that workers receive."""
    return {
        "task_id": task.task_id,
        "index": task.index,
        "scene": task.scene,
        "noise": task.noise,
        "range_noise": task.range_noise,
        "seed": task.seed,
        "method_spec": task.method.method,
        "options": task.method.options,
        "crlb": sweep.crlb,
    }


def task_row(task: Task, result: dict[str, Any], *, sweep: Sweep, version: str) -> dict[str, Any]:
    """One tidy row: identity and config columns first, then the task's result."""
    row: dict[str, Any] = {"task_id": task.task_id, "task_index": task.index, "sweep": sweep.name}
    row.update(task.config)
    row.update(
        {
            "seed": task.seed,
            "noisy": task.noisy,
            "method": task.method.label,
            "render_key": task.render_key,
            "renderer": sweep.renderer.used_by(task.scene),
            "code_version": version,
        }
    )
    row.update(result)
    return row


def check_resumable(out: str | Path, sweep: Sweep) -> None:
    """Raise :class:`UserError` unless ``out`` holds no sweep or this one (checked before any work)."""
    out = Path(out)
    if (out / SWEEP_JSON).exists():
        old = read_sweep_json(out)
        if old["sweep_hash"] != sweep.sweep_hash:
            raise UserError(
                f"{out}: holds results of another sweep ({old['name']!r}, hash {old['sweep_hash']}); "
                "choose another --out or remove it"
            )


def task_captures(sweep: Sweep, task: Task, out: str | Path, cache_dir: str | Path | None | bool = True) -> tuple[Any, Any]:
    """The noise-free capture of a finished task, from the render cache it ran with (``cache_dir``
    as :func:`run_sweep` takes it; True: its results folder ``out``'s, a cache hit), and the
    capture its estimator saw (the task's noise with its seed)."""
    clean = sweep.renderer.render(task.scene, cache_dir=_cache_folder(out, cache_dir))
    return clean, noisy_capture(clean, task_payload(task, sweep))


def row_estimate(row: Any) -> Any:
    """The :class:`~nearlight.estimator.Estimate` a result row records (lamp, σ, Ks; a point lamp),
    to re-synthesise it (:func:`nearlight.estimator.render_specular`).

    A row whose :data:`~nearlight.evaluation.scoring.metrics.LOBE_COLUMN` names another family than
    Torrance–Sparrow (``full``'s fitted lobe) gets that family's own BSDF back in
    ``stages["full"]["bsdf"]`` (its σ and Ks columns are the Torrance–Sparrow equivalent:
    :func:`~nearlight.physics.reflectance.convert_bsdf` inverts that), so the re-synthesis
    shows the lobe that was fitted. Rows written before the column existed read as Torrance–Sparrow.
    """
    x, y, z, sigma, *ks = (float(row[c]) for c in ESTIMATE_COLUMNS)
    est = Estimate(method=str(row["method"]), lamp_position=np.array([x, y, z]), ks=np.array(ks), sigma=sigma)
    lobe = str(row.get(LOBE_COLUMN, "") or "torrance_sparrow")
    if lobe != "torrance_sparrow" and lobe in LOBES and np.isfinite(sigma) and sigma > 0:
        bsdf = convert_bsdf({"model": "torrance_sparrow", "ks": est.ks, "sigma": sigma}, lobe)
        est.stages = {"full": {"lobe": lobe, "bsdf": bsdf}}
    return est


def _cache_folder(out: str | Path, cache_dir: str | Path | None | bool) -> Path | None:
    """The render cache a sweep in ``out`` uses: True = its own ``renders/``, a path, or None (no cache)."""
    return Path(out) / RENDERS if cache_dir is True else (Path(cache_dir) if cache_dir else None)


def sweep_inputs(sweep: Sweep) -> list[Path]:
    """The files a sweep read: its sweep file and the scene file it names (when they are files)."""
    source = Path(sweep.source)
    if not source.is_file():
        return []
    scene = load_yaml_file(source, what="sweep file").get("scene")
    scene_file = source.parent / scene if isinstance(scene, str) else None
    return [source, *([scene_file] if scene_file is not None and scene_file.is_file() else [])]


def _record_provenance(sweep: Sweep, out: str | Path, command: str | None) -> None:
    record(out, command=command or f"nearlight sweep {sweep.source} --out {out}",
           entry_modules=[__name__], inputs=sweep_inputs(sweep))


def _result(fut: Any) -> Any:
    return fut.result()


def run_sweep(
    sweep: Sweep,
    out: str | Path,
    *,
    workers: int = 1,
    scheduler: Any = None,
    progress: bool = True,
    cache_dir: str | Path | None | bool = True,
    command: str | None = None,
) -> RunSummary:
    """Run (or resume) ``sweep`` into ``out``.

    Parameters
    ----------
    sweep : Sweep
    out : path-like
        Results folder; finished tasks found there are not run again.
    workers : int, optional
        Local worker processes; 1 runs in this process.
    scheduler : str or distributed.Client, optional
        Dask scheduler address (``tcp://HOST:PORT``) or a client: run there instead.
    progress : bool, optional
        tqdm progress bars with ETA on stderr.
    cache_dir : path-like, True or None, optional
        Render cache of renderers that cache on disk: True (default) is the
        results folder's ``renders/`` (rows and figures refer to it; cluster
        workers share the folder), a path another folder (on a cluster, one
        every worker sees), None no cache (each task renders its own capture).
    command : str, optional
        The command that regenerates ``out``, recorded in its
        ``provenance.json`` by the run that completes the sweep (default
        ``nearlight sweep SOURCE --out OUT``).

    Returns
    -------
    RunSummary
    """
    t_start = time.perf_counter()
    if (Path(out) / SWEEP_JSON).exists():
        read_sweep_json(out)  # a damaged sweep.json is a one-line error naming it, before anything runs
    store = ResultStore(out, name=sweep.name, sweep_hash=sweep.sweep_hash, n_tasks=len(sweep.tasks), axes=list(sweep.axes))
    for moved in set_aside_damaged_parts(out):
        print(f"nearlight: note: a damaged result part was moved to {moved}; its task runs again", file=sys.stderr)
    done = store.done_ids()
    todo = [t for t in sweep.tasks if t.task_id not in done]
    version = code_version()
    cache = _cache_folder(out, cache_dir)
    cache_dir = str(cache) if cache is not None else None
    renderer = sweep.renderer
    rendered = failed = 0
    render_errors: dict[str, str] = {}
    running = f"sweep {sweep.name} (methods {', '.join(m.label for m in sweep.methods)})"
    with executing(workers, scheduler, running=running) as executor:
        on_disk: dict[str, bool] = {}  # once per render (its tasks share it), not once per task
        for t in todo if renderer.prerender and cache_dir else ():
            if t.render_key not in on_disk:
                on_disk[t.render_key] = renderer.on_disk(t.scene)
        cached = [t for t in todo if on_disk.get(t.render_key, False)]
        keys = list(dict.fromkeys(t.render_key for t in cached))
        if keys:
            scenes = {t.render_key: t.scene for t in todo}
            futs = {executor.submit(renderer.prepare, scenes[k], cache_dir=Path(cache_dir)): k for k in keys}
            for fut in completed(executor, futs, desc=f"{sweep.name}: renders", unit="render", progress=progress):
                try:
                    rendered += bool(_result(fut))
                except Exception as exc:  # the tasks of this configuration become error rows
                    render_errors[futs[fut]] = f"render: {type(exc).__name__}: {one_line(exc)}"

        futs = {}
        for t in todo:
            if t.render_key in render_errors:
                row = task_row(t, {"status": "error", "error": render_errors[t.render_key]}, sweep=sweep, version=version)
                store.write_row(row)
                failed += 1
                continue
            futs[executor.submit(run_task, task_payload(t, sweep), renderer=renderer, cache_dir=cache_dir)] = t
        for fut in completed(executor, futs, desc=f"{sweep.name}: tasks", unit="task", progress=progress,
                             total=len(sweep.tasks), initial=len(sweep.tasks) - len(futs)):  # fmt: skip
            t = futs[fut]
            row = task_row(t, _result(fut), sweep=sweep, version=version)
            store.write_row(row)
            failed += row["status"] != "ok"
    complete = store.consolidate() is not None
    if complete and todo:  # a re-run that ran nothing leaves the record of the run that made the rows
        _record_provenance(sweep, out, command)
    ran = len(todo)
    return RunSummary(
        tasks=len(sweep.tasks),
        ran=ran,
        skipped=len(sweep.tasks) - ran,
        rendered=rendered,
        reused=len(cached) - rendered,
        own=ran - len(cached),
        failed=failed,
        seconds=time.perf_counter() - t_start,
        complete=complete,
    )
