"""The settings of structure from motion (``splatstyler sfm``, a grid's ``sfm = {...}``): their flags, and the
keyword arguments of ``training.scene.sfm.run_sfm`` they give."""

from __future__ import annotations

import argparse
from typing import Sequence


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from training.scene.sfm import CAMERA_MODELS, DEFAULT_MAX_FEATURES, DEFAULT_MAX_SIZE, MIN_POINTS

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


def sfm_options(args: argparse.Namespace) -> dict:
    """``run_sfm``'s settings (all but the folders, the log and the progress bars) the flags give."""
    return {"max_size": args.max_size, "max_features": args.max_features, "matcher": args.matcher,
            "verbose": args.verbose, "camera_model": args.camera_model,
            "refine_principal_point": args.refine_principal_point, "allow_partial": args.allow_partial}


def options_from_flags(flags: Sequence[str] = ()) -> dict:
    """``run_sfm``'s settings as `splatstyler sfm` takes them from ``flags`` (its defaults for the rest): what the
    viewer's SfM stage runs with."""
    from app.settings import parse_flags

    return sfm_options(parse_flags(add_arguments, flags, "sfm flags"))
