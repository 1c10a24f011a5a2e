"""The sweep engine: render each physical configuration once, run every task, keep every row.

Two phases. First each distinct physical configuration not yet in the render
cache is rendered once (renderers that cache on disk only). Then every task
not yet done runs (its render is a cache hit) and its row is written the moment
it comes back. Work goes to local worker processes (``workers`` > 1), to the
calling process (``workers`` = 1), or to a Dask distributed cluster
(``scheduler``): the same function computes the same row everywhere. With a
remote cluster the output folder must be on a file system the workers share
(the render cache lives there).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import functools
import multiprocessing
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from .environment import code_version
from ..errors import UserError
from .store import MANIFEST, RENDERS, ResultStore, read_manifest, set_aside_damaged_parts
from .sweep import Sweep, Task
from .metrics import ESTIMATE_COLUMNS, LOBE_COLUMN
from .tasks import noisy_capture, run_task


@dataclasses.dataclass
class RunSummary:
    """What a run did. Attributes: tasks in the sweep, tasks run now, tasks skipped as
    already done, renders made, tasks that re-used a render, failed tasks, wall seconds,
    and whether the sweep is now complete."""

    tasks: int
    ran: int
    skipped: int
    rendered: int
    reused: int
    failed: int
    seconds: float
    complete: bool


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
            "renderer": sweep.renderer.name,
            "code_version": version,
        }
    )
    row.update(result)
    return row


def check_resumable(out: str | Path, sweep: Sweep) -> None:
    """Raise :class:`UserError` unless ``out`` holds no sweep or this one (checked before any work)."""
    out = Path(out)
    if (out / MANIFEST).exists():
        old = read_manifest(out)
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

    A row whose :data:`~nearlight.evaluation.metrics.LOBE_COLUMN` names another family than
    Torrance–Sparrow (``full``'s fitted lobe) gets that family's own BSDF back in
    ``stages["full"]["bsdf"]`` (its σ and Ks columns are the Torrance–Sparrow equivalent:
    :func:`~nearlight.physics.reflectance.convert_bsdf` inverts that), so the re-synthesis
    shows the lobe that was fitted. Rows written before the column existed read as Torrance–Sparrow.
    """
    import numpy as np

    from ..estimator import Estimate
    from ..physics.reflectance import LOBES, convert_bsdf

    x, y, z, sigma, *ks = (float(row[c]) for c in ESTIMATE_COLUMNS)
    est = Estimate(method=str(row["method"]), lamp_position=np.array([x, y, z]), ks=np.array(ks), sigma=sigma)
    lobe = str(row.get(LOBE_COLUMN, "") or "torrance_sparrow")
    if lobe != "torrance_sparrow" and lobe in LOBES and np.isfinite(sigma) and sigma > 0:
        bsdf = convert_bsdf({"model": "torrance_sparrow", "ks": est.ks, "sigma": sigma}, lobe)
        est.stages = {"full": {"lobe": lobe, "bsdf": bsdf}}
    return est


class _Deferred:
    """A call run when its result is first asked for."""

    def __init__(self, fn: Callable, args: tuple, kw: dict):
        self.call = functools.partial(fn, *args, **kw)

    def result(self) -> Any:
        return self.call()


class _Inline:
    """Runs each call in this process (workers = 1), one at a time as results are collected."""

    def submit(self, fn: Callable, *args: Any, **kw: Any) -> _Deferred:
        return _Deferred(fn, args, kw)

    def as_completed(self, futures: list) -> Iterator:
        return iter(futures)

    def abort(self) -> None:
        pass

    def close(self) -> None:
        pass


def _exit_with_parent(parent: int) -> None:
    """Worker initializer: end this worker when the sweep process that started it is gone.

    A killed parent (even SIGKILL, which no handler sees) must not leave
    orphaned workers computing rows nobody will write. Linux's parent-death
    signal covers most cases; a thread that checks the parent id twice a
    second covers the rest (and other systems).
    """
    import os
    import signal
    import threading

    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="nearlight-parent-watch", daemon=True).start()


class _Local:
    """Local worker processes (spawned: Mitsuba and Dr.Jit threads do not survive fork)."""

    def __init__(self, workers: int):
        import os

        self.pool = cf.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                           initializer=_exit_with_parent, initargs=(os.getpid(),))  # fmt: skip
        self.aborted = False

    def submit(self, fn: Callable, *args: Any, **kw: Any) -> cf.Future:
        return self.pool.submit(fn, *args, **kw)

    def as_completed(self, futures: list) -> Iterator:
        return cf.as_completed(futures)

    def abort(self) -> None:
        """Stop now (interrupted): end the workers instead of waiting for their tasks."""
        self.aborted = True
        processes = list(getattr(self.pool, "_processes", {}).values())
        self.pool.shutdown(wait=False, cancel_futures=True)
        for p in processes:
            if p.is_alive():
                p.terminate()
        for p in processes:
            p.join(timeout=5)

    def close(self) -> None:
        if not self.aborted:
            self.pool.shutdown(wait=True, cancel_futures=True)


class _Dask:
    """A Dask distributed cluster at ``scheduler`` (an address or a Client/LocalCluster)."""

    def __init__(self, scheduler: Any):
        from distributed import Client

        self.own = not isinstance(scheduler, Client)
        self.client = Client(scheduler) if self.own else scheduler

    def submit(self, fn: Callable, *args: Any, **kw: Any) -> Any:
        return self.client.submit(fn, *args, pure=False, **kw)

    def as_completed(self, futures: list) -> Iterator:
        from distributed import as_completed

        return as_completed(futures)

    def abort(self) -> None:
        self.close()
        self.own = False

    def close(self) -> None:
        if self.own:
            self.client.close()


def _cache_folder(out: str | Path, cache_dir: str | Path | None | bool) -> Path | None:
    """The render cache a sweep in ``out`` uses: True = its own ``renders/``, a path, or None (no cache)."""
    return Path(out) / RENDERS if cache_dir is True else (Path(cache_dir) if cache_dir else None)


def sweep_inputs(sweep: Sweep) -> list[Path]:
    """The files a sweep read: its sweep file and the scene file it names (when they are files)."""
    source = Path(sweep.source)
    if not source.is_file():
        return []
    from ..files.yamlfile import load_yaml_file

    scene = load_yaml_file(source, what="sweep file").get("scene")
    scene_file = source.parent / scene if isinstance(scene, str) else None
    return [source, *([scene_file] if scene_file is not None and scene_file.is_file() else [])]


def _record_provenance(sweep: Sweep, out: str | Path, command: str | None) -> None:
    from .provenance import record

    record(out, command=command or f"nearlight sweep {sweep.source} --out {out}",
           entry_modules=[__name__], inputs=sweep_inputs(sweep))


def make_executor(workers: int, scheduler: Any) -> Any:
    """Where the engine's calls run: this process (``workers`` = 1), local worker processes, or a Dask
    cluster at ``scheduler``; ``submit``, ``as_completed``, ``abort`` (interrupted) and ``close``.
    Shared with the suite builder and ``nearlight score`` (:mod:`nearlight.evaluation.suite`)."""
    if scheduler is not None:
        return _Dask(scheduler)
    return _Inline() if workers <= 1 else _Local(workers)


@contextlib.contextmanager
def executing(workers: int, scheduler: Any, *, running: str = "a task") -> Iterator[Any]:
    """:func:`make_executor` for a ``with`` block: aborted when the block is interrupted, else closed.

    A local worker process that dies (killed, out of memory, a plug-in's ``os._exit``) is one
    :class:`UserError` line saying what it was running (``running``: e.g. ``"method mod:fn"``); what was
    written before stays, and the same command resumes.
    """
    from concurrent.futures.process import BrokenProcessPool

    executor = make_executor(workers, scheduler)
    try:
        yield executor
    except BrokenProcessPool:
        executor.abort()
        raise UserError(f"{running}: a worker process died while running it (killed, or it exited); what was "
                        f"finished before is kept: fix the cause, then run the same command again") from None  # fmt: skip
    except BaseException:
        executor.abort()
        raise
    finally:
        executor.close()


def completed(executor: Any, futures: Iterable, *, desc: str, unit: str, progress: bool,
              total: int | None = None, initial: int = 0) -> Iterator[Any]:
    """``executor.as_completed(futures)`` under a tqdm bar on stderr (one step per future).

    Parameters
    ----------
    executor : object
        From :func:`make_executor`.
    futures : iterable
        Its futures (a dict's keys, a list).
    desc, unit : str
        The bar's label and unit.
    progress : bool
        Show the bar.
    total, initial : int, optional
        The bar's length (default: the number of futures) and its start (work done before).
    """
    from tqdm import tqdm

    futures = list(futures)
    bar = tqdm(total=len(futures) if total is None else total, initial=initial, desc=desc, unit=unit,
               disable=not progress, file=sys.stderr)  # fmt: skip
    try:
        for fut in executor.as_completed(futures):
            yield fut
            bar.update()
    finally:
        bar.close()


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
    if (Path(out) / MANIFEST).exists():
        read_manifest(out)  # a damaged sweep.json is a one-line error naming it, before anything runs
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
        keys = list(dict.fromkeys(t.render_key for t in todo)) if renderer.prerender and cache_dir else []
        if keys:
            scenes = {t.render_key: t.scene for t in todo}
            futs = {executor.submit(renderer.prepare, scenes[k], cache_dir=Path(cache_dir)): k for k in keys}
            for fut in completed(executor, futs, desc=f"{sweep.name}: renders", unit="render", progress=progress):
                try:
                    rendered += bool(_result(fut))
                except Exception as exc:  # the tasks of this configuration become error rows
                    render_errors[futs[fut]] = f"render: {type(exc).__name__}: {' '.join(str(exc).split())}"

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
        reused=ran - rendered if renderer.prerender and cache_dir else 0,
        failed=failed,
        seconds=time.perf_counter() - t_start,
        complete=complete,
    )
