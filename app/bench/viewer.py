"""``splatstyler bench viewer``: renderer_gl frame and sort times against the numba CPU rasterizer's forward pass.

For each N (default 10k, 100k, 500k, 1M) at one size (default 1280x720), in one process and one standalone GL
context (EGL unless ``--backend``), on ``app.bench.raster``'s scene (a fixed amount of "stuff" whatever N):

- ``frame_ms``: a frame with the camera still (no sort): splat pass into the float accumulation target, resolve
  into an RGBA8 framebuffer, ``glFinish``; ``frame_cpu_ms`` the process's CPU time over that frame (all cores);
  ``frame_half_ms`` the same at half resolution (the viewer's size while the camera moves); ``frame_moving_ms`` at half resolution drawing the 35% most important Gaussians (the viewer's
  moving-camera preview on software GL); ``frame_f2_ms`` with a half-float accumulation target, ``frame_f1_ms`` with an
  8-bit one (dithered, the default for f1), ``frame_f1_plain_ms`` 8-bit without dithering (these four frame
  columns are timed round-robin, one renderer each); ``frame_instanced_ms`` (or
  ``frame_geometry_ms``) with the quad path that ``quads="auto"`` did not pick (``quads`` names the one it did);
- ``sort_float_ms`` / ``sort_u16_ms``: numpy back-to-front order with exact float keys / 16-bit keys;
  ``upload_ms``: writing that order to the index buffer (with ``glFinish``); ``sort_upload_ms``: the renderer's
  default ("auto") sort plus upload, what a turning camera adds to a frame;
- ``gpu_sort_ms``: the compute-shader bitonic sort (renderer_gl/gpu_sort.py), up to ``--gpu-sort-max`` Gaussians;
- ``path_<path>[/<format>]_ms``: a turning-camera frame (sort included) through each display path this machine can
  run (app/viewer/display/choice.py: GL with the CPU sort, GL with the GPU sort, CUDA), timed by the viewer's own
  chooser; ``display_path``: the one it picks; ``paths_skipped``: why the others were not timed;
- ``cuda_<transfer>_<stage>_ms``: where a frame of the CUDA display path goes (raster, convert, transfer, draw,
  and the whole frame), for the pinned copy and for CUDA-GL interop (app/bench/cuda_frame.py), where torch sees a
  CUDA device; elsewhere ``cuda_breakdown_skipped`` says why. ``--cuda-only`` measures this and the display
  paths alone;
- ``cpu_fwd_ms``: ``rasterize(backend="cpu")`` forward without gradients, same scene and size;
  ``cpu_over_gl``: cpu_fwd_ms / frame_ms.

Times are medians over ``--repeat`` runs after one warm-up. ``--live`` measures the viewer beside a trainer
instead (app/bench/viewer_live.py).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

DEFAULT_NS = (10_000, 100_000, 500_000, 1_000_000)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--n", default=None, help="comma-separated Gaussian counts (default 10k,100k,500k,1M)")
    parser.add_argument("--size", default="1280x720", help="image size WxH (default 1280x720)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per figure after one warm-up")
    parser.add_argument("--backend", choices=("auto", "egl", "osmesa"), default="egl", help="GL context")
    parser.add_argument("--gpu-sort-max", type=int, default=100_000,
                        help="measure the compute-shader sort up to this many Gaussians (slow on software GL)")
    parser.add_argument("--no-cpu", action="store_true", help="skip the CPU rasterizer comparison")
    parser.add_argument("--no-paths", action="store_true",
                        help="skip timing the viewer's display paths (turning-camera frames, as the viewer chooses)")
    parser.add_argument("--cuda-only", action="store_true",
                        help="only the CUDA display path: its frame breakdown (raster, convert, transfer, draw) for "
                             "the pinned copy and CUDA-GL interop, and the display paths as the viewer times them")
    parser.add_argument("--live", action="store_true",
                        help="instead: training steps/s with the viewer window open (camera still, camera moving) "
                             "against headless, and input-to-frame latency (app/bench/viewer_live.py); the trainer "
                             "on CUDA where gsplat is there")
    parser.add_argument("--seconds", type=float, default=20.0, help="--live: seconds measured per run (default 20)")
    parser.add_argument("--data", default=None, metavar="DATA",
                        help="--live: the scene to reconstruct (default: the demo's generated scene)")
    parser.add_argument("--preset", default="quick", help="--live: the reconstruction preset (default quick)")
    parser.add_argument("--style", default=None, metavar="IMAGE",
                        help="--live: also stylize after this painting (from the headless run's reconstruction)")
    parser.add_argument("--stylize-preset", default=None,
                        help="--live: the stylization preset (default: paper where CUDA trains, else quick)")
    parser.add_argument("--phases", default="headless,window_still,window_moving,latency",
                        help="--live: comma-separated subset of headless, window_still, window_moving, latency")
    parser.add_argument("--latency-splats", type=int, default=100_000,
                        help="--live: Gaussians in the model the latency phase shows (default 100k)")
    parser.add_argument("--latency-size", default="960x540", help="--live: the latency phase's window size")


def _median_ms(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000.0 * statistics.median(times)


def _interleaved_median_ms(fns: dict, repeat: int) -> dict[str, float]:
    """Median milliseconds of each function, run in turn (one warm-up round first); for ``frame_ms`` also the
    process's CPU time, ``frame_cpu_ms`` (llvmpipe draws on every core: on a machine other jobs share, a steadier
    figure than the wall time; on free cores frame_ms is about frame_cpu_ms / cores)."""
    times = {k: [] for k in fns}
    cpu = []
    for rnd in range(max(1, repeat) + 1):
        for key, fn in fns.items():
            c0 = time.process_time()
            t0 = time.perf_counter()
            fn()
            if rnd > 0:
                times[key].append(time.perf_counter() - t0)
                if key == "frame_ms":
                    cpu.append(time.process_time() - c0)
    out = {k: 1000.0 * statistics.median(v) for k, v in times.items()}
    if cpu:
        out["frame_cpu_ms"] = 1000.0 * statistics.median(cpu)
    return out


def _snapshot_and_camera(scene, w: int, h: int):
    """The bench scene as a ModelSnapshot, and the bench camera (identity pose, f = 0.9 w) as a ViewerCamera
    orbiting the middle of the scene's box."""
    import numpy as np

    from app.viewer.camera import ViewerCamera
    from training.core.messages import ModelSnapshot

    means, quats, scales, opac, sh = (t.numpy() for t in scene[:5])
    norm = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    snap = ModelSnapshot(1, 1, 0, means, scales, norm, opac, sh, 3)
    fov = float(np.degrees(2 * np.arctan(h / (2 * float(scene[6][1, 1])))))
    return snap, ViewerCamera(np.eye(3), np.zeros(3), 5.0, fov, up=np.array([0.0, -1.0, 0.0]))


def _display_paths(ctx, scene, w: int, h: int, repeat: int) -> dict:
    """Each display path's turning-camera frame (app/viewer/display/choice.py: the viewer's own chooser and
    timings), the one it picks, and why the others were not timed."""
    from app.viewer.display.choice import choose_display_path

    snap, cam = _snapshot_and_camera(scene, w, h)
    choice = choose_display_path(ctx, snap, cam, (w, h), override="auto", frames=max(1, repeat), always_time=True)
    out = {f"path_{label}_ms": ms for label, ms in choice.frame_ms.items()}
    out["display_path"] = choice.label()
    out["paths_skipped"] = "; ".join(f"{k}: {v}" for k, v in choice.skipped.items())
    return out


def _cuda_breakdown(ctx, scene, w: int, h: int, repeat: int) -> dict:
    """Where a frame of the CUDA display path goes (app/bench/cuda_frame.py), or why it cannot be measured here."""
    from app.bench.cuda_frame import frame_breakdown
    from app.viewer.display.choice import unavailable

    why = unavailable("cuda", ctx)
    if why is not None:
        return {"cuda_breakdown_skipped": why}
    snap, cam = _snapshot_and_camera(scene, w, h)
    return frame_breakdown(ctx, snap, cam.camera(w, h), repeat)


def run(args: argparse.Namespace) -> list[dict]:
    from app.render_inputs import parse_size

    if args.live:
        from app.bench.viewer_live import run_live

        return run_live(args.seconds, data=args.data, style=args.style, preset=args.preset,
                        stylize_preset=args.stylize_preset, latency_splats=args.latency_splats,
                        latency_size=args.latency_size,
                        phases=tuple(p.strip() for p in args.phases.split(",") if p.strip()))
    import numpy as np

    from app.bench.raster import bench_scene
    from renderer_gl import Offscreen, SplatRenderer, create_context, view
    from renderer_gl.context import context_backend
    from renderer_gl.sort import back_to_front

    ns = [int(float(v)) for v in args.n.split(",")] if args.n else list(DEFAULT_NS)
    w, h = parse_size(args.size)
    ctx = create_context(args.backend, require=430 if args.gpu_sort_max > 0 and not args.cuda_only else 330)
    gl_name = context_backend(ctx)
    if args.cuda_only:
        rows = []
        for n in ns:
            scene = bench_scene(n, w, h, 3)
            row = {"n": n, "width": w, "height": h, **_cuda_breakdown(ctx, scene, w, h, args.repeat)}
            if not args.no_paths:
                row.update(_display_paths(ctx, scene, w, h, args.repeat))
            row["gl"] = gl_name.split(",")[0]
            rows.append(row)
            print(f"bench viewer: {n} done", file=sys.stderr)
        ctx.release()
        return rows
    off = Offscreen(ctx, w, h)
    rows = []
    for n in ns:
        scene = bench_scene(n, w, h, 3)
        means, quats, scales, opac, sh = (t.numpy() for t in scene[:5])
        K = scene[6].numpy()
        cam = view(world_to_camera=np.eye(4), K=K, width=w, height=h)
        row = {"n": n, "width": w, "height": h}
        r = SplatRenderer(ctx, sort_tolerance_deg=1e9)  # never re-sort inside the frame timings
        t0 = time.perf_counter()
        r.set_splats(means, scales, quats, opac, sh, 3)
        ctx.finish()
        row["set_splats_ms"] = 1000 * (time.perf_counter() - t0)

        def frame(scale=1.0, renderer=r, lod=1.0):
            renderer.render(cam, off.fbo, scale=scale, lod=lod)
            ctx.finish()

        # The accumulation formats are timed round-robin, so that a change in the machine's load (a shared
        # machine) falls on all of them alike rather than on whichever ran at that moment.
        formats = {"frame_f2_ms": dict(accum_dtype="f2"), "frame_f1_ms": dict(accum_dtype="f1"),
                   "frame_f1_plain_ms": dict(accum_dtype="f1", dither=False)}
        others = {key: SplatRenderer(ctx, sort_tolerance_deg=1e9, **options) for key, options in formats.items()}
        for rf in others.values():
            rf.set_splats(means, scales, quats, opac, sh, 3)
        row.update(_interleaved_median_ms({"frame_ms": frame, **{k: (lambda rf=rf: frame(1.0, rf))
                                                                  for k, rf in others.items()}}, args.repeat))
        for rf in others.values():
            rf.release()
        row["frame_half_ms"] = _median_ms(lambda: frame(0.5), args.repeat)
        # the viewer's moving-camera frame on software GL: half resolution, the 35% most important Gaussians
        row["frame_moving_ms"] = _median_ms(lambda: frame(0.5, lod=0.35), args.repeat)
        other = "instanced" if r.quads == "geometry" else "geometry"
        ro = SplatRenderer(ctx, sort_tolerance_deg=1e9, quads=other)
        ro.set_splats(means, scales, quats, opac, sh, 3)
        row[f"frame_{other}_ms"] = _median_ms(lambda: frame(1.0, ro), args.repeat)
        ro.release()
        row["quads"] = r.quads
        model = r._slots[0]
        fwd = cam.forward
        order = back_to_front(model.means, fwd, "float")
        row["sort_float_ms"] = _median_ms(lambda: back_to_front(model.means, fwd, "float"), args.repeat)
        row["sort_u16_ms"] = _median_ms(lambda: back_to_front(model.means, fwd, "u16"), args.repeat)

        def upload():
            model.write_order(order, fwd)
            ctx.finish()

        row["upload_ms"] = _median_ms(upload, args.repeat)

        def sort_upload():
            model.write_order(back_to_front(model.means, fwd, "auto"), fwd)
            ctx.finish()

        row["sort_upload_ms"] = _median_ms(sort_upload, args.repeat)
        if n <= args.gpu_sort_max:
            from renderer_gl.gpu_sort import BitonicDepthSort

            gs = BitonicDepthSort(ctx, means)

            def gpu_sort():
                gs.sort(fwd)
                ctx.finish()

            row["gpu_sort_ms"] = _median_ms(gpu_sort, args.repeat)
            gs.release()
        r.release()
        if not args.no_paths:
            row.update(_display_paths(ctx, scene, w, h, args.repeat))
        row.update(_cuda_breakdown(ctx, scene, w, h, args.repeat))
        if not args.no_cpu:
            import torch

            from training.raster.rasterize import rasterize

            def cpu_forward():
                with torch.no_grad():
                    rasterize(*scene, w, h, sh_degree=3, backend="cpu")

            row["cpu_fwd_ms"] = _median_ms(cpu_forward, max(1, min(args.repeat, 2 if n > 200_000 else args.repeat)))
            row["cpu_over_gl"] = row["cpu_fwd_ms"] / row["frame_ms"]
        row["gl"] = gl_name.split(",")[0]
        row["load1"] = os.getloadavg()[0]
        rows.append(row)
        print(f"bench viewer: {n} done", file=sys.stderr)
    off.release()
    ctx.release()
    return rows
