"""Verb ``reproduce`` of the ``nearlight`` command: the paper's experiments, the README's first command.

The reproduction is imported when the verb runs, so that registering it keeps
``nearlight --help`` fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ...errors import UserError, require_extra
from ...generator.cli import add_cache_options, add_quiet_option, results_cache
from .check import check, read_reference


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``reproduce`` to the ``nearlight`` command."""
    p = subparsers.add_parser(
        "reproduce",
        help="reproduce the paper's experiments on physically-based renders",
        description="Run (or resume) the paper's experiments, the sweep files of sweeps/paper/, into "
        "--out/sweeps/ and write paper_reproduction.md (+ .json and figures) into --out.",
    )
    p.add_argument("--out", default="out/reproduce", help="report folder (default: %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help="each sweep file's quick profile: small images and 4 analyzer angles (under 2 minutes)")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    add_cache_options(p, default="OUT/sweeps/<profile>/<sweep>/renders")
    add_quiet_option(p)
    p.add_argument("--against", metavar="DIR",
                   help="then compare every table with DIR/paper_reproduction.json (same profile) within the "
                   "tolerances the report states; exit 1 if any number differs")
    p.set_defaults(run=_run)


def _reference(folder: str, profile: str) -> tuple[dict, list[str] | None, list[str]]:
    """The reference document of ``--against``, checked before any work, and which of its tables to compare.

    A reference kept in ``reports/references/`` (a ``reference.json`` beside it) is compared on the
    tables whose code is today's only (:mod:`nearlight.evaluation.paper.references`); the retired
    ones are named. Any other folder: every table.
    """
    from .references import RECORD, references

    doc = read_reference(Path(folder) / "paper_reproduction.json", profile)
    if not (Path(folder) / RECORD).is_file():
        return doc, None, []
    (_, _, live, retired), = references(profile, folder=Path(folder).parent, names=[Path(folder).name])
    if not live:
        raise UserError(f"--against {folder}: every table of this kept reference is retired (their code changed "
                        f"since it was kept: {', '.join(retired)}); nothing to compare")
    return doc, live, retired


def _run(args: argparse.Namespace) -> int:
    """Exit 1 when a task failed or, with ``--against``, a number differs; else 0."""
    from .reproduce import FULL, QUICK, failures, reproduce

    require_extra("render")
    if args.workers < 1:
        raise UserError(f"--workers: expected a positive integer, got {args.workers}")
    ref, tables, retired = _reference(args.against, QUICK if args.quick else FULL) if args.against else (None, None, [])
    md = reproduce(args.out, quick=args.quick, workers=args.workers, progress=not args.quiet,
                   cache_dir=results_cache(args))
    print(md)
    doc = json.loads((md.parent / "paper_reproduction.json").read_text())
    failed = failures(doc)
    for line in failed:
        print(f"nearlight: failed task: {line}", file=sys.stderr)
    if ref is None:
        return 1 if failed else 0
    lines, misses = check(doc, ref, tables=tables)
    print(f"against {args.against} (made by {ref.get('code_version', ref.get('nearlight_version'))}):")
    if retired:
        print(f"  not compared: {', '.join(retired)} (kept reference; their code changed since it was kept)")
    for line in lines:
        print(f"  {line}")
    return 1 if misses or failed else 0
