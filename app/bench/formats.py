"""``splatstyler bench formats``: every model file format's size and write/read time, beside PLY's measured in the
same run, and (with ``--data``) how renders of the model read back from each file compare with the original's.

Rows: format, Gaussians, SH bands kept, bytes (and per Gaussian), size / PLY's size, write and read seconds (best
of ``--repeat``; through ``write_export`` and ``read_model``, as the CLI and the viewer use them) and their ratios
to PLY's, and with ``--data SCENE`` the PSNR of renders (CPU rasterizer, ``--views`` of the scene's cameras, long
side ``--max-side``) of the model read back against renders of the original (inf: identical images). The model is
``--model FILE`` or random Gaussians (``--count``, ``--sh-degree``): sizes of the compressed formats depend on the
values, so random ones show the worst case. Each format is written and read once before timing (gsply compiles its
SPZ kernels on first use). Timings come from a shared machine unless you know otherwise: take them as noisy.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

# (format, spz version, file name)
CASES = [("ply", None, "m.ply"), ("compressed-ply", None, "m.compressed.ply"), ("splat", None, "m.splat"),
         ("spz", 4, "m.spz"), ("spz", 3, "m3.spz"), ("glb", None, "m.glb")]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", type=Path, default=None, metavar="FILE",
                        help="a model file to measure (default: random Gaussians)")
    parser.add_argument("--count", type=int, default=1_000_000, help="random Gaussians (default 1000000)")
    parser.add_argument("--sh-degree", type=int, choices=range(4), default=3, help="random model's SH degree "
                                                                                   "(default 3)")
    parser.add_argument("--repeat", type=int, default=1, help="timed runs per case, best kept (default 1)")
    parser.add_argument("--data", type=Path, default=None, metavar="SCENE",
                        help="also render the model read back from each file at this scene's cameras and give the "
                             "PSNR against the original's renders")
    parser.add_argument("--views", type=int, default=4, help="with --data: cameras rendered, evenly spread "
                                                              "(default 4)")
    parser.add_argument("--max-side", type=int, default=400, help="with --data: long side of the renders in pixels "
                                                                  "(default 400)")


def _best(fn, repeat: int):
    best, out = float("inf"), None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def random_model(count: int, degree: int, seed: int = 0):
    """Random Gaussians of the spread a reconstruction has (centres within a few units, small scales)."""
    import torch

    from training.model.gaussians import Gaussians

    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(count, 3, generator=g) * 2, log_scales=torch.randn(count, 3, generator=g) - 4,
                     quats=torch.randn(count, 4, generator=g), opacity_logits=torch.randn(count, generator=g) * 2,
                     sh0=torch.randn(count, 1, 3, generator=g) * 0.5,
                     shN=torch.randn(count, (degree + 1) ** 2 - 1, 3, generator=g) * 0.1, sh_degree=degree)


def _renderer(data: Path, views: int, max_side: int):
    import numpy as np

    from training.evaluate.measure import render_with_depth
    from training.scene.loader import load_scene

    cams = load_scene(data, load_images=False).cameras
    picked = [cams[i] for i in np.linspace(0, len(cams) - 1, max(1, min(views, len(cams)))).round().astype(int)]
    picked = [c.scaled(min(1.0, max_side / max(c.width, c.height))) for c in picked]
    return lambda g: render_with_depth(g, picked, background=(1.0, 1.0, 1.0))[0]


def _psnr(a, b) -> float:
    import numpy as np

    mse = float(np.mean([np.mean((x.astype(np.float64) - y) ** 2) for x, y in zip(a, b)]))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def run(args: argparse.Namespace) -> list[dict]:
    from training.model.export import write_export
    from training.model.model_io import read_model

    g = read_model(args.model) if args.model is not None else random_model(args.count, args.sh_degree)
    render = _renderer(args.data, args.views, args.max_side) if args.data is not None else None
    reference = render(g) if render is not None else None
    rows, ply = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        warm = random_model(300, g.sh_degree, seed=1)
        for fmt, version, name in CASES:
            write_export(Path(tmp) / name, warm, fmt, spz_version=version)
            read_model(Path(tmp) / name)
        for fmt, version, name in CASES:
            path = Path(tmp) / name
            write_s, result = _best(lambda: write_export(path, g, fmt, spz_version=version), args.repeat)
            read_s, back = _best(lambda: read_model(path), args.repeat)
            if fmt == "ply":
                ply = {"bytes": result.size, "write_s": write_s, "read_s": read_s}
            row = {"format": fmt if version is None else f"spz v{version}", "gaussians": len(g),
                   "sh_bands": result.sh_bands, "bytes": result.size,
                   "bytes_per_gaussian": round(result.size / len(g), 1),
                   "size_vs_ply": round(result.size / ply["bytes"], 3), "write_s": float(f"{write_s:.3g}"),
                   "read_s": float(f"{read_s:.3g}"), "write_vs_ply": round(write_s / ply["write_s"], 2),
                   "read_vs_ply": round(read_s / ply["read_s"], 2)}
            if render is not None:
                row["psnr_db"] = round(_psnr(render(back), reference), 2)
            rows.append(row)
            path.unlink()
    return rows
