"""``splatstyler sfm PHOTOS -o DATA``: cameras and sparse points for a folder of photos (pycolmap)."""

from __future__ import annotations

import argparse

from app.commands import add_run_flags


def register(sub: argparse._SubParsersAction) -> None:
    from training.scene.sfm import CAMERA_MODELS, DEFAULT_MAX_FEATURES, DEFAULT_MAX_SIZE, MIN_POINTS

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
    parser.add_argument("--max-size", type=int, default=DEFAULT_MAX_SIZE, metavar="PX",
                        help=f"shrink photos so the long side is at most PX pixels (default {DEFAULT_MAX_SIZE})")
    parser.add_argument("--max-features", type=int, default=DEFAULT_MAX_FEATURES, metavar="N",
                        help=f"SIFT features per photo at most (default {DEFAULT_MAX_FEATURES}; 1024-2048 is faster "
                             "on small photos)")
    parser.add_argument("--matcher", choices=("auto", "exhaustive", "sequential"), default="auto",
                        help="auto: exhaustive for up to 50 photos, sequential (name order) above")
    parser.add_argument("--camera-model", choices=CAMERA_MODELS, default="SIMPLE_RADIAL",
                        help="lens model shared by photos of one size: SIMPLE_RADIAL (default: focal + one "
                             "radial term), OPENCV (two focals, principal point, 4 distortion terms: wide or "
                             "strongly distorted lenses), PINHOLE (already undistorted photos)")
    parser.add_argument("--refine-principal-point", action="store_true",
                        help="let bundle adjustment move the principal point off the image centre (better "
                             "rotations when the true one is off centre; needs many photos to be stable)")
    parser.add_argument("--verbose", action="store_true", help="show COLMAP's own log lines")
    parser.add_argument("--allow-partial", action="store_true",
                        help=f"keep a model that placed fewer than half the photos or has fewer than "
                             f"{MIN_POINTS} points (by default that is a failure: exit 1, nothing written)")
    add_run_flags(parser, progress="no progress bars (preparing the photos, features, matching, registering)",
                  no_resume="a run builds in a work folder inside DATA and starts afresh")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from training.scene.sfm import SfmFailed, result_lines, run_sfm, summary_line

    try:
        result = run_sfm(args.photos, args.output, max_size=args.max_size, max_features=args.max_features,
                         matcher=args.matcher, log=lambda line: print(line, flush=True),
                         progress=sys.stderr.isatty() and not args.no_progress, verbose=args.verbose,
                         camera_model=args.camera_model, refine_principal_point=args.refine_principal_point, allow_partial=args.allow_partial)
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
