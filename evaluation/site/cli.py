"""Verb ``site`` of the ``nearlight`` command: a static HTML site of reports, results and scorecards."""

from __future__ import annotations

import argparse
import sys
import time


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``site`` to the ``nearlight`` command."""
    p = subparsers.add_parser(
        "site",
        help="a static HTML site of reports and scorecards: leaderboards per suite, every report as a page",
        description="Build a static HTML site (no server; opens from the file system) from folders of committed "
        "reports, results and scorecards: a leaderboard per suite from the scorecards (every number linked to the "
        "JSON it came from) and every Markdown report as a page with its figures (docs/results-site.md).",
    )
    p.add_argument("dirs", nargs="+", metavar="DIR", help="folders to build from, e.g. reports/")
    p.add_argument("--out", required=True, metavar="SITE",
                   help="the site's folder: absent, empty, or a site nearlight wrote (its site.json)")
    p.set_defaults(run=_site)


def _site(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .build import Site, check_site_out, write_site
    from .html import render

    clock = time.perf_counter()
    out = Path(args.out)
    check_site_out(out, [])  # the place first: a refused output costs nothing
    site = Site(args.dirs, out)
    written = write_site(site, render(site))
    print(f"site: {len(site.pages)} report pages, {len(site.boards)} scorecards on "
          f"{len(site.suites())} leaderboards, {len(written)} files; {time.perf_counter() - clock:.1f} s",
          file=sys.stderr)  # fmt: skip
    print(out / "index.html")
    return 0
