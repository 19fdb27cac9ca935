"""``splatstyler crop MODEL --box X0,Y0,Z0,X1,Y1,Z1 [--invert] -o OUT.ply``: keep the Gaussians whose centres lie
in a world-space box (or a sphere), or outside it with ``--invert``; everything else about them is unchanged.

OUT's name picks the format as in ``splatstyler export`` (.ply keeps the model's SH degree and every value bit for
bit; .compressed.ply, .splat and .spz quantise; .glb keeps float32). MODEL is any model file (.ply,
.compressed.ply, .splat, .spz, .glb). A box whose first number is negative is written ``--box=-1,...``.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("crop", help="keep the Gaussians inside (or outside) a box or sphere",
                            description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", type=Path, metavar="MODEL",
                        help="model file: .ply, .compressed.ply, .splat, .spz or .glb")
    shape = parser.add_mutually_exclusive_group(required=True)
    shape.add_argument("--box", default=None, metavar="X0,Y0,Z0,X1,Y1,Z1", help="two opposite corners, world space")
    shape.add_argument("--sphere", default=None, metavar="CX,CY,CZ,R", help="centre and radius, world space")
    parser.add_argument("--invert", action="store_true", help="keep the Gaussians outside instead")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="output file: .ply, .compressed.ply, .splat, .spz or .glb (written atomically)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from training.core.errors import InputError
    from training.model.export import SUFFIX_LIST, format_for_path, human_size, write_export
    from training.model.model_io import read_model
    from training.model.selection import box_mask, parse_floats, sphere_mask

    fmt = format_for_path(args.output)
    if fmt is None or args.output.is_dir():
        raise InputError(args.output, f"give an output file name ending in {SUFFIX_LIST}")
    if args.box is not None:
        values = parse_floats(args.box, 6, "--box")  # checked before the model is read: a typo costs nothing
    else:
        values = parse_floats(args.sphere, 4, "--sphere")
        if values[3] < 0:
            raise InputError(None, f"--sphere radius must be >= 0, got {values[3]}")
    g = read_model(args.model)
    means = g.means.numpy()
    if args.box is not None:
        keep = box_mask(means, values[:3], values[3:], invert=args.invert)
    else:
        keep = sphere_mask(means, values[:3], values[3], invert=args.invert)
    kept = int(keep.sum())
    if kept == 0:
        where = "outside" if args.invert else "inside"
        raise InputError(args.model, f"none of its {len(g)} Gaussians lies {where} the "
                                     f"{'box' if args.box is not None else 'sphere'}: nothing to write")
    result = write_export(args.output, g, fmt, mask=keep)
    print(f"wrote {args.output}: kept {kept} of {len(g)} Gaussians ({human_size(result.size)})")
    return 0
