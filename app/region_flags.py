"""``--mask``, ``--box``, ``--sphere`` and ``--invert``: which Gaussians a command acts on (``export`` and
``stylize``: a selection; ``crop``: the part it keeps). The flags are declared here, and read and checked once, before
the model is read (a typo costs nothing), by ``region_from_args``; ``Region.mask`` gives the (N,) bool mask over a
model's centres (training/model/selection.py does the geometry). A box whose first number is negative is written
``--box=-1,...`` (argparse would take ``-1`` for a flag)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from training.core.errors import InputError


def add_region_flags(parser: argparse.ArgumentParser, verb: str, with_mask: bool = True,
                     required: bool = False) -> None:
    """The flags, their help saying what ``verb`` ("export", "stylize", "keep") does with the Gaussians chosen."""
    group = parser.add_mutually_exclusive_group(required=required)
    if with_mask:
        group.add_argument("--mask", type=Path, default=None, metavar="FILE",
                           help=f"{verb} only these Gaussians: .npy bool mask or indices, or .txt indices")
    group.add_argument("--box", default=None, metavar="X0,Y0,Z0,X1,Y1,Z1",
                       help=f"{verb} only the Gaussians whose centres lie in this world-space box, two opposite "
                            "corners (--box=-1,... when the first number is negative)")
    group.add_argument("--sphere", default=None, metavar="CX,CY,CZ,R",
                       help=f"{verb} only the Gaussians whose centres lie in this sphere, centre and radius")
    parser.add_argument("--invert", action="store_true",
                        help=f"with --{'mask/--' if with_mask else ''}box/--sphere: {verb} the other Gaussians instead")


@dataclass(frozen=True)
class Region:
    """The region the flags name: a mask file, a box (lo, hi corners) or a sphere (centre, radius), inverted or
    not."""

    kind: str  # mask | box | sphere
    values: tuple[float, ...] = ()
    path: Path | None = None
    invert: bool = False

    def mask(self, means) -> np.ndarray:
        """(N,) bool over the model's centres (N, 3)."""
        from training.model.selection import box_mask, load_mask, sphere_mask

        means = np.asarray(means)
        if self.kind == "mask":
            chosen = load_mask(self.path, len(means))
        elif self.kind == "box":
            chosen = box_mask(means, self.values[:3], self.values[3:])
        else:
            chosen = sphere_mask(means, self.values[:3], self.values[3])
        return ~chosen if self.invert else chosen

    def describe(self) -> str:
        """The flags as typed: ``--mask FILE``, ``--box``, ``--sphere``, with `` --invert``."""
        flag = f"--mask {self.path}" if self.kind == "mask" else f"--{self.kind}"
        return flag + (" --invert" if self.invert else "")


def region_from_args(args: argparse.Namespace) -> Region | None:
    """The region the flags name, checked (one line naming the flag), or None when none is given."""
    from training.model.selection import parse_floats

    mask, box, sphere = getattr(args, "mask", None), args.box, args.sphere
    if mask is None and box is None and sphere is None:
        if args.invert:
            raise InputError(None, f"--invert needs {'--mask, ' if hasattr(args, 'mask') else ''}--box or --sphere")
        return None
    if mask is not None:
        return Region("mask", path=Path(mask), invert=args.invert)
    if box is not None:
        return Region("box", parse_floats(box, 6, "--box"), invert=args.invert)
    values = parse_floats(sphere, 4, "--sphere")
    if values[3] < 0:
        raise InputError(None, f"--sphere radius must be >= 0, got {values[3]}")
    return Region("sphere", values, invert=args.invert)
