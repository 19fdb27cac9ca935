"""``splatstyler crop MODEL --box X0,Y0,Z0,X1,Y1,Z1 [--invert] -o OUT.ply``: keep the Gaussians whose centres lie
in a world-space box (or a sphere), or outside it with ``--invert``; everything else about them is unchanged.

OUT's name picks the format as in ``splatstyler export`` (a PLY keeps the model's SH degree and every value bit for
bit; the compressed formats quantise). MODEL is any model file (training/model/formats.py). A box whose first number
is negative is written ``--box=-1,...``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.region_flags import add_region_flags, region_from_args
from training.model.formats import MODEL_FILE, SUFFIX_LIST


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("crop", help="keep the Gaussians inside (or outside) a box or sphere",
                            description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", type=Path, metavar="MODEL",
                        help=MODEL_FILE)
    add_region_flags(parser, "keep", with_mask=False, required=True)
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help=f"output file: {SUFFIX_LIST} (written atomically)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from training.core.errors import InputError
    from training.model.export import human_size, write_export
    from training.model.formats import format_for_path
    from training.model.model_io import read_model

    fmt = format_for_path(args.output)
    if fmt is None or args.output.is_dir():
        raise InputError(args.output, f"give an output file name ending in {SUFFIX_LIST}")
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
