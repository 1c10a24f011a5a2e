"""``nearlight estimate``: run an estimator on a capture directory."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..capture import read_capture
from ..errors import UserError
from ..files.atomic import write_json
from ..files.outputs import check_file_out
from ..files.yamlfile import parse_setting
from .api import estimate, load_method
from .options import check_options
from .plot import plot_estimate


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``estimate`` verb."""
    p = subparsers.add_parser(
        "estimate",
        help="estimate the lamp position and specular reflectance of a capture",
        description="Estimate the lamp's 3-D position (m), Ks (rgb) and sigma (rad) from a capture directory "
        "(format v2; v1 read). Methods: paper, paper-init, full, distant, render-compare (needs the render extra), "
        "or a plug-in module:function.",
    )
    p.add_argument("capture", metavar="DIR", help="capture directory (capture.json + capture.exr)")
    p.add_argument(
        "--method", default="paper",
        help="paper | paper-init | full | distant | render-compare | module:function (default paper)"
    )
    p.add_argument("--json", metavar="OUT", help="write the estimate as JSON here")
    p.add_argument("--plot", metavar="OUT.png", help="write E_p(t) and observed vs re-synthesised specular here")
    p.add_argument(
        "--set", dest="options", metavar="KEY=VALUE", action="append", default=[],
        help="method option, repeatable; VALUE in YAML (e.g. --set energy=radiance --set max_outer=50)",
    )
    p.set_defaults(run=run)


def parse_options(pairs: list[str]) -> dict[str, Any]:
    """``["KEY=VALUE", ...]`` of ``--set`` to ``{KEY: VALUE}``, values read as YAML (not yet checked)."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, value = parse_setting(pair, example="t_max=2.0")
        if not key.isidentifier():
            raise UserError(f"--set {pair!r}: expected KEY=VALUE with KEY an option's name, e.g. t_max=2.0")
        out[key] = value
    return out


def run(args: argparse.Namespace) -> int:
    # the method and its options are checked before anything is read or written
    options = check_options(load_method(args.method), parse_options(args.options), method=args.method)
    # Both output places are checked before any work; the plot is drawn before the
    # JSON is written, so a failing plot never leaves a lone estimate behind.
    if args.json:
        check_file_out(args.json, "estimate", flag="--json")
    if args.plot:
        check_file_out(args.plot, "png", flag="--plot")
    if args.json and args.plot and Path(args.json).resolve() == Path(args.plot).resolve():
        raise UserError(f"--json {args.json}: the same file as --plot")
    capture = read_capture(args.capture)
    est = estimate(capture, method=args.method, **options)
    if not est.ok:  # a failure with its reason (estimator.sanity): one line, the JSON if asked, exit 1
        failure = est.diagnostics["failure"]
        print(f"nearlight estimate: {est.method} failed ({failure['rule']}): {failure['reason']}", file=sys.stderr)
        if args.json:
            write_json(Path(args.json), est.to_dict(), what="the estimate")
            print(args.json)
        sys.stdout.flush()
        return 1
    if "partial" in est.diagnostics:  # Ks refused, lamp and σ kept (estimator.sanity)
        partial = est.diagnostics["partial"]
        print(f"nearlight estimate: note: {partial['quantity']} refused ({partial['rule']}): {partial['reason']}",
              file=sys.stderr)
    pos = ", ".join(f"{v:.4f}" for v in est.lamp_position)
    ks = ", ".join(f"{v:.4g}" for v in est.ks)
    # the result on stdout: the estimate, then the path of each file written
    print(f"{est.method}: lamp ({pos}) m  ks ({ks})  sigma {est.sigma:.4f} rad  "
          f"[{sum(est.timings.values()):.2f} s]")
    if args.plot:
        plot_estimate(capture, est, args.plot)
    if args.json:
        write_json(Path(args.json), est.to_dict(), what="the estimate")
    for written in (args.plot, args.json):
        if written:
            print(written)
    sys.stdout.flush()
    return 0
