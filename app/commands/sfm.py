"""``splatstyler sfm PHOTOS -o DATA``: cameras and sparse points for a folder of photos (pycolmap)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "sfm", help="structure from motion: photos folder -> COLMAP scene folder (images/ + sparse/0)",
        description="Run pycolmap on a folder of photos: SIFT features, matching (exhaustive for up to 50 photos, "
                    "sequential in name order above), incremental mapping, undistortion. Writes DATA/images, "
                    "DATA/sparse/0 and DATA/database.db, which `splatstyler reconstruct DATA` reads.")
    parser.add_argument("photos", metavar="PHOTOS", help="folder holding the photos (PNG, JPEG, TIFF, EXR, ...)")
    parser.add_argument("-o", "--output", metavar="DATA", required=True,
                        help="scene folder to create (must not already hold images/ or sparse/)")
    parser.add_argument("--max-size", type=int, default=1600, metavar="PX",
                        help="shrink photos so the long side is at most PX pixels (default 1600)")
    parser.add_argument("--max-features", type=int, default=8192, metavar="N",
                        help="SIFT features per photo at most (default 8192; 1024-2048 is faster on small photos)")
    parser.add_argument("--matcher", choices=("auto", "exhaustive", "sequential"), default="auto",
                        help="auto: exhaustive for up to 50 photos, sequential (name order) above")
    parser.add_argument("--verbose", action="store_true", help="show COLMAP's own log lines")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from training.scene.sfm import run_sfm

    result = run_sfm(args.photos, args.output, max_size=args.max_size, max_features=args.max_features,
                     matcher=args.matcher, log=lambda line: print(line, flush=True),
                     progress=sys.stderr.isatty(), verbose=args.verbose)
    total = sum(result.seconds.values())
    stages = ", ".join(f"{k} {v:.1f}s" for k, v in result.seconds.items())
    print(f"registered {result.num_registered}/{result.num_photos} photos, {result.num_points} points, "
          f"{result.matcher} matching; {total:.1f} s ({stages})")
    print(f"scene written to {result.output} (images/, sparse/0)")
    if result.num_registered < result.num_photos:
        print(f"note: {result.num_photos - result.num_registered} photos could not be placed and are left out",
              file=sys.stderr)
    return 0
