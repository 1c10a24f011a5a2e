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

    .venv/bin/python scripts/keep_reference.py fingerprints --out FP.json      # in a checkout of the old code
    .venv/bin/python scripts/keep_reference.py carry BEFORE_RUN AFTER_RUN FP.json --note "..."

``fingerprints`` writes the reproduction tables' fingerprints of the checkout's
code (both profiles); ``carry`` moves every kept reference's table that a code
change retired but left as it was (this machine's BEFORE_RUN, made by the code
of FP.json, and AFTER_RUN, made by today's, agree on it to the last bit) to
today's fingerprint (:func:`nearlight.evaluation.paper.references.carry`). A
checkout older than the ``fingerprints`` command prints the same with
``python -c "import json; from nearlight.evaluation.paper.references import
fingerprints as f; print(json.dumps({'full': f(quick=False), 'quick': f(quick=True)}))"``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from nearlight.errors import UserError
from nearlight.files.atomic import write_json
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
    f = sub.add_parser("fingerprints")
    f.add_argument("--out", type=Path, required=True)
    c = sub.add_parser("carry")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    c.add_argument("fingerprints", type=Path, help="the `fingerprints` file of the code that made BEFORE")
    c.add_argument("--note", required=True, help="the change, in a line")
    args = p.parse_args(argv)
    try:
        if args.kind == "reproduction":
            print(reproductions.keep(args.run, args.name, args.tables, note=args.note))
        elif args.kind == "scores":
            print(suites.keep(args.build, args.scores, args.suite_file, args.name, note=args.note))
        elif args.kind == "fingerprints":
            doc = {"full": reproductions.fingerprints(quick=False), "quick": reproductions.fingerprints(quick=True)}
            print(write_json(args.out, doc, what="the fingerprints"))
        else:
            try:
                old = json.loads(args.fingerprints.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise UserError(f"{args.fingerprints}: cannot read a fingerprints file ({exc})") from None
            done = reproductions.carry(args.before, args.after, old, note=args.note)
            print("\n".join(done) if done else "nothing to carry")
    except UserError as exc:
        print(f"keep_reference: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
