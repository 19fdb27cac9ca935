"""``splatstyler stylize SCENE.ply --data DATA --style PAINTING -o OUT``: stylize a reconstruction after a painting.

Writes OUT/point_cloud.ply (standard 3DGS layout, geometry unchanged unless --params all), OUT/renders/*.png (every
view, stylized) and OUT/report.json (losses, time per stage, style-feature utilisation of the last plan, and the
metrics of docs/evaluation.md: multi-view consistency, style distance to the painting relative to the unstylized
renders, structure kept); the last lines printed sum them up.

--mask, --box or --sphere stylizes only the selected Gaussians; every other Gaussian's colour stays bit-identical
(colour transfer included). Run it again on the output with another selection and painting to give several
regions different styles.

Ctrl-C or SIGTERM after the first iteration saves the model so far and OUT/stylize_checkpoint.pt; once the
iterations and the colour transfer are done, both are saved before the metrics and renders. --resume continues
from that checkpoint: the same model, data, painting, selection and the settings fixed at the start (view order,
virtual views, preset, render size, colour transfer, scene kind, seed, --params) are required, while the loss
settings may differ. The checkpoint is removed once the report is written.
"""

from __future__ import annotations

import argparse

from app.commands import add_run_flags
from app.settings import stylize as settings


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("stylize", help="stylize a reconstructed scene after a painting (CCFT, colour only by default)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", metavar="SCENE.ply", help="Gaussian model reconstructed from DATA (3DGS PLY)")
    p.add_argument("--data", required=True, help="the scene the model was reconstructed from (COLMAP folder or "
                                                 "transforms.json)")
    p.add_argument("--style", required=True, help="the painting (any image OpenImageIO reads, at least 64 px)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    settings.add_arguments(p)
    p.add_argument("--force", action="store_true",
                   help="with --resume: when the checkpoint was made from other inputs, start afresh instead of "
                        "stopping")
    p.add_argument("--overwrite", action="store_true",
                   help="start afresh in an OUT that holds an interrupted stylization's stylize_checkpoint.pt, "
                        "replacing it (without --resume or --overwrite such an OUT is refused, exit 2)")
    add_run_flags(p, progress="no progress bar (the time estimates are still printed)",
                  resume="continue the interrupted stylization in OUT (OUT/stylize_checkpoint.pt); it must have been "
                         "made from these inputs and fixed settings, else exit 2")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.commands import starting, stylize_in_console

    starting()
    stylize_in_console(args.model, args.data, args.style, args.output, no_progress=args.no_progress,
                       resume=args.resume, force=args.force, overwrite=args.overwrite,
                       **settings.stylize_options(args, args.model))
    return 0
