"""``nearlight render`` and ``nearlight show``: the generator's verbs."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..errors import require_extra
from ..files.outputs import check_file_out, check_folder


def renderer_folder() -> str:
    """The user cache's sub-folder of this process's renderer: its variant and LLVM target.

    A render key names a scene, not the code that renders it: kept under one key, a render made
    with another LLVM target (another machine sharing the cache, ``NEARLIGHT_JIT_TARGET=host``, the
    host-target renders of nearlight before 0.4) would be read back as this one's. E.g.
    ``llvm_ad_mono_polarized-x86-64-v3-avx2-fma-8-lanes``, ``llvm_ad_mono_polarized-host``.
    """
    from .jit_target import planned_target
    from .llvm import LLVM_VARIANT, planned_variant

    variant = planned_variant()[0]
    if variant != LLVM_VARIANT:
        return variant
    target = planned_target()
    slug = "host" if target.startswith("host") else "-".join("".join(c if c.isalnum() else " " for c in target).split())
    return f"{variant}-{slug}"


def cache_root() -> Path:
    """``$NEARLIGHT_CACHE`` or ``$XDG_CACHE_HOME/nearlight/renders`` (``~/.cache/...``): the user cache, every renderer's."""
    if os.environ.get("NEARLIGHT_CACHE"):
        return Path(os.environ["NEARLIGHT_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "nearlight" / "renders"


def default_cache_dir() -> Path:
    """The user cache of this process's renderer: :func:`cache_root` / :func:`renderer_folder`.

    Raises
    ------
    UserError
        ``NEARLIGHT_JIT_TARGET`` or ``NEARLIGHT_MITSUBA_VARIANT`` names no choice.
    """
    return cache_root() / renderer_folder()


def add_cache_options(parser: argparse.ArgumentParser, *, default: str | None = None) -> None:
    """``--cache DIR`` and ``--no-cache``, spelled the same on every verb that renders.

    One rule (docs/cli.md, "The render cache"): renders are kept by render key
    in one folder; ``--cache DIR`` chooses it, ``--no-cache`` renders afresh.
    The default is the user cache for ``render`` and the results folder's
    ``renders/`` for ``sweep`` and ``reproduce`` (``default`` names it in the help).
    """
    where = default or f"$NEARLIGHT_CACHE or {cache_root()}, a sub-folder per renderer"
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--cache", metavar="DIR", default=None, help=f"render cache folder (default: {where})")
    group.add_argument("--no-cache", action="store_true", help="do not read or write a render cache")


def cache_dir(args: argparse.Namespace, *, default: Path | None = None) -> Path | None:
    """The render cache folder the options of :func:`add_cache_options` ask for (checked), or None.

    ``default`` replaces the user cache (:func:`default_cache_dir`) when ``--cache`` is not given.
    """
    if args.no_cache:
        return None
    folder = Path(args.cache) if args.cache else (default or default_cache_dir())
    check_folder(folder, what="render cache folder (--cache)")
    return folder


def results_cache(args: argparse.Namespace) -> Path | None | bool:
    """The ``cache_dir`` of :func:`nearlight.evaluation.engine.run.run_sweep` for a verb with a results
    folder: True (its ``renders/``) unless ``--cache DIR`` (checked) or ``--no-cache`` (None)."""
    return cache_dir(args) if args.cache or args.no_cache else True


def add_quiet_option(parser: argparse.ArgumentParser) -> None:
    """``--quiet``, on every verb that shows progress: no progress bars (results, notes and errors stay)."""
    parser.add_argument("--quiet", action="store_true", help="no progress bars on stderr")


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
    add_cache_options(p)
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing capture at --out (only a capture: a folder holding exactly "
                   "capture.json and capture.exr)")
    add_quiet_option(p)
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
    from . import load_scene, render_capture
    from .pipeline import check_writable

    require_extra("render")
    check_writable(Path(args.out), overwrite=args.overwrite)
    scene = load_scene(args.scene, overrides=args.overrides)
    out = render_capture(scene, args.out, cache_dir=cache_dir(args), progress=not args.quiet, overwrite=args.overwrite)
    print(out)  # the result: the capture folder written
    return 0


def _show(args: argparse.Namespace) -> int:
    from .show import contact_sheet

    folder = Path(args.capture)
    named = folder if folder.name not in ("", "..") else folder.resolve()
    out = Path(args.out) if args.out else named.parent / f"{named.name or 'capture'}.png"
    check_file_out(out, "png", flag="--out")
    contact_sheet(folder, out)
    print(out)  # the result: the PNG written
    return 0
