"""``splatstyler reconstruct DATA -o OUT``: train a 3DGS model with the paper's regularizers.

Writes OUT/point_cloud.ply (standard 3DGS layout), OUT/report.json (metrics and settings), OUT/renders/ and
OUT/contact_sheet.png (each test view's photo beside its render, and the depth; training/reconstruct/results.py)
and OUT/checkpoint.pt (every --checkpoint-every iterations, on Ctrl-C and at the end; ``--resume`` continues from
it): training/reconstruct/pipeline.py's job, the flags app/settings/reconstruct.py's. The checkpoint is kept after a
finished run, on purpose: ``--resume --iters N`` extends the run from it and the demo's window writes the
reconstruction's report from it; it costs about three times the PLY on disk, which --help says, so a user who wants
only the model deletes it. The training resolution comes from the preset's target long side
(training/reconstruct/resolution.py); a time estimate is printed a tenth into the run, when the first large
Gaussians have shrunk, and again whenever it moves by more than 20 % (training/reconstruct/time_estimate.py);
report.json keeps the first one and the actual time.
"""

from __future__ import annotations

import argparse

from app.commands import add_run_flags
from app.settings import reconstruct as settings


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reconstruct",
        help="train a 3D Gaussian Splatting model of a scene (3DGS + depth/shape/size regularizers)",
        description="Train a 3DGS model of DATA (a COLMAP folder or a transforms.json scene) into OUT: "
                    "OUT/point_cloud.ply, OUT/report.json, OUT/checkpoint.pt. The checkpoint is kept when the run "
                    "finishes (the model with the optimiser's state, about three times point_cloud.ply's size): "
                    "--resume --iters N trains on from it, and --resume alone writes the report again; delete it "
                    "once the model is final (the viewer's reconstructions keep theirs too).",
    )
    p.add_argument("data", metavar="DATA", help="scene: COLMAP folder (images/ + sparse/), or transforms.json")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output folder")
    settings.add_arguments(p)
    p.add_argument("--force", action="store_true",
                   help="with --resume: when OUT/checkpoint.pt was made from other data, start afresh (replacing "
                        "it) instead of stopping")
    p.add_argument("--overwrite", action="store_true",
                   help="start afresh in an OUT that holds an interrupted run's checkpoint.pt, replacing it (without "
                        "--resume or --overwrite such an OUT is refused, exit 2: nothing is lost by mistake)")
    p.add_argument("--checkpoint-every", type=int, default=1000, metavar="N",
                   help="save OUT/checkpoint.pt every N iterations (0: only on Ctrl-C and at the end)")
    add_run_flags(p, progress="no progress bar (the time estimates are still printed)",
                  resume="continue from OUT/checkpoint.pt with its settings: --iters may extend the run, "
                         "--backend change the rasterizer and --eval-every, --stop-when-flat the scoring; any other setting given must be the checkpoint's, and "
                         "the checkpoint must have been made from this DATA, else exit 2")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.commands import reconstruct_in_console, starting

    starting()
    reconstruct_in_console(args.data, args.output, settings.config_from_args(args), no_progress=args.no_progress,
                           resume=args.resume, force=args.force, overwrite=args.overwrite,
                           resume_config=lambda saved: settings.resumed_config(args, saved),
                           checkpoint_every=args.checkpoint_every)
    return 0
