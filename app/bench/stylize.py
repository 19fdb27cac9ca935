"""``splatstyler bench stylize``: stylization iterations per second, with the time of each stage of an iteration.

The scene is the procedural demo scene (rendered here at the requested size, a few views) with Gaussians made from
its surface points, and the procedural demo painting unless ``--style`` names one. Each row is one loss/backend:
iterations per second over the timed iterations (after warm-up ones that include compilation and caches), and the
median milliseconds of rasterize (forward), VGG forward (render, plus content/style features when a view starts),
similarity/top-K, Sinkhorn and guide (CCFT's own breakdown, inside "loss"), the VGG backward (the objective's
gradient on the render, its terms apart for the gradient balance), the rasterizer's backward and the optimiser step.

Stylization trains colours only: the cpu rasterizer's backward then skips every geometric term, and it reuses the
frozen geometry's projection and compositing weights while a view lasts (docs/rasterizer.md). Each row also runs
a second Stylizer whose geometry tensors require gradients (means, quats, scales, opacities), which forces the full
backward and rules out that reuse, as in reconstruction; it is reported as ``full_*``, with
``colour_only_speedup`` = colour-only it/s over full it/s. The two take turns, one step each, so a shared
machine's load affects both alike.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--losses", default="ccft,nnfm,gram", help="comma-separated losses (default: all three)")
    parser.add_argument("--backends", default="auto", help="comma-separated rasterizer backends (default: auto)")
    parser.add_argument("--width", type=int, default=256, help="render width (default 256)")
    parser.add_argument("--height", type=int, default=192, help="render height (default 192)")
    parser.add_argument("--points", type=int, default=20000, help="Gaussians (from demo surface points; 20000)")
    parser.add_argument("--views", type=int, default=4, help="views in the trajectory (default 4)")
    parser.add_argument("--iters", type=int, default=20, help="timed iterations per row (default 20)")
    parser.add_argument("--warmup", type=int, default=3, help="untimed iterations first (default 3)")
    parser.add_argument("--sh-degree", type=int, default=3, choices=(0, 1, 2, 3))
    parser.add_argument("--style", default=None, help="style image (default: the procedural demo painting)")
    parser.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))


def run(args: argparse.Namespace) -> list[dict]:
    import copy

    import numpy as np

    from assets.demo.scene import make_demo_scene
    from training.model.gaussian_init import gaussians_from_points
    from training.scene.scene import Scene
    from training.raster.rasterize import resolve_device
    from training.stylize.trainer import StylizeConfig, Stylizer
    from training.stylize.vgg_features import load_vgg16_features

    device = resolve_device(args.device)
    demo = make_demo_scene(num_views=args.views, width=args.width, height=args.height, num_points=args.points,
                           supersample=1)
    scene = Scene(cameras=demo.cameras, images=demo.images, points=demo.points, point_colors=demo.point_colors)
    gaussians = gaussians_from_points(demo.points, demo.point_colors, sh_degree=args.sh_degree)
    if args.style:
        from training.stylize.style_image import load_style_image

        style = load_style_image(args.style)
    else:
        from assets.demo.painting import make_style_image

        style = np.asarray(make_style_image(size=512, seed=0), dtype=np.float32)
    vgg = load_vgg16_features()
    rows = []
    for backend in [b.strip() for b in args.backends.split(",") if b.strip()]:
        for loss in [name.strip() for name in args.losses.split(",") if name.strip()]:
            config = StylizeConfig(loss=loss, preset="quick", max_side=max(args.width, args.height),
                                   iters_per_view=max(1, (args.warmup + args.iters) // args.views),
                                   backend=backend, device=str(device))
            row = {"loss": loss, "backend": backend, "device": str(device), "gaussians": len(gaussians),
                   "size": f"{args.width}x{args.height}"}
            colour = Stylizer(gaussians, scene, style, copy.deepcopy(config), vgg=vgg)
            full = Stylizer(gaussians, scene, style, copy.deepcopy(config), vgg=vgg)
            timed = _time_steps([(colour, []), (full, _train_geometry(full))], args.warmup, args.iters)
            row.update(timed[0])
            row.update({"full_" + key: value for key, value in timed[1].items()})
            row["colour_only_speedup"] = row["it_per_s"] / row["full_it_per_s"]
            rows.append(row)
    return rows


STAGES = ("rasterize", "vgg_forward", "loss", "similarity_topk", "sinkhorn", "guide", "vgg_backward",
          "raster_backward", "optimizer")


def _train_geometry(stylizer) -> list:
    """Make the stylizer's geometry require gradients, so its rasterizer runs the full backward (and autograd
    carries the gradients to these tensors, as a reconstruction step would); returns those tensors."""
    g = stylizer.gaussians
    try:
        tensors = [g.means, g.quats, stylizer.model.scales, stylizer.model.opacities]
    except AttributeError as exc:  # the trainer keeps its render-ready geometry under these names
        raise RuntimeError(f"bench stylize: the Stylizer's geometry is not where the benchmark expects it ({exc})")
    for t in tensors:
        t.requires_grad_(True)
    return tensors


def _time_steps(runs: list, warmup: int, iters: int) -> list[dict]:
    """Steps the (stylizer, geometry) pairs in turn, one step each per round, so that a shared machine's load
    changes affect every variant alike and their ratio stays meaningful; returns one timing dict per pair."""
    import statistics
    import time

    def step(stylizer, geometry):
        for t in geometry:  # the stylizer's optimiser only clears the colours' gradients
            t.grad = None
        return stylizer.step()

    for _ in range(warmup):
        for stylizer, geometry in runs:
            step(stylizer, geometry)
    elapsed = [0.0] * len(runs)
    samples: list[dict[str, list[float]]] = [{} for _ in runs]
    for _ in range(iters):
        for k, (stylizer, geometry) in enumerate(runs):
            t0 = time.perf_counter()
            timings = step(stylizer, geometry)["timings"]
            elapsed[k] += time.perf_counter() - t0
            for key, value in timings.items():
                samples[k].setdefault(key, []).append(value)
    out = []
    for k in range(len(runs)):
        row = {"it_per_s": iters / elapsed[k], "ms_per_it": 1000 * elapsed[k] / iters}
        for key in STAGES:
            if key in samples[k]:
                row[f"{key}_ms"] = 1000 * statistics.median(samples[k][key])
        out.append(row)
    return out
