"""``splatstyler export IN -o OUT``: convert a Gaussian model between file formats.

IN is a 3DGS PLY (or a .splat file); OUT's extension picks the format: ``.splat`` (web viewers; colour from the
SH DC term only) or ``.ply`` (standard 3DGS layout; ``--sh-degree`` lowers the SH degree kept, e.g. 0 for colour
without view dependence; the file keeps all 45 f_rest, zeroed, as every PLY we write does for other tools).
"""

from __future__ import annotations

import argparse
from pathlib import Path

OUTPUT_FORMATS = (".splat", ".ply")


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "export",
        help="convert a Gaussian PLY to .splat, or re-save it as PLY with fewer SH degrees",
        description="Convert a 3DGS PLY (or .splat) to .splat or .ply; the output extension picks the format.",
    )
    parser.add_argument("input", type=Path, metavar="IN", help="3DGS .ply (or .splat) file")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="output file, .splat or .ply (written atomically)")
    parser.add_argument("--sh-degree", type=int, choices=range(4), default=None, metavar="D",
                        help="PLY output: keep SH up to degree D (0..3, at most the input's); default: all")
    parser.set_defaults(func=run)


def lower_sh_degree(gaussians, degree: int):
    """The same model keeping SH coefficients up to ``degree`` (<= gaussians.sh_degree)."""
    from training.model.gaussians import Gaussians, num_sh_coeffs

    if degree > gaussians.sh_degree:
        raise ValueError(f"cannot raise SH degree {gaussians.sh_degree} to {degree}")
    params = gaussians.parameters()
    params["shN"] = params["shN"][:, : num_sh_coeffs(degree) - 1].contiguous()
    return Gaussians(**params, sh_degree=degree)


def run(args: argparse.Namespace) -> int:
    from app.commands.info import detect_kind
    from training.core.errors import InputError

    out_fmt = args.output.suffix.lower()
    if out_fmt not in OUTPUT_FORMATS:
        raise InputError(args.output, f"unknown output format '{args.output.suffix}'; use .splat or .ply")
    if args.output.is_dir():
        raise InputError(args.output, "is a folder; give an output file name ending in .splat or .ply")
    kind = detect_kind(args.input)
    if kind == "ply":
        from training.model.ply_io import read_ply

        g = read_ply(args.input)
    elif kind == "splat":
        from training.model.splat_io import read_splat

        g = read_splat(args.input)
    else:
        raise InputError(args.input, "is not a Gaussian model file (.ply or .splat)")

    if args.sh_degree is not None:
        if out_fmt == ".splat":
            raise InputError(None, "--sh-degree applies to .ply output only (.splat holds no SH beyond the colour)")
        if args.sh_degree > g.sh_degree:
            raise InputError(args.input, f"holds SH degree {g.sh_degree}; --sh-degree {args.sh_degree} cannot "
                                         "add degrees")
        g = lower_sh_degree(g, args.sh_degree)

    if out_fmt == ".splat":
        from training.model.splat_io import write_splat

        write_splat(args.output, g)
    else:
        from training.model.ply_io import write_ply

        write_ply(args.output, g)
    print(f"wrote {args.output} ({len(g)} Gaussians, "
          + ("SH degree 0 colour only" if out_fmt == ".splat" else f"SH degree {g.sh_degree}") + ")")
    return 0
