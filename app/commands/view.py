"""``splatstyler view [MODEL] [--data DATA] [--style PAINTING]``: the live viewer.

Opens a window with the model (a 3DGS PLY or .splat), the dataset's cameras and the painting; from its panels a
reconstruction or a stylization runs live beside the view, with sliders for the stylization's settings.
``--run`` starts one at once. Closing the window (or Ctrl-C) stops the trainer and saves: a reconstruction's
checkpoint and PLY, a stylization's current model, under the output folder.
"""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="open the live viewer (watch and steer reconstruction and stylization)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", nargs="?", default="", metavar="MODEL", help="a Gaussian model (.ply or .splat)")
    p.add_argument("--data", default="", help="the scene (COLMAP folder or transforms.json): cameras, photos")
    p.add_argument("--style", default="", help="the painting to stylize after")
    p.add_argument("-o", "--output", default="viewer_out", help="where runs and exports are written "
                                                               "(default: viewer_out)")
    p.add_argument("--run", choices=("reconstruct", "stylize", "all"), default=None,
                   help="start at once: reconstruct DATA, stylize MODEL, or both in turn")
    p.add_argument("--preset", choices=("quick", "standard", "paper"), default="quick",
                   help="reconstruction preset (default: quick)")
    p.add_argument("--iters", type=int, default=None, help="reconstruction iterations (default: the preset's)")
    p.add_argument("--downscale", type=int, default=None, help="reconstruction image downscale "
                                                               "(default: the preset's)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.viewer.app import Paths, ViewerApp, run as run_viewer

    start = {"all": "demo"}.get(args.run, args.run)
    app = ViewerApp(Paths(model=args.model, data=args.data, style=args.style, out=args.output), start=start,
                    preset=args.preset, recon_iters=args.iters, downscale=args.downscale)
    run_viewer(app)
    for path in app.session.saved:
        print(f"saved {path}")
    if app.error:
        print(f"splatstyler: last error in the viewer: {app.error}")
    return 0
