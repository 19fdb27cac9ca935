"""``splatstyler bench reconstruct``: iterations per second of the quick preset, with a per-phase breakdown.

Runs the Reconstructor for ``--iters`` iterations (after ``--warmup`` untimed ones, which also compile the numba
kernels) on the demo scene (rendered on the fly) or a scene given with ``--scene``, once per rasterizer backend in
``--backends``; the torch backend is the reference the fast one is compared against. By default training starts
from the initial model; ``--checkpoint OUT/checkpoint.pt`` (a ``reconstruct`` run's, made from ``--scene``) starts
from that model, its optimiser and its place in the schedule instead, so the steps timed are the ones a real run
spends most of its time in (the fox's quick preset: 60k Gaussians from step 2500 on).

Columns are mean milliseconds per iteration of the trainer's phases (Reconstructor.step: checks, rasterize, loss,
ssim, depth, shape, size, backward, optimizer, densify), ``other`` (the rest of the step: picking the view, the
PSNR shown in the progress line, events), and for the cpu backend the rasterizer's own stages (``raster_*``:
project, sort, sh, composite in the forward; composite_bwd and project_sh_bwd inside ``backward``).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", default=None, metavar="PATH",
                        help="scene to train on (default: the built-in demo scene, 24 views at 256x192)")
    parser.add_argument("--downscale", type=int, default=None,
                        help="image downscale for --scene (default: the quick preset's size, or the checkpoint's)")
    parser.add_argument("--checkpoint", default=None, metavar="CKPT",
                        help="start from this reconstruct checkpoint (OUT/checkpoint.pt of a run on --scene): its "
                             "model, optimiser, schedule position and settings")
    parser.add_argument("--iters", type=int, default=300, help="timed iterations (default 300)")
    parser.add_argument("--warmup", type=int, default=10, help="untimed iterations first (default 10)")
    parser.add_argument("--backends", default="cpu,torch",
                        help="comma-separated rasterizer backends to time (default cpu,torch)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")


def _demo_scene():
    from assets.demo.scene import make_demo_scene
    from training.scene.scene import Scene

    d = make_demo_scene(num_views=24, width=256, height=192, num_points=4000)
    return Scene(d.cameras, d.images, points=d.points, point_colors=d.point_colors)


def run(args) -> list[dict]:
    import time
    from dataclasses import replace

    import torch

    from training.core.errors import InputError
    from training.core.run_estimate import load_average
    from training.reconstruct.config import ReconstructConfig
    from training.reconstruct.trainer import PHASES, Reconstructor

    if args.threads:
        torch.set_num_threads(args.threads)
    state = None
    cfg0 = ReconstructConfig.from_preset("quick", device="cpu")
    if args.checkpoint:
        if not args.scene:
            raise InputError(None, "--checkpoint needs the --scene it was trained on")
        from training.reconstruct.checkpoint import load_checkpoint

        state = load_checkpoint(args.checkpoint)
        cfg0 = ReconstructConfig.from_dict(state["config"])
    if args.scene:
        from training.reconstruct.resolution import training_downscale
        from training.scene.loader import load_scene

        downscale = args.downscale or (cfg0.downscale if state is not None else
                                       training_downscale(args.scene, cfg0.max_side, cfg0.downscale))
        scene = load_scene(args.scene, downscale=downscale)
        name = str(args.scene)
    else:
        scene = _demo_scene()
        name = "demo"
    rows = []
    for backend in [b.strip() for b in args.backends.split(",") if b.strip()]:
        cfg = replace(cfg0, densify=replace(cfg0.densify), device="cpu", backend=backend)
        trainer = Reconstructor(scene, cfg)
        if state is not None:
            trainer.load_state_dict(state)
        step0 = trainer.step_count
        for _ in range(args.warmup):
            trainer.step()
        phases = dict.fromkeys(PHASES, 0.0)
        raster: dict[str, float] = {}
        load_before = load_average()
        t0 = time.perf_counter()
        for _ in range(args.iters):
            m = trainer.step()
            for k in phases:
                phases[k] += m["times"].get(k, 0.0)
            for k, v in m.get("raster_times", {}).items():
                raster[k] = raster.get(k, 0.0) + v
        total = time.perf_counter() - t0
        n = max(args.iters, 1)
        cam = scene.cameras[scene.train_indices[0]]
        rows.append({
            "scene": name, "size": f"{cam.width}x{cam.height}", "backend": backend,
            "steps": f"{step0 + args.warmup + 1}-{step0 + args.warmup + n}",
            "it_per_s": n / total,
            **{f"ms_{k}": 1000.0 * v / n for k, v in phases.items()},
            "ms_other": 1000.0 * (total - sum(phases.values())) / n,
            "ms_total": 1000.0 * total / n,
            **{f"ms_raster_{k}": 1000.0 * v / n for k, v in raster.items()},
            "gaussians_end": len(trainer.gaussians),
            "threads": torch.get_num_threads(),
            "load_1min": (load_before or [None])[0],
        })
    return rows
