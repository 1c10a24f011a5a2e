"""Keep a run made on another CPU (or with another LLVM target) as a reference (reports/references/).

    .venv/bin/python scripts/keep_reference.py reproduction RUN_DIR NAME --tables first_stage ... --note "..."
    .venv/bin/python scripts/keep_reference.py scores SUITE.yaml BUILD_DIR NAME SCORE_DIR... --note "..."

``reproduction``: RUN_DIR is a ``nearlight reproduce --out`` folder, kept as
``reports/references/NAME/`` for the named tables
(:mod:`nearlight.evaluation.paper.references`). ``scores``: BUILD_DIR is a
``nearlight suite build --out`` folder of SUITE.yaml and each SCORE_DIR a
``nearlight score --out`` folder of it, kept as
``reports/references/scores/<suite>/NAME/`` (:mod:`nearlight.evaluation.suites.references`).
Either records the fingerprint of today's code: keep only what today's code
made, and say where it comes from in ``--note``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nearlight.errors import UserError
from nearlight.evaluation.paper import references as reproductions
from nearlight.evaluation.suites import references as suites


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="kind", required=True)
    r = sub.add_parser("reproduction")
    r.add_argument("run", type=Path)
    r.add_argument("name")
    r.add_argument("--tables", nargs="+", required=True)
    s = sub.add_parser("scores")
    s.add_argument("suite_file", type=Path)
    s.add_argument("build", type=Path)
    s.add_argument("name")
    s.add_argument("scores", type=Path, nargs="+")
    for q in (r, s):
        q.add_argument("--note", required=True, help="where the run comes from and why its code is today's")
    args = p.parse_args(argv)
    try:
        if args.kind == "reproduction":
            print(reproductions.keep(args.run, args.name, args.tables, note=args.note))
        else:
            print(suites.keep(args.build, args.scores, args.suite_file, args.name, note=args.note))
    except UserError as exc:
        print(f"keep_reference: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
