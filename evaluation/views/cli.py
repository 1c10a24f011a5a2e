"""Verbs ``report``, ``compare`` and ``baseline`` of the ``nearlight`` command: views of finished results folders,
and the one way to regenerate a regression baseline.

The views are imported when a verb runs, so that registering them keeps
``nearlight --help`` fast.
"""

from __future__ import annotations

import argparse
import sys

from ...generator.cli import add_quiet_option
from ..engine.cli import add_executor_options, check_executor, on_executor


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``report``, ``compare`` and ``baseline`` to the ``nearlight`` command."""
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
        help="regression check of a sweep's results (or a scorecard) against a baseline",
        description="Compare every method x metric x configuration of NEW_DIR with BASELINE_DIR: noise-free "
        "configurations value against value, noisy ones pooled over their seeds (Mann-Whitney U, Sidak-corrected "
        "to a family-wise ALPHA); two scorecards (`nearlight score` folders) with their cases paired, over all "
        "cases and per category value (Wilcoxon signed-rank; failures: McNemar). Prints each check (baseline, "
        "new value, change with its interval, verdict) and what differs between the two environments; exit 1 "
        "if anything got worse, 0 if not.",
    )
    p.add_argument("new", metavar="NEW_DIR")
    p.add_argument("baseline", metavar="BASELINE_DIR")
    add_thresholds(p)
    p.add_argument("--json", metavar="OUT.json", help="also write every check and the verdict as JSON")
    p.add_argument("--include-runtime", action="store_true", help="also compare runtime_s")
    p.set_defaults(run=_compare)

    p = subparsers.add_parser(
        "baseline",
        help="regenerate a regression baseline, writing the new run's verdict against the old one beside it",
        description="Run SWEEP.yaml into a new folder, report it, compare it with the baseline OUT (as `compare` "
        "does) and replace OUT with it, writing every worse, missing and better check into OUT/verdict.md and "
        "OUT/verdict.json. When a check is worse or missing, nothing is replaced unless --reason says why "
        "(exit 1); OUT must be a sweep's results folder or absent.",
    )
    p.add_argument("sweep", metavar="SWEEP.yaml")
    p.add_argument("--out", required=True, metavar="BASELINE_DIR", help="the baseline folder (replaced whole)")
    p.add_argument("--reason", metavar="TEXT", help="one line: why the new baseline may be worse than the old")
    add_thresholds(p)
    add_executor_options(p)
    add_quiet_option(p)
    p.set_defaults(run=_baseline)


def add_thresholds(parser: argparse.ArgumentParser) -> None:
    """``--tolerance REL`` and ``--alpha P`` of a regression check (``compare``, ``baseline``)."""
    parser.add_argument("--tolerance", type=float, default=0.05, metavar="REL",
                        help="relative change that counts (default 0.05 = 5%%)")
    parser.add_argument("--alpha", type=float, default=0.05, metavar="P",
                        help="family-wise false-alarm rate of the checks pooled over seeds, or paired over a "
                        "scorecard's cases (default 0.05)")


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


def _baseline(args: argparse.Namespace) -> int:
    from .baseline import VERDICT_MD, regenerate_baseline

    check_executor(args)
    done = on_executor(args, regenerate_baseline, args.sweep, args.out, reason=args.reason,
                       tolerance=args.tolerance, alpha=args.alpha, progress=not args.quiet)  # fmt: skip
    for line in done.lines:
        print(line)
    if not done.replaced:
        print(f"nearlight baseline: {len(done.regressions)} check(s) worse or missing against {args.out}: "
              "nothing replaced; if that is intended, run again with --reason saying why", file=sys.stderr)
        return 1
    print(f"{args.out}/{VERDICT_MD}")  # the result: the verdict written beside the new baseline
    return 0
