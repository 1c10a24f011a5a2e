"""Verb ``gsa`` of the ``nearlight`` command: sample a GSA file, run each design on the sweep engine, report it.

The study and the engine are imported when the verb runs, so that registering
it keeps ``nearlight --help`` fast.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ...errors import require_extra
from ...files.outputs import check_folder
from ...generator.cli import add_cache_options, add_quiet_option, results_cache
from ..engine.cli import add_executor_options, check_executor, executor_text, on_executor


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``gsa`` to the ``nearlight`` command."""
    p = subparsers.add_parser(
        "gsa",
        help="global sensitivity analysis: sample a GSA file's inputs, run them as a sweep, rank what matters",
        description="Sample each design of a GSA file (Saltelli for Sobol' indices, or Morris screening; SALib), "
        "run every sampled configuration on the sweep engine into DIR/<design>/ (a Sobol' design's replicates into "
        "DIR/<design>/seed-<s>/; resumed when it exists) and "
        "write DIR/<design>/gsa/: the indices with bootstrap intervals per method and metric, bar charts and "
        "scatter plots.",
    )
    p.add_argument("gsa", metavar="GSA.yaml")
    p.add_argument("--out", required=True, metavar="DIR", help="results folder: one sub-folder per design")
    p.add_argument("--design", metavar="NAME", help="run only this design (default: every design of the file)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="change a key of the GSA file, e.g. designs.screening.n=2 (repeatable)")
    add_executor_options(p)
    add_cache_options(p, default="DIR/<design>/renders")
    add_quiet_option(p)
    p.set_defaults(run=_gsa)


def _gsa(args: argparse.Namespace) -> int:
    from ...files.yamlfile import parse_setting
    from ..engine.run import check_resumable, run_sweep
    from .report import check_report_out, write_gsa_report
    from .study import load_study

    check_executor(args)
    settings = dict(parse_setting(item, example="designs.screening.n=2") for item in args.set)
    check_folder(args.out, what="results folder")
    study = load_study(args.gsa, settings=settings, design=args.design)
    for run in study.runs.values():
        if run.sweep.renderer.extra is not None:
            require_extra(run.sweep.renderer.extra)
        for rep in run.replicates:  # every design before anything runs
            check_resumable(Path(args.out) / run.design.name / rep.folder, rep.sweep)
        check_report_out(study, run, Path(args.out) / run.design.name)  # and where its report goes
    cache = results_cache(args)
    status = 0
    for name, run in study.runs.items():
        out = Path(args.out) / name
        command = " ".join(["nearlight gsa", args.gsa, "--out", args.out, "--design", name,
                            *(f"--set {item}" for item in args.set)])  # fmt: skip
        complete = True
        for rep in run.replicates:
            sweep, folder = rep.sweep, out / rep.folder
            which = "" if rep.folder == "." else f" replicate seed {rep.seed} ({rep.folder}, {len(run.replicates)} in all)"
            print(
                f"gsa {study.name} {name}{which}: {run.design.method} design, n = {run.design.n}: "
                f"{len(run.samples) // len(run.replicates)} samples, {len(sweep.tasks)} tasks, "
                f"{len(sweep.render_keys)} physical configurations, on {executor_text(args)} -> {folder}",
                file=sys.stderr,
            )
            s = on_executor(args, run_sweep, sweep, folder, progress=not args.quiet, cache_dir=cache, command=command)
            print(
                f"gsa {study.name} {name}{which}: {s.line()}; " + ("complete" if s.complete else "INCOMPLETE"),
                file=sys.stderr,
            )
            complete &= s.complete
        if complete:
            print(write_gsa_report(study, run, out, command=command))  # the result: each design's report folder
        else:
            print(out)
            status = 1
    return status
