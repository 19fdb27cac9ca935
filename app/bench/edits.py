"""``splatstyler bench edits``: what the colour edits, style strength, transforms and project files cost on models
of the sizes a viewer shows, against copying the model's SH coefficients once (the least any edit that writes new
coefficients costs) measured in the same run.

Rows: operation, Gaussians, SH degree, seconds (best of ``--repeat``), the reference's seconds and the ratio.
Random models (the arithmetic does not depend on the values). Timings come from a shared machine unless you know
otherwise: take them as noisy.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

DEFAULT_SIZES = "100000,1000000"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sizes", default=DEFAULT_SIZES, help=f"comma-separated Gaussian counts (default "
                                                                  f"{DEFAULT_SIZES})")
    parser.add_argument("--sh-degree", type=int, choices=range(4), default=3, help="SH degree (default 3)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per case, best kept (default 3)")


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run(args: argparse.Namespace) -> list[dict]:
    import numpy as np
    import torch

    from app.project import FileRef, ModelEntry, Project, open_project, save_project
    from training.model.colour_edit import ColourAdjustment, ColourEdits
    from training.model.gaussians import Gaussians
    from training.model.ply_io import write_ply
    from training.model.transform import transform_gaussians

    rows = []
    k = (args.sh_degree + 1) ** 2
    for n in (int(s) for s in args.sizes.split(",") if s.strip()):
        rng = np.random.default_rng(0)
        sh = rng.standard_normal((n, k, 3)).astype(np.float32)
        original = rng.standard_normal((n, k, 3)).astype(np.float32)
        region = rng.random(n) > 0.5
        adjust = ColourAdjustment(brightness=0.05, saturation=0.2, hue=20.0)
        reference = _best(lambda: sh.copy(), args.repeat)
        g = Gaussians(*(torch.from_numpy(rng.standard_normal(shape).astype(np.float32))
                        for shape in ((n, 3), (n, 3), (n, 4), (n,))), torch.from_numpy(sh[:, :1].copy()),
                      torch.from_numpy(sh[:, 1:].copy()), args.sh_degree)
        turn = np.eye(4)
        turn[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
        cases = {
            "colour, every Gaussian": lambda: ColourEdits([(None, adjust)]).apply(sh),
            "colour, half (a region)": lambda: ColourEdits([(region, adjust)]).apply(sh),
            "style strength 0.5": lambda: ColourEdits(strength=0.5).apply(sh, original_sh=original),
            "transform (rotation, SH rotated)": lambda: transform_gaussians(g, turn),
        }
        for name, fn in cases.items():
            seconds = _best(fn, args.repeat)
            rows.append({"operation": name, "gaussians": n, "sh_degree": args.sh_degree, "seconds": seconds,
                         "copy_sh_s": reference, "ratio": seconds / reference})
        with tempfile.TemporaryDirectory() as tmp:
            model = Path(tmp) / "m.ply"
            write_ply(model, g)
            half = np.arange(0, n, 2)
            project = Project([ModelEntry(FileRef(model), kept=half, selected=np.zeros(len(half), bool),
                                          hidden=np.zeros(len(half), bool), colour=ColourEdits([(region, adjust)]))])
            path = Path(tmp) / "p.splatproj"
            for name, fn in (("save project (model hashed)", lambda: save_project(path, project)),
                             ("open project (hash checked)", lambda: open_project(path))):
                seconds = _best(fn, 1)
                rows.append({"operation": name, "gaussians": n, "sh_degree": args.sh_degree, "seconds": seconds,
                             "copy_sh_s": reference, "ratio": seconds / reference,
                             "file_bytes": path.stat().st_size})
    return rows
