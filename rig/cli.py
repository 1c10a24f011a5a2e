"""``nearlight rig import`` and ``nearlight rig export``: a real rig's raw files to a capture, and the rig simulator."""

from __future__ import annotations

import argparse

from ..errors import UserError, require_extra


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``rig`` verb with its two actions."""
    p = subparsers.add_parser(
        "rig",
        help="real rigs: import a rig's raw files as a capture; export a capture as raw rig files",
        description="Import the raw files of a polarization camera and a depth sensor, named by a rig file "
        "(docs/rig-files.md), as a capture; or export a capture as the raw files such a rig would record.",
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    imp = sub.add_parser("import", help="rig file -> capture",
                         description="Read RIG.yaml and the files it names, write the capture.")  # fmt: skip
    imp.add_argument("rig_file", metavar="RIG.yaml")
    imp.add_argument("--out", required=True, metavar="DIR", help="capture directory to write")
    imp.add_argument("--overwrite", action="store_true", help="replace a capture at DIR (only a capture)")
    imp.set_defaults(run=run_import)
    exp = sub.add_parser("export", help="capture -> raw rig files (the rig simulator)",
                         description="Write the mosaic frame (with camera noise), the depth map and the rig file "
                         "a polarization rig would record for CAPTURE, into a new folder.")  # fmt: skip
    exp.add_argument("capture", metavar="CAPTURE", help="capture directory")
    exp.add_argument("--out", required=True, metavar="RIGDIR", help="folder to create")
    exp.add_argument("--mosaic", choices=("mono", "colour"), default="mono", help="sensor kind (default mono)")
    exp.add_argument("--seed", type=int, default=0, help="camera noise seed (default 0)")
    exp.add_argument("--full-well", type=float, default=20000.0, help="electrons (default 20000)")
    exp.add_argument("--read-noise", type=float, default=5.0, help="electrons rms (default 5)")
    exp.add_argument("--bits", type=int, default=12, help="ADC bits, 1 to 16 (default 12)")
    exp.add_argument("--depth-scale", type=float, default=1e-3, help="metres per depth-PNG unit (default 0.001: mm)")
    exp.add_argument("--depth-format", choices=("png", "exr"), default="png",
                     help="png: 16-bit in --depth-scale units (default); exr: float32 metres")  # fmt: skip
    exp.set_defaults(run=run_export)


def run_import(args: argparse.Namespace) -> int:
    from .importer import import_rig

    require_extra("rig")
    print(import_rig(args.rig_file, args.out, overwrite=args.overwrite))
    return 0


def run_export(args: argparse.Namespace) -> int:
    from ..capture import read_capture
    from .export import export_rig

    require_extra("rig")
    if not 1 <= args.bits <= 16:
        raise UserError(f"--bits: expected an integer from 1 to 16 (a 16-bit PNG), got {args.bits}")
    for flag, value, low in (("--full-well", args.full_well, 0.0), ("--depth-scale", args.depth_scale, 0.0)):
        if not value > low:
            raise UserError(f"{flag}: expected a number > 0, got {value}")
    if not args.read_noise >= 0:
        raise UserError(f"--read-noise: expected a number >= 0, got {args.read_noise}")
    if args.seed < 0:
        raise UserError(f"--seed: expected an integer >= 0, got {args.seed}")
    capture = read_capture(args.capture)
    print(export_rig(capture, args.out, mosaic=args.mosaic, seed=args.seed, full_well=args.full_well,
                     read_noise=args.read_noise, bits=args.bits, depth_scale=args.depth_scale,
                     depth_format=args.depth_format))  # fmt: skip
    return 0
