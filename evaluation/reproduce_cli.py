"""``nearlight reproduce``: the paper's experiments, the README's first command."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "reproduce",
        help="reproduce the paper's experiments on physically-based renders",
        description="Render paper-like scenes, run every estimator method, and write "
        "paper_reproduction.md (+ .json and figures) into --out.",
    )
    p.add_argument("--out", default="out/reproduce", help="report folder (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="small images and 4 analyzer angles (under 2 minutes)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(run=_run)


def _run(args: argparse.Namespace) -> int:
    from nearlight.evaluation.reproduce import reproduce

    md = reproduce(args.out, quick=args.quick, progress=not args.no_progress)
    print(md)
    return 0
