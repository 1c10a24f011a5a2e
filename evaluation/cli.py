"""Verbs ``sweep``, ``report``, ``compare`` and ``gsa`` of the ``nearlight`` command."""

from __future__ import annotations

import argparse
import re
import sys

from ..errors import UserError, require_extra
from ..generator.cli import add_cache_options, add_quiet_option, results_cache


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``sweep``, ``report``, ``compare`` and ``gsa`` to the ``nearlight`` command."""
    p = subparsers.add_parser(
        "sweep",
        help="run (or resume) a sweep file into a results folder",
        description="Expand a sweep file into tasks, render each physical configuration once, run every "
        "estimator on every capture and write one Parquet row per task into DIR. The same command resumes "
        "an interrupted sweep.",
    )
    p.add_argument("sweep", metavar="SWEEP.yaml")
    p.add_argument("--out", required=True, metavar="DIR", help="results folder (resumed when it exists)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask distributed scheduler")
    add_cache_options(p, default="DIR/renders")
    add_quiet_option(p)
    p.set_defaults(run=_sweep)

    p = subparsers.add_parser(
        "report",
        help="error tables (Markdown, CSV) and plots (PNG) of a sweep's results",
        description="Write DIR/report/: tables of mean, median and 90th percentile of every error per method "
        "and axis value, the Cramér–Rao bounds beside each method's RMSE, and error plots.",
    )
    p.add_argument("dir", metavar="DIR")
    p.add_argument("--out", metavar="REPORT_DIR", help="default DIR/report")
    p.set_defaults(run=_report)

    p = subparsers.add_parser(
        "compare",
        help="regression check of a sweep's results against a baseline",
        description="Compare every method x metric x configuration of NEW_DIR with BASELINE_DIR: noise-free "
        "configurations value against value, noisy ones pooled over their seeds (Mann-Whitney U, Sidak-corrected "
        "to a family-wise ALPHA). Prints each check (baseline, new value, change with its interval, verdict) "
        "and what differs between the two environments; exit 1 if anything got worse, 0 if not.",
    )
    p.add_argument("new", metavar="NEW_DIR")
    p.add_argument("baseline", metavar="BASELINE_DIR")
    p.add_argument("--tolerance", type=float, default=0.05, metavar="REL",
                   help="relative change that counts (default 0.05 = 5%%)")
    p.add_argument("--alpha", type=float, default=0.05, metavar="P",
                   help="family-wise false-alarm rate of the checks pooled over seeds (default 0.05)")
    p.add_argument("--json", metavar="OUT.json", help="also write every check and the verdict as JSON")
    p.add_argument("--include-runtime", action="store_true", help="also compare runtime_s")
    p.set_defaults(run=_compare)

    p = subparsers.add_parser(
        "gsa",
        help="global sensitivity analysis: sample a GSA file's inputs, run them as a sweep, rank what matters",
        description="Sample each design of a GSA file (Saltelli for Sobol' indices, or Morris screening; SALib), "
        "run every sampled configuration on the sweep engine into DIR/<design>/ (resumed when it exists) and "
        "write DIR/<design>/gsa/: the indices with bootstrap intervals per method and metric, bar charts and "
        "scatter plots.",
    )
    p.add_argument("gsa", metavar="GSA.yaml")
    p.add_argument("--out", required=True, metavar="DIR", help="results folder: one sub-folder per design")
    p.add_argument("--design", metavar="NAME", help="run only this design (default: every design of the file)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="change a key of the GSA file, e.g. designs.screening.n=2 (repeatable)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this Dask distributed scheduler")
    add_cache_options(p, default="DIR/<design>/renders")
    add_quiet_option(p)
    p.set_defaults(run=_gsa)

    from . import suite_cli

    suite_cli.register(subparsers)  # suite build, suite verify, score


def check_executor(args: argparse.Namespace) -> None:
    """``--workers`` positive; ``--scheduler`` a ``tcp://HOST:PORT`` with the cluster extra installed."""
    if args.workers < 1:
        raise UserError(f"--workers: expected a positive integer, got {args.workers}")
    if args.scheduler is not None:
        check_scheduler(args.scheduler)
        require_extra("cluster")


def _sweep(args: argparse.Namespace) -> int:
    from .engine import check_resumable, run_sweep
    from .sweep import load_sweep

    check_executor(args)
    from ..files.outputs import check_folder

    check_folder(args.out, what="results folder")
    sweep = load_sweep(args.sweep)
    if sweep.renderer.extra is not None:
        require_extra(sweep.renderer.extra)
    check_resumable(args.out, sweep)  # before anything is printed or run
    cache = results_cache(args)
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else f"{args.workers} local worker(s)"
    print(
        f"sweep {sweep.name}: {len(sweep.tasks)} tasks, {len(sweep.render_keys)} physical configurations, "
        f"on {where} -> {args.out}",
        file=sys.stderr,
    )
    if args.scheduler:
        try:
            s = run_sweep(sweep, args.out, scheduler=args.scheduler, progress=not args.quiet, cache_dir=cache)
        except (OSError, ValueError) as exc:
            raise UserError(f"--scheduler {args.scheduler}: cannot connect ({' '.join(str(exc).split())})") from None
    else:
        s = run_sweep(sweep, args.out, workers=args.workers, progress=not args.quiet, cache_dir=cache)
    print(
        f"sweep {sweep.name}: ran {s.ran} task(s), skipped {s.skipped} already done, {s.failed} failed; "
        f"renders: {s.rendered} rendered, {s.reused} task(s) re-used a render; {s.seconds:.1f} s; "
        + ("complete: results.parquet written" if s.complete else "INCOMPLETE"),
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


def _report(args: argparse.Namespace) -> int:
    from .report import write_report

    folder = write_report(args.dir, out=args.out)
    print(folder)  # the result: the report folder written
    return 0


def _compare(args: argparse.Namespace) -> int:
    from .compare import compare_dirs

    checks, lines = compare_dirs(
        args.new, args.baseline, json_out=args.json, tolerance=args.tolerance, alpha=args.alpha,
        include_runtime=args.include_runtime,
    )
    for line in lines:
        print(line)
    if args.json:
        print(args.json)
    return 1 if any(c.regression for c in checks) else 0


def _gsa(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..files.outputs import check_folder
    from ..files.yamlfile import parse_setting
    from .engine import check_resumable, run_sweep
    from .gsa import load_study
    from .gsa_report import check_report_out, write_gsa_report

    check_executor(args)
    settings = dict(parse_setting(item, example="designs.screening.n=2") for item in args.set)
    check_folder(args.out, what="results folder")
    study = load_study(args.gsa, settings=settings, design=args.design)
    for run in study.runs.values():
        if run.sweep.renderer.extra is not None:
            require_extra(run.sweep.renderer.extra)
        check_resumable(Path(args.out) / run.design.name, run.sweep)  # every design before anything runs
        check_report_out(study, run, Path(args.out) / run.design.name)  # and where its report goes
    cache = results_cache(args)
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else f"{args.workers} local worker(s)"
    status = 0
    for name, run in study.runs.items():
        out = Path(args.out) / name
        command = " ".join(["nearlight gsa", args.gsa, "--out", args.out, "--design", name,
                            *(f"--set {item}" for item in args.set)])  # fmt: skip
        sweep = run.sweep
        print(
            f"gsa {study.name} {name}: {run.design.method} design, n = {run.design.n}: {len(run.samples)} samples, "
            f"{len(sweep.tasks)} tasks, {len(sweep.render_keys)} physical configurations, on {where} -> {out}",
            file=sys.stderr,
        )
        kw = {"scheduler": args.scheduler} if args.scheduler else {"workers": args.workers}
        try:
            s = run_sweep(sweep, out, progress=not args.quiet, cache_dir=cache, command=command, **kw)
        except (OSError, ValueError) as exc:
            if not args.scheduler:
                raise
            raise UserError(f"--scheduler {args.scheduler}: cannot connect ({' '.join(str(exc).split())})") from None
        print(
            f"gsa {study.name} {name}: ran {s.ran} task(s), skipped {s.skipped} already done, {s.failed} failed; "
            f"renders: {s.rendered} rendered, {s.reused} task(s) re-used a render; {s.seconds:.1f} s; "
            + ("complete" if s.complete else "INCOMPLETE"),
            file=sys.stderr,
        )
        if s.complete:
            print(write_gsa_report(study, run, out, command=command))  # the result: each design's report folder
        else:
            print(out)
            status = 1
    return status
