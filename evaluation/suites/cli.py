"""Verbs ``suite build``, ``suite verify``, ``suite export`` and ``score`` of the ``nearlight`` command (docs/benchmark-suites.md).

The suite builder and the scorecard are imported when a verb runs, so that
registering them keeps ``nearlight --help`` fast.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ...errors import UserError, require_extra
from ...generator.cli import add_cache_options, add_quiet_option, cache_dir
from ..engine.cli import add_executor_options, check_executor, on_executor


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``suite`` (``build``, ``verify``, ``export``) and ``score`` to the ``nearlight`` command."""
    p = subparsers.add_parser(
        "suite",
        help="build a benchmark suite (frozen, versioned captures with checksums) or verify one",
        description="A suite file (suites/*.yaml) is a sweep file without methods (or a list of such `parts`, one "
        "per scene), plus version, categories and the pinned hash of its cases. `suite build` renders every case once into a portable folder with "
        "manifest.json; `suite verify` checks its checksums, or compares it with another build.",
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    b = sub.add_parser("build", help="render a suite file's cases into DIR and write DIR/manifest.json",
                       description="Render every case of SUITE.yaml (resumed when DIR holds a partial build of "
                       "the same suite) and write DIR/manifest.json.")  # fmt: skip
    b.add_argument("suite", metavar="SUITE.yaml")
    b.add_argument("--out", required=True, metavar="DIR", help="suite folder (created; resumed when it is this suite's)")
    add_executor_options(b)
    add_cache_options(b)
    add_quiet_option(b)
    b.set_defaults(run=_build)

    v = sub.add_parser("verify", help="check a built suite's files against its manifest (and another build's)",
                       description="Check the sha256 of every file of DIR against DIR/manifest.json; with --against, "
                       "also compare DIR's build with another build's manifest: files that differ must agree "
                       "within the tolerance on their image digests. Exit 1 if anything does not.")  # fmt: skip
    v.add_argument("dir", metavar="DIR")
    v.add_argument("--against", metavar="MANIFEST.json", help="another build's manifest.json (or its folder)")
    v.set_defaults(run=_verify)

    e = sub.add_parser("export", help="write a built suite's inputs without its truth, for a method run elsewhere",
                       description="Copy the input captures of the built suite DIR (no truth key, no truth layer) and "
                       "a manifest of their checksums into the new folder INPUTS; the categories, seeds and truth stay "
                       "behind. Answers come back as a results file: nearlight score DIR --results FILE --out OUT "
                       "(docs/benchmark-suites.md, \"Results files\").")  # fmt: skip
    e.add_argument("dir", metavar="DIR")
    e.add_argument("--out", required=True, metavar="INPUTS", help="export folder (new, or empty)")
    e.set_defaults(run=_export)

    s = subparsers.add_parser(
        "score",
        help="score a method on every case of a built suite: scorecard (Markdown, JSON, PNG)",
        description="Run METHOD on every case of SUITE_DIR (the capture without its truth), score each against "
        "the truth, and write OUT/scorecard.{md,json,png}: recall over a ladder of thresholds per category, "
        "medians with bootstrap intervals, failures, run time; and OUT/results.jsonl, its answers as a results "
        "file. Resumed when OUT holds the same run. With --results, score the answers of a results file written "
        "elsewhere (self-reported); with --check, only check such a file (exit 2 naming its first bad line).",
    )
    s.add_argument("suite_dir", metavar="SUITE_DIR", help="a built suite (or, with --check, its export)")
    what = s.add_mutually_exclusive_group(required=True)
    what.add_argument("--method", metavar="NAME|MODULE:FUNCTION", help="built-in name or plug-in, run here")
    what.add_argument("--results", metavar="FILE.jsonl", help="score a results file's answers (self-reported)")
    what.add_argument("--check", metavar="FILE.jsonl", help="check a results file against the suite; write nothing")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a method option (repeatable)")
    s.add_argument("--out", metavar="DIR", help="score folder (resumed when it holds this run); not with --check")
    add_executor_options(s)
    add_quiet_option(s)
    s.set_defaults(run=_score)


def _build(args: argparse.Namespace) -> int:
    from .suite import build_suite, check_build_out, load_suite

    check_executor(args)
    suite = load_suite(args.suite)
    if suite.renderer.extra is not None:
        require_extra(suite.renderer.extra)
    check_build_out(args.out, suite)
    print(f"suite {suite.name} v{suite.version}: {len(suite.cases)} cases, {len(suite.render_keys)} physical "
          f"configurations -> {args.out}", file=sys.stderr)  # fmt: skip
    t0 = time.perf_counter()
    path, n = on_executor(args, build_suite, suite, args.out, progress=not args.quiet, cache_dir=cache_dir(args))
    print(f"suite {suite.name} v{suite.version}: built {n['built']} case(s), kept {n['kept']} already built, "
          f"{n['rendered']} render(s); {time.perf_counter() - t0:.1f} s; manifest written", file=sys.stderr)  # fmt: skip
    print(path)
    return 0


def _verify(args: argparse.Namespace) -> int:
    from .export import FORMAT as EXPORT_FORMAT
    from .export import read_inputs
    from .suite import MANIFEST, checksum_problems, read_manifest_file, verify_against

    manifest = read_inputs(args.dir)[0]  # a built suite, or an export of its inputs (checksums only)
    if args.against and manifest["format"] == EXPORT_FORMAT:
        raise UserError(f"--against {args.against}: {args.dir} is an export (no digests to compare); verify it alone")
    problems = checksum_problems(args.dir, manifest)
    for line in problems:
        print(line)
    bad = bool(problems)
    n_files = sum(len(c["files"]) for c in manifest["cases"])
    if args.against:
        ref_path = Path(args.against)
        ref = read_manifest_file(ref_path / MANIFEST if ref_path.is_dir() else ref_path)
        if (ref["suite"], ref["version"], ref["cases_hash"]) != (manifest["suite"], manifest["version"], manifest["cases_hash"]):
            print(f"differs: {args.against} is suite {ref['suite']!r} v{ref['version']} ({ref['cases_hash']}), "
                  f"{args.dir} is {manifest['suite']!r} v{manifest['version']} ({manifest['cases_hash']})")  # fmt: skip
            return 1
        verdicts = verify_against(manifest, ref)
        for verdict, line in verdicts:
            if verdict != "identical":
                print(line)
        counts = {k: sum(v == k for v, _ in verdicts) for k in ("identical", "within", "differs")}
        bad |= counts["differs"] > 0
        print(f"{'DIFFERS' if counts['differs'] else 'ok'}: against {args.against}: {counts['identical']} case(s) "
              f"identical, {counts['within']} within the tolerance, {counts['differs']} beyond it")  # fmt: skip
    print(f"{'FAILED' if problems else 'ok'}: {n_files - len(problems)} of {n_files} files of {args.dir} match "
          f"its manifest")  # fmt: skip
    return 1 if bad else 0


def _export(args: argparse.Namespace) -> int:
    from .export import export_inputs

    path, n = export_inputs(args.dir, args.out)
    print(f"suite export: {n} case(s) of {args.dir}, inputs only -> {args.out}", file=sys.stderr)
    print(path)
    return 0


def _check(args: argparse.Namespace) -> int:
    from .export import read_inputs
    from .results_file import read_results

    if args.out or args.set:
        raise UserError(f"--check {args.check}: checks a results file and writes nothing; leave out "
                        f"{'--out' if args.out else '--set'}")  # fmt: skip
    suite, cases = read_inputs(args.suite_dir)
    head, rows = read_results(args.check, suite, cases)
    failed = sum(r["status"] != "ok" for r in rows.values())
    print(f"ok: {args.check}: {len(rows)} row(s) for the {len(cases)} case(s) of {suite['suite']} v{suite['version']} "
          f"({failed} failed), method {head['method']} {head['method_version']}")  # fmt: skip
    return 0


def _score(args: argparse.Namespace) -> int:
    from ...files.yamlfile import parse_setting
    from .scorecard import RESULTS_JSONL, SCORECARD_JSON, SCORECARD_MD, SCORECARD_PNG, score_suite

    if args.check:
        return _check(args)
    if not args.out:
        raise UserError(f"{'--method' if args.method else '--results'}: needs --out DIR (the score folder)")
    if args.results and args.set:
        raise UserError(f"--set {args.set[0]}: a results file's method ran elsewhere; it takes no options here")
    check_executor(args)
    options = dict(parse_setting(item, example="energy=radiance") for item in args.set)
    what = ["--method", args.method] if args.method else ["--results", args.results]
    command = " ".join(["nearlight score", args.suite_dir, *what, *(f"--set {s}" for s in args.set),
                        "--out", args.out, *(["--workers", str(args.workers)] if args.workers > 1 else [])])  # fmt: skip
    card, n = on_executor(args, score_suite, args.suite_dir, args.out, method=args.method, results=args.results,
                          options=options, progress=not args.quiet, command=command)  # fmt: skip
    print(f"score {args.method or args.results}: ran {n['ran']} case(s), skipped {n['skipped']} already scored, "
          f"{n['failed']} failed; " + ("scorecard written" if card else "INCOMPLETE"), file=sys.stderr)  # fmt: skip
    if card is None:
        print(args.out)
        return 1
    lamp = card["groups"][0]["lamp_position_error_pct"]
    print(f"{card['method']} on {card['suite']} v{card['version']}: lamp recall "
          + ", ".join(f"<{t:g}%: {100 * r:.0f}%" for t, r in zip(card["thresholds"]["lamp_position_error_pct"], lamp["recall"]))
          + f"; {card['failed']} of {card['cases']} failed")  # fmt: skip
    for name in (SCORECARD_MD, SCORECARD_JSON, SCORECARD_PNG) + ((RESULTS_JSONL,) if args.method else ()):
        print(Path(args.out) / name)
    return 0
