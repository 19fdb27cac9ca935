"""CPU time of each phase of a reconstruction step, on any checkout of splatstyler (the before/after tables of
docs/performance.md).

    PYTHONPATH=CHECKOUT python scripts/profile_step.py DATA CHECKPOINT [--step N] [--iters N]

Loads a ``reconstruct`` checkpoint (its model, optimiser and settings) made from DATA, sets the schedule to
``--step``, runs 5 untimed steps, then ``--iters`` timed ones, and prints one JSON line: the process's CPU time (both
cores' together) per step in each phase, measured by wrapping the functions the step calls, so that a checkout
from before the trainer timed its own phases is measured the same way: the forward render and, inside it, the
rasterizer's kernels; SSIM and the regularizers; the whole backward and, inside it, the rasterizer's; Adam; the
finiteness checks; density control. Also the step's wall and CPU time and the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from collections import Counter

import training  # noqa: F401  (sets OMP_WAIT_POLICY before torch loads, as the CLI does)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("data")
    p.add_argument("checkpoint")
    p.add_argument("--step", type=int, default=3000, help="schedule position (default 3000: after densification)")
    p.add_argument("--iters", type=int, default=30)
    args = p.parse_args()
    warnings.simplefilter("ignore")

    import torch

    import training.raster.cpu as cpu
    import training.reconstruct.trainer as trainer_module
    from training.reconstruct.checkpoint import load_checkpoint
    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.loader import load_scene

    cpu_s: Counter = Counter()

    def timed(fn, key):
        def wrapper(*a, **k):
            t = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                cpu_s[key] += time.process_time() - t
        return wrapper

    for name, key in (("render_view", "rasterize"), ("ssim", "ssim"), ("shape_loss", "shape"),
                      ("size_loss", "size")):
        setattr(trainer_module, name, timed(getattr(trainer_module, name), key))
    for name in ("_project_fwd", "_sh_fwd", "_bin", "_pack", "depth_order", "_record_capacity", "_composite_fwd",
                 "_composite_bwd", "_reduce_pairs", "_project_bwd", "_sh_bwd"):
        if hasattr(cpu, name):
            setattr(cpu, name, timed(getattr(cpu, name), f"raster.{name.lstrip('_')}"))
    cpu._RasterizeCPU.backward = staticmethod(timed(cpu._RasterizeCPU.backward, "backward.raster"))
    torch.Tensor.backward = timed(torch.Tensor.backward, "backward")
    Reconstructor._params_finite = timed(Reconstructor._params_finite, "checks")

    state = load_checkpoint(args.checkpoint)
    cfg = ReconstructConfig.from_dict(state["config"])
    scene = load_scene(args.data, downscale=cfg.downscale)
    tr = Reconstructor(scene, cfg)
    tr.load_state_dict(state)
    tr.step_count = args.step
    tr.optimizer.step = timed(tr.optimizer.step, "optimizer")
    tr.strategy.step_post_backward = timed(tr.strategy.step_post_backward, "densify")
    for _ in range(5):
        tr.step()
    cpu_s.clear()
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(args.iters):
        tr.step()
    wall, total = time.perf_counter() - t0, time.process_time() - c0
    out = {k: round(1000 * v / args.iters, 2) for k, v in sorted(cpu_s.items())}
    out.update(step_cpu_ms=round(1000 * total / args.iters, 2), step_wall_ms=round(1000 * wall / args.iters, 2),
               gaussians=len(tr.gaussians), load_1min=os.getloadavg()[0], threads=torch.get_num_threads())
    print(json.dumps(out))


if __name__ == "__main__":
    main()
