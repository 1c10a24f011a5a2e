"""Verb ``sweep`` of the ``nearlight`` command, and the executor options every engine verb shares.

``--workers N`` and ``--scheduler tcp://HOST:PORT`` are spelled and checked
the same on ``sweep``, ``gsa``, ``suite build`` and ``score``
(:func:`check_executor`), and a scheduler that cannot be reached is the same
one line on each (:func:`on_executor`). The verb's work is imported when it
runs, so that registering it keeps ``nearlight --help`` fast.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from typing import Any

from ...errors import UserError, one_line, require_extra
from ...files.outputs import check_folder
from ...generator.cli import add_cache_options, add_quiet_option, results_cache


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``sweep`` to the ``nearlight`` command."""
    p = subparsers.add_parser(
        "sweep",
        help="run (or resume) a sweep file into a results folder",
        description="Expand a sweep file into tasks, render each physical configuration once, run every "
        "estimator on every capture and write one Parquet row per task into DIR. The same command resumes "
        "an interrupted sweep.",
    )
    p.add_argument("sweep", metavar="SWEEP.yaml")
    p.add_argument("--out", required=True, metavar="DIR", help="results folder (resumed when it exists)")
    add_executor_options(p)
    add_cache_options(p, default="DIR/renders")
    add_quiet_option(p)
    p.set_defaults(run=_sweep)


def add_executor_options(parser: argparse.ArgumentParser) -> None:
    """``--workers N`` and ``--scheduler tcp://HOST:PORT``, checked by :func:`check_executor`."""
    parser.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    parser.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask distributed scheduler")


def check_executor(args: argparse.Namespace) -> None:
    """``--workers`` positive; ``--scheduler`` a ``tcp://HOST:PORT`` with the cluster extra installed."""
    if args.workers < 1:
        raise UserError(f"--workers: expected a positive integer, got {args.workers}")
    if args.scheduler is not None:
        check_scheduler(args.scheduler)
        require_extra("cluster")


def on_executor(args: argparse.Namespace, fn: Callable[..., Any], *a: Any, **kw: Any) -> Any:
    """``fn(*a, workers=args.workers, **kw)``, or ``fn(*a, scheduler=args.scheduler, **kw)`` with ``--scheduler``.

    On a scheduler an ``OSError`` or ``ValueError`` (what Dask raises for an
    address nothing answers at) is one :class:`UserError` line,
    ``--scheduler ADDRESS: cannot connect (<reason>)``.
    """
    if not args.scheduler:
        return fn(*a, workers=args.workers, **kw)
    try:
        return fn(*a, scheduler=args.scheduler, **kw)
    except (OSError, ValueError) as exc:
        raise UserError(f"--scheduler {args.scheduler}: cannot connect ({one_line(exc)})") from None


def executor_text(args: argparse.Namespace) -> str:
    """Where the work runs, for a status line: ``Dask scheduler ADDRESS`` or ``N local worker(s)``."""
    return f"Dask scheduler {args.scheduler}" if args.scheduler else f"{args.workers} local worker(s)"


def _sweep(args: argparse.Namespace) -> int:
    from .run import check_resumable, run_sweep
    from .sweep import load_sweep

    check_executor(args)
    check_folder(args.out, what="results folder")
    sweep = load_sweep(args.sweep)
    if sweep.renderer.extra is not None:
        require_extra(sweep.renderer.extra)
    check_resumable(args.out, sweep)  # before anything is printed or run
    cache = results_cache(args)
    print(
        f"sweep {sweep.name}: {len(sweep.tasks)} tasks, {len(sweep.render_keys)} physical configurations, "
        f"on {executor_text(args)} -> {args.out}",
        file=sys.stderr,
    )
    s = on_executor(args, run_sweep, sweep, args.out, progress=not args.quiet, cache_dir=cache)
    print(
        f"sweep {sweep.name}: {s.line()}; " + ("complete: results.parquet written" if s.complete else "INCOMPLETE"),
        file=sys.stderr,
    )
    print(args.out)  # the result: the results folder (complete or not: the exit status says)
    return 0 if s.complete else 1


#: A Dask scheduler address: ``[protocol://]host:port``.
_ADDRESS = re.compile(r"^(?:(?:tcp|tls|ucx|ws|wss)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?):(\d{1,5})$")


def check_scheduler(address: str) -> str:
    """Raise :class:`UserError` unless ``address`` reads as a Dask scheduler address ``tcp://HOST:PORT``."""
    m = _ADDRESS.match(address)
    if not m or not 0 < int(m.group(1)) < 65536:
        raise UserError(f"--scheduler {address!r}: expected a scheduler address tcp://HOST:PORT (port 1-65535)")
    return address
