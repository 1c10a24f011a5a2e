"""Keep a reproduction made on another CPU (or with another LLVM target) as a reference.

    .venv/bin/python scripts/keep_reference.py RUN_DIR NAME --tables first_stage board ... --note "..."

RUN_DIR is a ``nearlight reproduce --out`` folder; the reference is written to
``reports/references/NAME/`` with the fingerprints of the named tables' code
today (:mod:`nearlight.evaluation.paper.references`). Keep only tables whose
code is the code that made the run; say how you know in ``--note``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nearlight.errors import UserError
from nearlight.evaluation.paper.references import keep


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", type=Path)
    p.add_argument("name")
    p.add_argument("--tables", nargs="+", required=True)
    p.add_argument("--note", required=True, help="where the run comes from and why its tables' code is today's")
    args = p.parse_args(argv)
    try:
        print(keep(args.run, args.name, args.tables, note=args.note))
    except UserError as exc:
        print(f"keep_reference: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
