"""``splatstyler crop MODEL.ply --box X0,Y0,Z0,X1,Y1,Z1 [--invert] -o OUT.ply``: keep the Gaussians whose centres lie
in a world-space box (or a sphere), or outside it with ``--invert``; everything else about them is unchanged.

OUT's name picks the format as in ``splatstyler export`` (.ply keeps the model's SH degree and every value bit for
bit; .compressed.ply and .splat quantise). A box whose first number is negative is written ``--box=-1,...``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.region_flags import add_region_flags, region_from_args


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("crop", help="keep the Gaussians inside (or outside) a box or sphere",
                            description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", type=Path, metavar="MODEL", help="3DGS .ply (or .splat) file")
    add_region_flags(parser, "keep", with_mask=False, required=True)
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="output file: .ply, .compressed.ply or .splat (written atomically)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.commands.export import read_model
    from training.core.errors import InputError
    from training.model.export import format_for_path, human_size, write_export

    fmt = format_for_path(args.output)
    if fmt is None or args.output.is_dir():
        raise InputError(args.output, "give an output file name ending in .ply, .compressed.ply or .splat")
    region = region_from_args(args)  # checked before the model is read: a typo costs nothing
    g = read_model(args.model)
    keep = region.mask(g.means.numpy())
    kept = int(keep.sum())
    if kept == 0:
        where = "outside" if args.invert else "inside"
        raise InputError(args.model, f"none of its {len(g)} Gaussians lies {where} the {region.kind}: nothing to "
                                     "write")
    result = write_export(args.output, g, fmt, mask=keep)
    print(f"wrote {args.output}: kept {kept} of {len(g)} Gaussians ({human_size(result.size)})")
    return 0
