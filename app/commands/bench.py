"""``splatstyler bench NAME``: speed and memory benchmarks, each against a reference measured in the same run.

Each benchmark lives in ``app/bench/<name>.py`` (registered in BENCHES) and exposes
``add_arguments(parser)`` and ``run(args) -> list[dict]``. This command prints the rows as a table, or with
``--json`` one JSON object per line.
"""

from __future__ import annotations

import argparse
import json

from app.bench import ccft, edits, formats, gpu, raster, reconstruct, stylize, viewer

# name -> (module, one-line help)
BENCHES = {
    "reconstruct": (reconstruct, "iterations/s of the quick reconstruction preset, per phase"),
    "raster": (raster, "rasterizer forward/backward time and peak memory per backend vs the torch reference"),
    "ccft": (ccft, "CCFT loss time and peak memory for n, m in {1k, 4k, 16k} against dense POT"),
    "stylize": (stylize, "stylization iterations/s with a per-stage breakdown (rasterize, VGG, top-K, Sinkhorn, backward)"),
    "edits": (edits, "colour edits, style strength, transforms and project files at 100k-1M Gaussians vs a copy of the SH"),
    "viewer": (viewer, "renderer_gl frame, sort and upload times at 10k-1M splats vs the CPU rasterizer's forward pass"),
    "formats": (formats, "each model file format's bytes and write/read time beside PLY's (1M random Gaussians or --model), and with --data the PSNR of renders read back"),
    "gpu": (gpu, "on an NVIDIA GPU: cuda parity tests, raster and viewer benches, reconstruct and stylize (paper presets); writes OUT/bench_gpu.json and .md"),
}


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("bench", help="run a speed/memory benchmark and print a table (or --json lines)")
    benches = parser.add_subparsers(dest="bench", metavar="NAME")
    for name, (module, help_text) in BENCHES.items():
        p = benches.add_parser(name, help=help_text, description=help_text)
        p.add_argument("--json", action="store_true", help="print one JSON object per line instead of a table")
        module.add_arguments(p)
        p.set_defaults(func=lambda args, m=module: _run(m, args))
    parser.set_defaults(func=lambda args: (parser.print_help(), 2)[1])


def _run(module, args) -> int:
    rows = module.run(args)
    if args.json:
        for row in rows:
            print(json.dumps(row), flush=True)
    else:
        print(format_table(rows))
    return 0


def format_table(rows: list[dict]) -> str:
    if not rows:
        return "(no results)"
    cols: list[str] = []
    for row in rows:
        cols.extend(k for k in row if k not in cols)

    def cell(v) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    table = [[cell(r.get(c, "")) for c in cols] for r in rows]
    widths = [max(len(c), *(len(t[i]) for t in table)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(cols, widths)), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(v.rjust(w) for v, w in zip(t, widths)) for t in table]
    return "\n".join(lines)
