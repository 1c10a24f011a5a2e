"""Verbs ``report`` and ``compare`` of the ``nearlight`` command: views of finished results folders.

The views are imported when a verb runs, so that registering them keeps
``nearlight --help`` fast.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``report`` and ``compare`` to the ``nearlight`` command."""
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
