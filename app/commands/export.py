"""``splatstyler export IN -o OUT``: write a Gaussian model (or a selection of it) as PLY, compressed PLY, .splat,
SPZ or glTF.

IN is any model file ``read_model`` reads (.ply, .compressed.ply, .splat, .spz, .glb). OUT's name picks the format
(``--format`` overrides it): ``*.compressed.ply`` (PlayCanvas's chunked compressed PLY, which SuperSplat and the
PlayCanvas engine load: 16 bytes per Gaussian plus 3 per SH coefficient kept), ``*.ply`` (standard 3DGS layout;
all 45 f_rest, zero-padded, unless ``--compact-sh``), ``*.splat`` (web viewers; colour from the SH DC term only),
``*.spz`` (Niantic's SPZ, about a tenth of a PLY with SH kept; ``--spz-version 4`` (default, the current spec, ZSTD)
or ``3`` (gzip) for older readers), ``*.glb`` (glTF 2.0 with KHR_gaussian_splatting, float32). Axes: each file
opens the right way up where users open it (docs/editor.md, "Axes"): SPZ keeps the model's right-down-forward
(graphdeco's PLY) axes as SuperSplat and splat-transform read SPZ, named in a version 4 file; ``--axes rub``
writes the right-up-back that the SPZ README describes instead (any of the 16 conventions of the reference's
coordinate-system extension is taken). glTF is left-up-front as its spec says. ``--input-axes`` names the axes
of an SPZ input that does not name its own (default rdf; ``rub`` for files that follow the README unlabelled).
``--sh-bands B`` keeps SH bands 0..B. A selection (``--mask FILE``, ``--box``, ``--sphere``, with ``--invert``)
writes only those Gaussians. The size of the file is printed before it is written (SPZ: once compressed);
``--dry-run`` prints it and writes nothing.

``--project P`` (instead of IN) bakes a project file (``*.splatproj``, app/project.py) with no display: its models'
kept rows, transforms, the scene's up axis and scale, colour adjustments and style strength, merged into one
model (app/project_bake.py); hidden Gaussians are written too unless ``--without-hidden``. A model file of the
project that is missing or changed is one line naming it (exit 2).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.region_flags import add_region_flags, region_from_args
from training.model.formats import NAMES


def axes_arg(value: str) -> str:
    """An axes name of training/model/axes.py, any case (imported when the flag is given: --help stays light)."""
    from training.model.axes import axes_name

    try:
        return axes_name(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "export",
        help="write a model (or a selection) as PLY, compressed PLY, .splat, SPZ or glTF (.glb), with a "
             "choice of SH bands",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("input", type=Path, metavar="IN", nargs="?", default=None,
                        help="model file: .ply, .compressed.ply, .splat, .spz or .glb (or --project)")
    parser.add_argument("--project", type=Path, default=None, metavar="P",
                        help="bake this project file (.splatproj) instead: its edits, transforms, colour "
                             "adjustments and style strength applied, its models merged")
    parser.add_argument("--without-hidden", action="store_true",
                        help="with --project: leave out the Gaussians hidden in the project")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="output file: .ply, .compressed.ply, .splat, .spz or .glb (written atomically)")
    parser.add_argument("--format", choices=NAMES, default=None,
                        help="output format (default: from OUT's name)")
    parser.add_argument("--spz-version", type=int, choices=(3, 4), default=None, metavar="3|4",
                        help="SPZ: 4 (default, the current spec: ZSTD streams) or 3 (one gzip stream, for older "
                             "readers)")
    parser.add_argument("--axes", type=axes_arg, default=None, metavar="AXES",
                        help="SPZ: the axes the file stores: rdf (default: the PLY's, as SuperSplat and "
                             "splat-transform read SPZ) or rub (the SPZ README's), or another of the reference's 16 "
                             "(e.g. ruf); named in the file (all but a version 3 file of rdf)")
    parser.add_argument("--input-axes", type=axes_arg, default=None, metavar="AXES",
                        help="an SPZ input that does not name its axes holds these (default rdf; rub for files "
                             "written to the SPZ README's convention without saying so)")
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
    from training.model.export import export_size, human_size, max_sh_bands, write_export
    from training.model.formats import BY_NAME, SUFFIX_LIST, format_for_path
    from training.model.model_io import read_model

    fmt = args.format or format_for_path(args.output)
    if fmt is None:
        raise InputError(args.output, f"unknown output format '{args.output.suffix}'; use {SUFFIX_LIST} (or "
                                      "--format)")
    if args.output.is_dir():
        raise InputError(args.output, f"is a folder; give an output file name ending in {SUFFIX_LIST}")
    if args.spz_version is not None and fmt != "spz":
        raise InputError(None, f"--spz-version applies to SPZ output, not {BY_NAME[fmt].label}")
    if args.axes is not None and fmt != "spz":
        raise InputError(None, f"--axes applies to SPZ output ({BY_NAME[fmt].label} has one convention: "
                               "docs/editor.md, \"Axes\")")
    if (args.input is None) == (args.project is None):
        raise InputError(None, "give a model file IN or --project P (one of them)")
    if args.without_hidden and args.project is None:
        raise InputError(None, "--without-hidden applies to --project")
    source = args.input if args.project is None else args.project
    region = region_from_args(args)  # checked before the model is read
    if args.input_axes is not None and args.project is not None:
        raise InputError(None, "--input-axes applies to a model file IN, not to --project")
    g = read_model(args.input, spz_axes=args.input_axes) if args.project is None \
        else baked_project(args.project, args.without_hidden)
    if args.sh_degree is not None:
        if fmt == "splat" and args.sh_degree > 0:
            raise InputError(None, "--sh-bands above 0 needs a format that holds SH (.splat keeps only the colour)")
        if args.sh_degree > g.sh_degree:
            raise InputError(source, f"holds SH degree {g.sh_degree}; --sh-bands {args.sh_degree} cannot "
                                         "add degrees")
    bands = min(g.sh_degree, max_sh_bands(fmt)) if args.sh_degree is None else args.sh_degree
    mask = None if region is None else region.mask(g.means.numpy())
    count = len(g) if mask is None else int(mask.sum())
    if count == 0:
        raise InputError(None, f"the selection holds none of the model's {len(g)} Gaussians: nothing to export")
    size = export_size(fmt, bands, count, pad_sh=not args.compact_sh)
    what = f"{count} of {len(g)} Gaussians" if mask is not None else f"{count} Gaussians"
    name = BY_NAME[fmt].label + (f" version {args.spz_version or 4}, {args.axes or 'RDF'} axes" if fmt == "spz"
                                else "")
    sized = ("size known once compressed" if size is None
             else f"{human_size(size)} ({size} bytes, {size / count:.1f} per Gaussian)")
    line = f"{args.output}: {name}, {what}, SH bands {bands}, {sized}"
    if args.dry_run:
        print(f"would write {line}")
        return 0
    print(f"writing {line}", flush=True)
    try:
        result = write_export(args.output, g, fmt, bands, mask, pad_sh=not args.compact_sh,
                              spz_version=args.spz_version, spz_axes=args.axes)
    except ValueError as exc:  # what the model holds and the format cannot (SPZ's 24-bit reach): the input's
        raise InputError(source, f"{exc}; {args.output} was not written") from None
    print(f"wrote {args.output} ({count} Gaussians, "
          + ("SH degree 0 colour only" if fmt == "splat" else f"SH degree {bands}")
          + (f", {human_size(result.size)}, {result.size / count:.1f} bytes per Gaussian)" if size is None else ")"))
    return 0
