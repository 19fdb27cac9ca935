"""``splatstyler video MODEL (--path PATH.json | --orbit | --dataset) -o OUT.mp4|OUT_DIR``: render a camera path
through the viewer's renderer (renderer_gl) with no display, into an MP4 (H.264 by the ffmpeg inside the
imageio-ffmpeg wheel) or a folder of PNG frames.

Paths: ``--path`` a keyframe file (the viewer's "save path", app/camera_path.py); ``--orbit`` a loop around the
model (fitted to the dataset's cameras with ``--data``); ``--dataset`` the dataset's cameras in order (needs
``--data``). ``--split-with ORIGINAL.ply`` renders a before/after video: ORIGINAL left of a divider, MODEL right.
Ctrl-C leaves no MP4 behind (it is renamed into place only when complete); a PNG folder keeps the frames already
finished.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.commands import add_run_flags
from training.model.formats import MODEL_FILE

DEFAULT_SIZE = (960, 540)


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("video", help="render a camera path (keyframes, orbit, dataset) to MP4 or PNG frames, "
                                          "headless", description=__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", type=Path, metavar="MODEL",
                        help=MODEL_FILE)
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--path", type=Path, default=None, metavar="PATH.json", help="camera path file")
    which.add_argument("--orbit", action="store_true", help="a loop around the model")
    which.add_argument("--dataset", action="store_true", help="the dataset's cameras in order (needs --data)")
    parser.add_argument("--data", type=Path, default=None, help="scene folder: its cameras fit the orbit, or are "
                                                                "the --dataset path")
    parser.add_argument("--downscale", type=int, default=1, help="the scene's --downscale (camera sizes)")
    parser.add_argument("--size", default=None, metavar="WxH",
                        help=f"frame size (default: the path's; an orbit {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]}); "
                             "even sides for MP4")
    parser.add_argument("--fps", type=float, default=None, help="frames per second (default: the path's, else 30)")
    parser.add_argument("--seconds", type=float, default=None,
                        help="length (default: the path's; an orbit 8 s; the dataset 0.25 s per camera)")
    parser.add_argument("--elevation", type=float, default=20.0, help="orbit elevation in degrees (default 20)")
    parser.add_argument("--split-with", type=Path, default=None, metavar="ORIGINAL",
                        help="before/after: ORIGINAL left of the divider, MODEL right")
    parser.add_argument("--background", default="0,0,0", metavar="R,G,B", help="background colour in 0..1")
    parser.add_argument("--sh-degree", type=int, choices=range(4), default=3, metavar="D",
                        help="evaluate SH up to degree D (default 3: all the model has)")
    parser.add_argument("--backend", choices=("auto", "egl", "osmesa"), default="auto",
                        help="OpenGL with no display: EGL, OSMesa, or auto")
    parser.add_argument("--save-path", type=Path, default=None, metavar="PATH.json",
                        help="also write the camera path used (e.g. an orbit, to edit in the viewer)")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                        help="OUT.mp4, or a folder for PNG frames (frame_00000.png, ...)")
    add_run_flags(parser, no_resume="frames render in milliseconds; a stopped MP4 is not kept, a PNG folder keeps "
                                    "its finished frames")
    parser.set_defaults(func=run)


def build_path(args: argparse.Namespace, means, opacities, size):
    """The camera path the arguments ask for, with --fps/--seconds applied."""
    from app.camera_path import CameraPath, dataset_path, orbit_around
    from training.core.errors import InputError

    scene = None
    if args.data is not None:
        from training.scene.loader import load_scene

        scene = load_scene(args.data, downscale=args.downscale, load_images=False)
        if not scene.cameras:
            raise InputError(args.data, "has no cameras")
    fps = args.fps if args.fps is not None else 30.0
    if args.path is not None:
        path = CameraPath.load(args.path)
        if args.fps is not None:
            path.fps = args.fps
    elif args.dataset:
        if scene is None:
            raise InputError(None, "--dataset needs --data (the scene whose cameras to follow)")
        path = dataset_path(scene.cameras, seconds=args.seconds, fps=fps)
    else:
        import math

        w, h = size or DEFAULT_SIZE
        fov = 50.0
        if scene is not None:  # the dataset camera's horizontal field of view
            c = scene.cameras[0]
            fov = math.degrees(2 * math.atan(0.5 * c.width / c.fx))
        path = orbit_around(means, opacities, scene.cameras if scene is not None else None, width=w, height=h,
                            fov_deg=fov, elevation_deg=args.elevation, seconds=args.seconds or 8.0, fps=fps)
    if args.seconds is not None:
        path.duration = args.seconds
    path.validate(args.path)
    return path


def run(args: argparse.Namespace) -> int:
    from app.camera_path import CameraPath  # noqa: F401  (fail early on a broken install, before the model loads)
    from app.render_inputs import load_model_arrays, parse_background, parse_size
    from app.video_output import is_video_file, write_path_video
    from training.core.errors import InputError

    size = parse_size(args.size)
    background = parse_background(args.background)
    out = args.output
    if is_video_file(out):
        if out.is_dir():
            raise InputError(out, "is a folder; give a file name ending in .mp4, or a folder name for PNG frames")
    elif out.suffix:
        raise InputError(out, f"unknown video format '{out.suffix}'; give OUT.mp4, or a folder name for PNG frames")
    elif out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")
    if args.fps is not None and not 0 < args.fps <= 240:
        raise InputError(None, f"--fps must be in (0, 240], got {args.fps}")
    if args.seconds is not None and not args.seconds > 0:
        raise InputError(None, f"--seconds must be positive, got {args.seconds}")

    arrays = load_model_arrays(args.model)
    other = load_model_arrays(args.split_with) if args.split_with is not None else None
    path = build_path(args, arrays[0], arrays[3], size)
    width, height = size or (path.keyframes[0].width, path.keyframes[0].height)
    if is_video_file(out) and (width % 2 or height % 2):
        raise InputError(None, f"MP4 (H.264, yuv420p) needs even sides; {width}x{height} is not (use --size)")
    if args.save_path is not None:
        path.save(args.save_path)
    cameras = path.cameras(width, height)

    from renderer_gl import SplatRenderer, create_context

    try:
        ctx = create_context(args.backend)
    except RuntimeError as exc:
        raise InputError(None, f"--backend {args.backend}: {exc}") from None
    renderer = SplatRenderer(ctx, sort_tolerance_deg=0.0)  # every frame sorted for its own view: no stale order
    from tqdm import tqdm

    from app.progress import redraw_timing

    bar = tqdm(total=len(cameras), desc="video", unit="frame", dynamic_ncols=True, disable=args.no_progress,
               **redraw_timing())
    try:
        if other is not None:  # the divider shows slot 0 left: the original (before) there, MODEL (after) right
            renderer.set_splats(*other[:5], other[5], slot=0)
            renderer.set_splats(*arrays[:5], arrays[5], slot=1)
        else:
            renderer.set_splats(*arrays[:5], arrays[5], slot=0)
        stats = write_path_video(renderer, cameras, out, width, height, path.fps,
                                 progress=lambda i, n: bar.update(1), split=0.5 if other is not None else None,
                                 background=background, max_sh_degree=args.sh_degree)
    finally:
        bar.close()
        renderer.release()
        ctx.release()
    kind = "MP4" if is_video_file(out) else "PNG frames"
    print(f"wrote {out} ({kind}, {stats['frames']} frames {width}x{height} at {path.fps:g} fps, "
          f"{path.duration:g} s); {1000 * stats['seconds_per_frame']:.1f} ms per frame "
          f"({1000 * stats['render_seconds_per_frame']:.1f} ms rendering)")
    return 0
