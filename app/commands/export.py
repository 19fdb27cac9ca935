"""``splatstyler export IN -o OUT``: write a Gaussian model (or a selection of it) as PLY, compressed PLY or .splat.

IN is a 3DGS PLY (or a .splat file). OUT's name picks the format (``--format`` overrides it): ``*.compressed.ply``
(PlayCanvas's chunked compressed PLY, which SuperSplat and the PlayCanvas engine load: 16 bytes per Gaussian plus
3 per SH coefficient kept), ``*.ply`` (standard 3DGS layout; all 45 f_rest, zero-padded, unless ``--compact-sh``),
``*.splat`` (web viewers; colour from the SH DC term only). ``--sh-bands B`` keeps SH bands 0..B. A selection
(``--mask FILE``, ``--box``, ``--sphere``, with ``--invert``) writes only those Gaussians. The size of the file is
printed before it is written; ``--dry-run`` prints it and writes nothing.

``--project P`` (instead of IN) bakes a project file (``*.splatproj``, app/project.py) with no display: its models'
kept rows, transforms, the scene's up axis and scale, colour adjustments and style strength, merged into one
model (app/project_bake.py); hidden Gaussians are written too unless ``--without-hidden``. A model file of the
project that is missing or changed is one line naming it (exit 2).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.region_flags import add_region_flags, region_from_args

OUTPUT_FORMATS = (".splat", ".ply")


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "export",
        help="write a model (or a selection) as PLY, compressed PLY or .splat, with a choice of SH bands",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("input", type=Path, metavar="IN", nargs="?", default=None,
                        help="3DGS .ply (or .splat) file (or --project)")
    parser.add_argument("--project", type=Path, default=None, metavar="P",
                        help="bake this project file (.splatproj) instead: its edits, transforms, colour "
                             "adjustments and style strength applied, its models merged")
    parser.add_argument("--without-hidden", action="store_true",
                        help="with --project: leave out the Gaussians hidden in the project")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="output file: .ply, .compressed.ply or .splat (written atomically)")
    parser.add_argument("--format", choices=("ply", "compressed-ply", "splat"), default=None,
                        help="output format (default: from OUT's name)")
    parser.add_argument("--sh-bands", "--sh-degree", dest="sh_degree", type=int, choices=range(4), default=None,
                        metavar="B", help="keep SH bands up to B (0..3, at most the input's); default: all the "
                                          "input and the format hold")
    parser.add_argument("--compact-sh", action="store_true",
                        help="PLY: write only the kept bands' f_rest instead of all 45 zero-padded (smaller; some "
                             "older viewers expect 45)")
    add_region_flags(parser, "export")
    parser.add_argument("--dry-run", action="store_true", help="print what would be written and its size; write "
                                                               "nothing")
    parser.set_defaults(func=run)


def read_model(path: Path):
    """A .ply or .splat model; InputError for anything else."""
    from app.render_inputs import detect_kind
    from training.core.errors import InputError

    kind = detect_kind(path)
    if kind == "ply":
        from training.model.ply_io import read_ply

        return read_ply(path)
    if kind == "splat":
        from training.model.splat_io import read_splat

        return read_splat(path)
    raise InputError(path, "is not a Gaussian model file (.ply or .splat)")


def baked_project(path: Path, drop_hidden: bool):
    """The project's models baked into one; its first model problem is the error, other problems warnings."""
    import sys

    from app.project import open_project
    from app.project_bake import bake_project, model_problem
    from training.core.errors import InputError

    project, problems = open_project(path)
    for entry in project.models:
        problem = model_problem(entry)
        if problem is not None:
            raise InputError(None, problem)
    for line in problems:
        print(f"warning: {line}", file=sys.stderr)
    return bake_project(project, drop_hidden)


def run(args: argparse.Namespace) -> int:
    from training.core.errors import InputError
    from training.model.export import FORMAT_NAMES, export_size, format_for_path, human_size, write_export

    fmt = args.format or format_for_path(args.output)
    if fmt is None:
        raise InputError(args.output, f"unknown output format '{args.output.suffix}'; use .ply, .compressed.ply or "
                                      ".splat (or --format)")
    if args.output.is_dir():
        raise InputError(args.output, "is a folder; give an output file name ending in .ply, .compressed.ply or "
                                      ".splat")
    if (args.input is None) == (args.project is None):
        raise InputError(None, "give a model file IN or --project P (one of them)")
    if args.without_hidden and args.project is None:
        raise InputError(None, "--without-hidden applies to --project")
    source = args.input if args.project is None else args.project
    region = region_from_args(args)  # checked before the model is read
    g = read_model(args.input) if args.project is None else baked_project(args.project, args.without_hidden)
    if args.sh_degree is not None:
        if fmt == "splat" and args.sh_degree > 0:
            raise InputError(None, "--sh-bands above 0 needs PLY output (.splat holds no SH beyond the colour)")
        if args.sh_degree > g.sh_degree:
            raise InputError(source, f"holds SH degree {g.sh_degree}; --sh-bands {args.sh_degree} cannot "
                                         "add degrees")
    bands = min(g.sh_degree, 0 if fmt == "splat" else 3) if args.sh_degree is None else args.sh_degree
    mask = None if region is None else region.mask(g.means.numpy())
    count = len(g) if mask is None else int(mask.sum())
    if count == 0:
        raise InputError(None, f"the selection holds none of the model's {len(g)} Gaussians: nothing to export")
    size = export_size(fmt, bands, count, pad_sh=not args.compact_sh)
    what = f"{count} of {len(g)} Gaussians" if mask is not None else f"{count} Gaussians"
    line = (f"{args.output}: {FORMAT_NAMES[fmt]}, {what}, SH bands {bands}, {human_size(size)} ({size} bytes, "
            f"{size / count:.1f} per Gaussian)")
    if args.dry_run:
        print(f"would write {line}")
        return 0
    print(f"writing {line}", flush=True)
    write_export(args.output, g, fmt, bands, mask, pad_sh=not args.compact_sh)
    print(f"wrote {args.output} ({count} Gaussians, "
          + ("SH degree 0 colour only" if fmt == "splat" else f"SH degree {bands}") + ")")
    return 0
