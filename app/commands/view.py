"""``splatstyler view [MODEL | PHOTOS] [--data DATA] [--style PAINTING]``: the live viewer.

Given a folder of photos (PHOTOS, with no cameras yet), the window takes them to a stylized scene: structure from
motion (as `splatstyler sfm`: the registered cameras and the sparse points appear in the view as COLMAP places
them), the reconstruction (as `splatstyler reconstruct`) and, with --style, the stylization (as `splatstyler
stylize`), each writing what its command writes into the output folder (scene/, reconstruction/, stylized/), and a
project recording them (project.splatproj). Stop, closing the window, Ctrl+Q or SIGTERM during structure from motion
leave no half-made scene folder. File > New from photos... and a folder of photos dropped on the window start the
same from inside the window, after a dialog of the settings.

Opens a window with the model (any model file `export` writes), the dataset's cameras and the
painting; from its panels a reconstruction or a stylization runs live beside the view, with sliders for the
stylization's settings. ``--run`` starts one at once. In the Edit panel a gizmo (keys G, T, Y) moves, turns and scales the selection, the
crop box or one model of the scene; File > Add model (or a model file dropped on the window while a model is open) joins
another model to the scene, to align by the gizmo or by three point pairs and export as one file. Closing the window (or Ctrl-C) stops the trainer and saves: a reconstruction's
checkpoint and PLY, a stylization's current model, under the output folder.

The Edit panel selects (rectangle, brush, lasso, box, sphere; by colour, visible surface, opacity, size and
neighbours), hides, deletes and crops; the Colour panel adjusts brightness, contrast, saturation, hue, temperature
and the style strength on the selection or on everything. All are undoable, and exported and saved as shown.

The "Scale and up" panel gives the scene its real size (two points picked on the model, a known length typed) and
its up axis (a picked floor, a plane fitted around a picked point, or the dataset cameras' mean up); both move the
model and the cameras, undo with Ctrl+Z, are saved in the project and applied by ``export --project``.
"""

from __future__ import annotations

import argparse

from training.model.formats import SUFFIX_LIST


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="open the live viewer (watch and steer reconstruction and stylization)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", nargs="?", default="", metavar="MODEL",
                   help=f"a Gaussian model ({SUFFIX_LIST}), a project (.splatproj) saved "
                        "from the viewer, or a folder of photos (no cameras yet): made into a scene in the window, "
                        "then stylized after --style when given")
    p.add_argument("--data", default="", help="the scene (COLMAP folder or transforms.json): cameras, photos")
    p.add_argument("--style", default="", help="the painting to stylize after")
    p.add_argument("-o", "--output", default="viewer_out", help="where runs and exports are written "
                                                               "(default: viewer_out)")
    p.add_argument("--run", choices=("reconstruct", "stylize", "all"), default=None,
                   help="start at once: reconstruct DATA, stylize MODEL, or both in turn")
    p.add_argument("--preset", choices=("quick", "standard", "paper"), default="quick",
                   help="reconstruction preset, and with PHOTOS the stylization's too (default: quick)")
    p.add_argument("--iters", type=int, default=None, help="reconstruction iterations (default: the preset's)")
    p.add_argument("--downscale", type=int, default=None, help="reconstruction image downscale "
                                                               "(default: the preset's)")
    from training.scene.sfm import CAMERA_MODELS, DEFAULT_MAX_SIZE

    p.add_argument("--max-size", type=int, default=DEFAULT_MAX_SIZE, metavar="PX",
                   help=f"with PHOTOS: structure from motion on the photos shrunk to this long side (as `splatstyler "
                        f"sfm --max-size`; default {DEFAULT_MAX_SIZE})")
    p.add_argument("--camera-model", choices=CAMERA_MODELS, default="SIMPLE_RADIAL",
                   help="with PHOTOS: the lens model (as `splatstyler sfm --camera-model`; default SIMPLE_RADIAL)")
    p.set_defaults(func=run)


def check_arguments(args: argparse.Namespace) -> None:
    """What the command line names is checked before a window opens: one line and exit 2 for a missing or wrong
    file, or for a --run that lacks what it needs."""
    from pathlib import Path

    from app.viewer.live.photos import is_scene, photos_folder
    from training.core.errors import InputError
    from training.model.model_io import checked_format

    if args.model and photos_folder(args.model) is not None:
        from training.scene.sfm import list_photos

        list_photos(photos_folder(args.model))  # at least two
        if args.run:
            raise InputError(None, "--run is for a model or --data: a folder of photos starts at once")
        if args.max_size < 16:
            raise InputError(None, f"--max-size must be at least 16 pixels, got {args.max_size}")
    elif args.model and is_scene(Path(args.model)):
        raise InputError(args.model, "is a scene (it has cameras), not a model: give it as --data")
    elif args.model.lower().endswith(".splatproj"):
        from app.project import open_project

        open_project(args.model, check_hashes=False)  # not a project: one line; moved files are said in the window
    elif args.model:
        checked_format(Path(args.model))
    if args.data:
        from training.scene.loader import load_scene

        if photos_folder(args.data) is not None:
            raise InputError(args.data, "holds photos but no cameras: `splatstyler view "
                                        f"{args.data}` makes a scene of them in the window")

        if not load_scene(args.data, load_images=False).cameras:
            raise InputError(args.data, "the scene has no cameras")
    if args.style:
        from training.stylize.style_image import load_style_image

        load_style_image(args.style)
    needs = {"reconstruct": ("data",), "stylize": ("model", "data", "style"), "all": ("data", "style")}
    names = {"model": "MODEL", "data": "--data", "style": "--style"}
    missing = [names[n] for n in needs.get(args.run, ()) if not getattr(args, n)]
    if missing:
        raise InputError(None, f"--run {args.run} needs {' and '.join(missing)}")


def run(args: argparse.Namespace) -> int:
    import sys

    from training.core import stop

    check_arguments(args)
    with stop.exit_at_once("while the viewer was starting; nothing saved"):  # imports: seconds, nothing to keep
        from app.commands import starting
        from app.viewer.app import ViewerApp, run as run_viewer
        from app.viewer.platform import choose_platform
        from app.viewer.state import Paths

        starting()
    from app.viewer.live.photos import photos_folder
    from app.viewer.state import PhotosState

    photos = None
    if args.model and photos_folder(args.model) is not None:
        photos = PhotosState(folder=args.model, painting=args.style, max_size=args.max_size,
                             camera_model=args.camera_model)
        args.model = ""
    if choose_platform() == "null":
        print("splatstyler view: no display, so the window renders off screen where nobody sees it; for a window "
              "run it on a desktop, over `ssh -X`, or under Xvfb with a VNC server (Ctrl-C or SIGTERM stops and "
              "saves)", file=sys.stderr)
    start = {"all": "demo"}.get(args.run, args.run)
    project = args.model if args.model.lower().endswith(".splatproj") else None
    app = ViewerApp(Paths(model="" if project else args.model, data=args.data, style=args.style, out=args.output),
                    start=start, preset=args.preset, recon_iters=args.iters, downscale=args.downscale, project=project,
                    photos=photos)
    stopped_by = run_viewer(app)
    for path in app.session.saved:
        print(f"saved {path}")
    for line in app.session.notes:  # what a stop left (a stopped SfM: nothing)
        print(line)
    if app.ui.messages.error:
        print(f"splatstyler: last error in the viewer: {app.ui.messages.error}")
    return 128 + stopped_by if stopped_by else 0
