"""Where the engine's calls run: this process, local worker processes, or a Dask cluster.

One interface for the three (``submit``, ``as_completed``, ``abort`` when
interrupted, ``close``), shared by the sweep engine
(:func:`nearlight.evaluation.engine.run.run_sweep`), the suite builder and
``nearlight score``: the same function computes the same row everywhere.
Local workers are spawned, not forked (Mitsuba's and Dr.Jit's threads do not
survive a fork), and end themselves when the process that started them is
gone. Dask is imported only when a scheduler is given (the ``cluster`` extra).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import functools
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from tqdm import tqdm

from ...errors import UserError


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
    try:
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


def make_executor(workers: int, scheduler: Any) -> Any:
    """Where the engine's calls run: this process (``workers`` = 1), local worker processes, or a Dask
    cluster at ``scheduler``; ``submit``, ``as_completed``, ``abort`` (interrupted) and ``close``.
    Shared with the suite builder and ``nearlight score`` (:mod:`nearlight.evaluation.suites.suite`)."""
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
    futures = list(futures)
    bar = tqdm(total=len(futures) if total is None else total, initial=initial, desc=desc, unit=unit,
               disable=not progress, file=sys.stderr)  # fmt: skip
    try:
        for fut in executor.as_completed(futures):
            yield fut
            bar.update()
    finally:
        bar.close()
