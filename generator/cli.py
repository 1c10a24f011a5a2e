"""``nearlight render`` and ``nearlight show``: the generator's verbs."""

from __future__ import annotations

import argparse
import os
from pathlib import Path


def default_cache_dir() -> Path:
    """``$NEARLIGHT_CACHE`` or ``$XDG_CACHE_HOME/nearlight/renders`` (``~/.cache/...``)."""
    if os.environ.get("NEARLIGHT_CACHE"):
        return Path(os.environ["NEARLIGHT_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "nearlight" / "renders"


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``render`` and ``show`` to the ``nearlight`` command."""
    p = subparsers.add_parser(
        "render",
        help="render a scene file to a capture directory",
        description="Render SCENE.yaml with Mitsuba 3 to a capture directory (capture.json + capture.exr).",
    )
    p.add_argument("scene", metavar="SCENE.yaml", help="scene file (see scenes/)")
    p.add_argument("--out", required=True, metavar="DIR", help="capture directory to create")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key, value in YAML, e.g. --set lamp.position=[0.2,0.1,0.3]")  # fmt: skip
    p.add_argument("--cache", metavar="DIR", default=None,
                   help=f"render cache folder (default: $NEARLIGHT_CACHE or {default_cache_dir()})")  # fmt: skip
    p.add_argument("--no-cache", action="store_true", help="do not read or write the render cache")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing capture at --out (only a capture: a folder holding exactly "
                   "capture.json and capture.exr)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=_render)

    s = subparsers.add_parser(
        "show",
        help="write a PNG contact sheet of a capture",
        description="Contact sheet of a capture: analyzer images, specular, diffuse, DoLP and AoLP.",
    )
    s.add_argument("capture", metavar="DIR", help="capture directory")
    s.add_argument("--out", metavar="PNG", default=None,
                   help="output PNG (default: DIR.png beside DIR); an existing file there is replaced only if it is a PNG")
    s.set_defaults(run=_show)


def _render(args: argparse.Namespace) -> int:
    import sys

    from . import load_scene, render_capture

    from .pipeline import check_writable
    from ..files.outputs import check_folder

    check_writable(Path(args.out), overwrite=args.overwrite)
    scene = load_scene(args.scene, overrides=args.overrides)
    cache = None if args.no_cache else (args.cache or default_cache_dir())
    if cache is not None:
        check_folder(cache, what="render cache folder (--cache)")
    out = render_capture(scene, args.out, cache_dir=cache, progress=not args.quiet, overwrite=args.overwrite)
    print(f"wrote {out}", file=sys.stderr)
    return 0


def _show(args: argparse.Namespace) -> int:
    import sys

    from .show import contact_sheet

    from ..files.outputs import check_file_out

    folder = Path(args.capture)
    named = folder if folder.name not in ("", "..") else folder.resolve()
    out = Path(args.out) if args.out else named.parent / f"{named.name or 'capture'}.png"
    check_file_out(out, "png", flag="--out")
    contact_sheet(folder, out)
    print(f"wrote {out}", file=sys.stderr)
    return 0
