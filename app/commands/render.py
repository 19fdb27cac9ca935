"""``splatstyler render MODEL.ply [--data DATA] (--camera N | --orbit K) -o OUT``: images of a model through
renderer_gl with no display (EGL, or OSMesa where EGL is absent): what the viewer would show.

One camera (``--camera``: a dataset camera's index or image name) writes OUT itself: PNG, or EXR for float
output (``--mode depth`` gives the expected depth in scene units, other modes linear RGB). ``--orbit K``
writes K views evenly spaced around the model (or the dataset's cameras) into the folder OUT.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from training.model.formats import MODEL_FILE

MODES = ("color", "depth", "alpha", "points", "ellipsoids")
IMAGE_EXTENSIONS = (".png", ".exr")


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "render",
        help="render a model to PNG/EXR with no display (renderer_gl on EGL or OSMesa)",
        description="Render a Gaussian model from a dataset camera or an orbit, headless, through the viewer's "
                    "OpenGL renderer.",
    )
    parser.add_argument("model", type=Path, metavar="MODEL",
                        help=MODEL_FILE)
    parser.add_argument("--data", type=Path, default=None, help="scene folder whose cameras to use")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--camera", default=None, metavar="N",
                       help="dataset camera: index into the scene's cameras, or image name (needs --data)")
    which.add_argument("--orbit", type=int, default=None, metavar="K", help="K views on a circle around the model")
    parser.add_argument("--size", default=None, metavar="WxH",
                        help="image size (default: the dataset camera's, or 640x480 for an orbit without --data)")
    parser.add_argument("--downscale", type=int, default=1, help="the scene's --downscale (camera sizes)")
    parser.add_argument("--mode", choices=MODES, default="color", help="what to draw (default: color)")
    parser.add_argument("--background", default="0,0,0", metavar="R,G,B", help="background colour in 0..1")
    parser.add_argument("--sh-degree", type=int, choices=range(4), default=3, metavar="D",
                        help="evaluate SH up to degree D (default 3: all the model has)")
    parser.add_argument("--split", type=Path, default=None, metavar="OTHER",
                        help="a second model (e.g. the stylized one) shown right of a divider, MODEL left")
    parser.add_argument("--split-position", type=float, default=0.5, help="divider position in 0..1")
    parser.add_argument("--elevation", type=float, default=20.0, help="orbit elevation in degrees")
    parser.add_argument("--backend", choices=("auto", "egl", "osmesa"), default="auto",
                        help="OpenGL with no display: EGL, OSMesa, or auto (EGL, then OSMesa)")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="image file (.png/.exr) for --camera; folder for --orbit")
    parser.add_argument("--format", choices=("png", "exr"), default="png", help="--orbit: image format")
    parser.set_defaults(func=run)


def _dataset_camera(scene, which: str, data: Path):
    from training.core.errors import InputError

    names = [c.name for c in scene.cameras]
    if which in names:
        return scene.cameras[names.index(which)], names.index(which)
    try:
        i = int(which)
    except ValueError:
        raise InputError(data, f"has no camera named {which!r} (give an index 0..{len(names) - 1} or an image "
                               "name)") from None
    if not 0 <= i < len(names):
        raise InputError(data, f"has {len(names)} cameras; --camera {i} is out of range")
    return scene.cameras[i], i


def _resized(v, size):
    return v if size is None else v.resized(*size)


def orbit_views(means, opacities, count: int, size, elevation: float, scene=None):
    """Views around the model: centre and radius from the dataset's cameras when given (their mean up
    direction too), else from the opaque Gaussians' spread."""
    import numpy as np

    from renderer_gl import view
    from training.scene.pose import orbit

    if scene is not None:
        centres = np.stack([c.center for c in scene.cameras])
        target = np.median(means[opacities > 0.5], axis=0) if (opacities > 0.5).any() else means.mean(0)
        radius = float(np.median(np.linalg.norm(centres - target, axis=1)))
        up = -np.mean([c.world_to_camera[1, :3] for c in scene.cameras], axis=0)
        ref = scene.cameras[0]
        w, h = size or (ref.width, ref.height)
        f = ref.fx * w / ref.width
        start = ref.center - target
    else:
        keep = opacities > 0.5 if (opacities > 0.5).sum() >= 10 else np.ones(len(means), bool)
        target = np.median(means[keep], axis=0)
        spread = float(np.percentile(np.linalg.norm(means[keep] - target, axis=1), 90))
        radius = 2.5 * max(spread, 1e-3)
        up = np.array([0.0, -1.0, 0.0])  # COLMAP and 3DGS scenes are mostly y-down
        w, h = size or (640, 480)
        f = 0.5 * w / np.tan(np.radians(25.0))
        start = None
    K = [[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]]
    return [view(world_to_camera=m, K=K, width=w, height=h)
            for m in orbit(target, radius, count, up, elevation_deg=elevation, start=start)]


def _write(path: Path, renderer, v, args, background, fbo_cache: dict) -> None:
    import numpy as np

    from renderer_gl import Offscreen
    from training.scene.image_io import write_image

    if path.suffix.lower() == ".exr":
        if args.mode == "depth":
            out = renderer.render_arrays(v, ("depth",), max_sh_degree=args.sh_degree)
            write_image(path, out["depth"])
        elif args.mode == "alpha":
            write_image(path, renderer.render_arrays(v, ("alpha",))["alpha"])
        elif args.mode == "color" and args.split is None:
            out = renderer.render_arrays(v, ("rgb",), background=background, max_sh_degree=args.sh_degree)
            write_image(path, out["rgb"])
        else:
            from training.core.errors import InputError

            raise InputError(path, f"EXR holds float data: use it with --mode color, depth or alpha "
                                   f"(without --split), or write {args.mode} as .png")
        return
    key = (v.width, v.height)
    if key not in fbo_cache:
        fbo_cache[key] = Offscreen(renderer.ctx, v.width, v.height)
    off = fbo_cache[key]
    split = args.split_position if args.split is not None else None
    renderer.render(v, off.fbo, mode=args.mode, background=background, max_sh_degree=args.sh_degree, split=split)
    write_image(path, off.read().astype(np.float32) / 255.0)


def run(args: argparse.Namespace) -> int:
    from app.render_inputs import load_model_arrays, parse_background, parse_size

    from training.core.errors import InputError
    from training.core import stop

    size = parse_size(args.size)
    background = parse_background(args.background)
    if args.camera is not None and args.data is None:
        raise InputError(None, "--camera needs --data (the scene whose cameras to use); or use --orbit K")
    if args.orbit is not None and not 1 <= args.orbit <= 10_000:
        raise InputError(None, f"--orbit must be 1..10000 views, got {args.orbit}")
    if not 0.0 <= args.split_position <= 1.0:
        raise InputError(None, f"--split-position must be in 0..1, got {args.split_position}")
    if args.camera is not None:
        if args.output.suffix.lower() not in IMAGE_EXTENSIONS:
            raise InputError(args.output, "give an image file name ending in .png or .exr")
        if args.output.is_dir():
            raise InputError(args.output, "is a folder; give an image file name ending in .png or .exr")
    elif args.output.exists() and not args.output.is_dir():
        raise InputError(args.output, "exists and is not a folder (--orbit writes one image per view into a folder)")

    arrays = load_model_arrays(args.model)
    other = load_model_arrays(args.split) if args.split is not None else None
    scene = None
    if args.data is not None:
        from training.scene.loader import load_scene

        scene = load_scene(args.data, downscale=args.downscale, load_images=False)
        if not scene.cameras:
            raise InputError(args.data, "has no cameras")

    from renderer_gl import SplatRenderer, create_context, view

    try:
        ctx = create_context(args.backend)
    except RuntimeError as exc:
        raise InputError(None, f"--backend {args.backend}: {exc}") from None
    renderer = SplatRenderer(ctx, sort_tolerance_deg=0.0)
    renderer.set_splats(*arrays[:5], arrays[5], slot=0)
    if other is not None:
        renderer.set_splats(*other[:5], other[5], slot=1)
    fbos: dict = {}
    try:
        if args.camera is not None:
            cam, index = _dataset_camera(scene, args.camera, args.data)
            _write(args.output, renderer, _resized(view(cam), size), args, background, fbos)
            print(f"wrote {args.output} (camera {index} '{cam.name}', {args.mode})")
        else:
            views = orbit_views(arrays[0], arrays[3], args.orbit, size, args.elevation, scene)
            args.output.mkdir(parents=True, exist_ok=True)
            for i, v in enumerate(views):
                stop.check()
                _write(args.output / f"{args.mode}_{i:04d}.{args.format}", renderer, v, args, background, fbos)
            print(f"wrote {len(views)} {args.format.upper()} images to {args.output} ({args.mode})")
    finally:
        for off in fbos.values():
            off.release()
        renderer.release()
        ctx.release()
    return 0
