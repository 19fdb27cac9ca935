"""``splatstyler bench raster``: rasterizer speed and memory, every backend against the torch reference.

Each (backend, N, size) case runs in its own Python process, so its peak resident memory (``ru_maxrss`` of that
process, read with ``resource.getrusage``) belongs to that case alone; it includes the interpreter, torch and
numba themselves (``base_rss_mb`` is the same figure taken just before the first render). Times are medians over
``--repeat`` iterations after one warm-up; the forward pass runs with gradients enabled, as in training.
``first_render_s`` is the time from the worker process's first line (before torch is imported) to its first
finished image, i.e. a new process's cold start with the numba cache as it is on disk.

The scene: N Gaussians uniformly in a 4 x 3 x 4 box 3 to 7 units in front of a camera with a 0.9 x width focal
length, random rotations, scales log-normal around 0.03 * sqrt(10000 / N) (a fixed amount of "stuff" whatever
N, as in a trained model), opacities uniform in [0.05, 0.95], degree-3 SH colours.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

_T0 = time.perf_counter()  # first line of a worker process: the cold-start clock starts here

DEFAULT_NS = (10_000, 50_000, 200_000)
DEFAULT_SIZES = ((256, 192), (512, 384))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--n", type=int, default=None, help="number of Gaussians (default: 10k, 50k and 200k)")
    parser.add_argument("--size", default=None, help="image size WxH (default: 256x192 and 512x384)")
    parser.add_argument("--backends", default="cpu,torch",
                        help="comma-separated backends to measure (cpu, torch, cuda; default cpu,torch)")
    parser.add_argument("--repeat", type=int, default=5, help="timed iterations per case after one warm-up")
    parser.add_argument("--sh-degree", type=int, default=3, help="SH degree of the colours (default 3)")


def run(args: argparse.Namespace) -> list[dict]:
    from app.render_inputs import parse_size

    ns = [args.n] if args.n else list(DEFAULT_NS)
    sizes = [parse_size(args.size)] if args.size else list(DEFAULT_SIZES)
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    rows = []
    from tqdm import tqdm

    cases = [(n, w, h, b) for n in ns for (w, h) in sizes for b in backends]
    for n, w, h, backend in tqdm(cases, desc="bench raster", unit="case", file=sys.stderr):
        spec = {"backend": backend, "n": n, "width": w, "height": h, "repeat": max(1, args.repeat),
                "sh_degree": args.sh_degree}
        proc = subprocess.run([sys.executable, "-m", "app.bench.raster", json.dumps(spec)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["(no output)"]
            rows.append({"backend": backend, "n": n, "width": w, "height": h, "error": tail[0]})
            continue
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    for row in rows:
        ref = next((r for r in rows if r["backend"] == "torch" and r["n"] == row["n"]
                    and r["width"] == row["width"] and r["height"] == row["height"] and "fwdbwd_ms" in r), None)
        if ref is not None and "fwdbwd_ms" in row:
            row["speedup_vs_torch"] = ref["fwdbwd_ms"] / row["fwdbwd_ms"]
            row["fwd_speedup_vs_torch"] = ref["fwd_ms"] / row["fwd_ms"]
    return rows


def bench_scene(n: int, width: int, height: int, sh_degree: int, seed: int = 0):
    """The benchmark scene (see the module docstring): tensors means, quats, scales, opacities, sh, viewmat, K."""
    import torch

    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([4.0, 3.0, 4.0]) + torch.tensor([0.0, 0.0, 5.0])
    quats = torch.randn(n, 4, generator=g)
    scales = 0.03 * (10_000 / n) ** 0.5 * torch.exp(0.5 * torch.randn(n, 3, generator=g))
    opacities = 0.05 + 0.9 * torch.rand(n, generator=g)
    sh = 0.3 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g)
    f = 0.9 * width
    K = torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    return means, quats, scales, opacities, sh, torch.eye(4), K


def _worker(spec: dict) -> dict:
    import resource
    import statistics

    import torch

    from training.raster.rasterize import rasterize

    n, w, h, backend, deg = spec["n"], spec["width"], spec["height"], spec["backend"], spec["sh_degree"]
    device = "cuda" if backend == "cuda" else "cpu"
    scene = [t.to(device) for t in bench_scene(n, w, h, deg)]
    params = [t.clone().requires_grad_(True) for t in scene[:5]]
    base_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    def sync():
        if device == "cuda":
            torch.cuda.synchronize()

    fwd, total = [], []
    first_render_s = None
    for it in range(spec["repeat"] + 1):
        for p in params:
            p.grad = None
        sync()
        t0 = time.perf_counter()
        img, alpha, info = rasterize(*params, *scene[5:], w, h, sh_degree=deg, backend=backend)
        sync()
        t1 = time.perf_counter()
        if first_render_s is None:
            first_render_s = t1 - _T0
        (img.sum() + alpha.sum()).backward()
        sync()
        t2 = time.perf_counter()
        if it > 0:  # the first iteration is the warm-up (JIT cache load, allocator growth)
            fwd.append(t1 - t0)
            total.append(t2 - t0)
    return {
        "backend": info["backend"], "n": n, "width": w, "height": h,
        "fwd_ms": 1000 * statistics.median(fwd), "fwdbwd_ms": 1000 * statistics.median(total),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, "base_rss_mb": base_rss,
        "first_render_s": first_render_s, "threads": torch.get_num_threads(), "load1": os.getloadavg()[0],
    }


if __name__ == "__main__":
    print(json.dumps(_worker(json.loads(sys.argv[1]))), flush=True)
