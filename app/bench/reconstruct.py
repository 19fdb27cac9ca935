"""``splatstyler bench reconstruct``: iterations per second of the quick preset, with a per-phase breakdown.

Runs the Reconstructor from its initial state for ``--iters`` iterations (after ``--warmup`` untimed ones, which
also compile the numba kernels) on the demo scene (rendered on the fly) or a scene given with ``--scene``, once
per rasterizer backend in ``--backends``; the torch backend is the reference the fast one is compared against.
The breakdown columns are mean milliseconds per iteration of: rasterize (forward render), loss (photometric and
regularizer terms), backward, optimizer (Adam step), densify (statistics and density control).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", default=None, metavar="PATH",
                        help="scene to train on (default: the built-in demo scene, 24 views at 256x192)")
    parser.add_argument("--downscale", type=int, default=None,
                        help="image downscale for --scene (default: the quick preset's)")
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

    import torch

    from training.reconstruct.config import ReconstructConfig
    from training.reconstruct.trainer import Reconstructor

    if args.threads:
        torch.set_num_threads(args.threads)
    cfg0 = ReconstructConfig.from_preset("quick", device="cpu")
    if args.scene:
        from training.scene.loader import load_scene

        scene = load_scene(args.scene, downscale=args.downscale or cfg0.downscale)
        name = str(args.scene)
    else:
        scene = _demo_scene()
        name = "demo"
    rows = []
    for backend in [b.strip() for b in args.backends.split(",") if b.strip()]:
        cfg = ReconstructConfig.from_preset("quick", device="cpu", backend=backend)
        trainer = Reconstructor(scene, cfg)
        for _ in range(args.warmup):
            trainer.step()
        phases = {"rasterize": 0.0, "loss": 0.0, "backward": 0.0, "optimizer": 0.0, "densify": 0.0}
        t0 = time.perf_counter()
        for _ in range(args.iters):
            m = trainer.step()
            for k in phases:
                phases[k] += m["times"][k]
        total = time.perf_counter() - t0
        n = max(args.iters, 1)
        cam = scene.cameras[scene.train_indices[0]]
        rows.append({
            "scene": name, "size": f"{cam.width}x{cam.height}", "backend": backend,
            "it_per_s": n / total,
            **{f"ms_{k}": 1000.0 * v / n for k, v in phases.items()},
            "ms_total": 1000.0 * total / n,
            "gaussians_end": len(trainer.gaussians),
            "threads": torch.get_num_threads(),
        })
    return rows
