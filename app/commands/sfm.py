"""``splatstyler sfm PHOTOS -o DATA``: cameras and sparse points for a folder of photos (pycolmap)."""

from __future__ import annotations

import argparse

from app.commands import add_run_flags
from app.settings import sfm as settings


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "sfm", help="structure from motion: photos folder -> COLMAP scene folder (images/ + sparse/0)",
        description="Run pycolmap on a folder of photos: SIFT features, matching (exhaustive for up to 50 photos, "
                    "sequential in name order above), incremental mapping (retried with relaxed initialisation "
                    "when it finds no initial pair or places fewer than half the photos), undistortion. Writes "
                    "DATA/images, DATA/sparse/0, DATA/database.db and DATA/sfm_report.json (quality summary), "
                    "which `splatstyler reconstruct DATA` reads. DATA appears only when complete: a failed, "
                    "interrupted or killed run leaves nothing in the way of the next.")
    parser.add_argument("photos", metavar="PHOTOS", help="folder holding the photos (PNG, JPEG, TIFF, EXR, ...)")
    parser.add_argument("-o", "--output", metavar="DATA", required=True,
                        help="scene folder to create (must not already hold images/ or sparse/)")
    settings.add_arguments(parser)
    add_run_flags(parser, progress="no progress bars (preparing the photos, features, matching, registering)",
                  no_resume="a run builds in a work folder inside DATA and starts afresh")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from training.scene.sfm import SfmFailed, result_lines, run_sfm, summary_line

    try:
        result = run_sfm(args.photos, args.output, log=lambda line: print(line, flush=True),
                         progress=sys.stderr.isatty() and not args.no_progress, **settings.sfm_options(args))
    except SfmFailed as exc:
        print(summary_line(exc.result.report))
        for note in result_lines(exc.result)[1]:
            print(f"note: {note}", file=sys.stderr)
        print(f"splatstyler: error: {exc}", file=sys.stderr)
        return 1
    lines, notes = result_lines(result)
    for line in lines:
        print(line)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    return 0
